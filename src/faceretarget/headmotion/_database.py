"""``HeadMotionDatabase``: head motion for new speech from recorded phrases (Chuang 2004, Ch. 4).

Build
-----
Each take's pitch is extracted (:func:`extract_pitch`) and cut into phrases and segments
(:func:`segment_speech`); the head motion (relative to the take's mean pose) is resampled to the
database rate ``fps`` and each segment keeps the slice of motion between its onset and the next.
With ``mirror=True`` every take is also stored left-right mirrored (same speech features,
mirrored motion, :func:`~faceretarget.headpose.mirror_yxz`), doubling the data.

Synthesize
----------
1. Pitch and segmentation of the new audio, exactly as for the database.
2. **Phrase matching.**  Each input phrase is compared with every database phrase by the
   Euclidean distance of their statistics (:data:`PHRASE_STATS`) each divided by its standard
   deviation over the database; the ``n_phrases`` (M) nearest phrases give the candidate segments.
3. **Segment matching** (Eqs. 4.3-4.5).  For input segment ``i`` and candidate ``j``::

       d_pitch = sqrt(mean_k (p_i(k) - p_j(k))^2) / sigma_p        (4.3, length-normalised pitch)
       d_len   = |log(voiced_i / voiced_j)|                        (4.4, length penalty)
       c_ij    = d_pitch + c * d_len                               (4.5)

   with ``p(k)`` the voiced run's pitch (semitones re the take's median) resampled to
   ``n_shape`` points and ``sigma_p`` the database's pitch standard deviation; the ``n_candidates``
   (K) lowest ``c_ij`` are kept per input segment.
4. **Path search.**  Viterbi (:func:`viterbi`) over the K candidates of every input segment with
   the costs of :class:`PathWeights`: unary ``pitch * c_ij + gap * |log((g_i + 0.05) / (g_j +
   0.05))|`` (g = following voiceless length, s); pairwise at each join ``position * |dp| /
   s_p + velocity * |dv| / s_v + acceleration * |da| / s_a`` between the end of the previous and
   the start of the next segment's rotation, each time-scaled to the input lengths; ``|dp|`` is
   divided by the database's RMS pose, ``|dv|`` (``|da|``) by the database's RMS speed
   (acceleration) plus the mean magnitude of the two velocities (accelerations) compared, so that
   slow segments are not preferred merely for being slow; ``- consecutive`` when the two are
   consecutive in a database take; ``+ reuse`` when the same database segment (or its mirror) was
   used within the last ``reuse_window`` segments.

   **Centring** (``center_continuity``, default on).  Even so, calm segments fit any neighbour
   better than lively ones (small velocities differ little in absolute terms), so the search chose
   calm motion: the chosen segments' mean log speed was 0.10 above their takes' median against
   0.19 for the database.  Each ``K x K`` block of position/velocity/acceleration costs is therefore
   double-centred (its row means and column means subtracted, its grand mean added back): a
   candidate's general calmness adds the same to all of its transitions and drops out, and only how
   well this pair fits remains.  The consecutive bonus is applied after centring.

   **Motion energy** (unary, ``energy`` weight).  ``e_j`` = log of segment ``j``'s mean angular
   speed over its take's median frame speed (speaker-normalised, like pitch).  A least-squares fit
   on the database (ridge ``1e-3 * S`` on the slopes) predicts ``e`` from the segment's pitch peak,
   peak above its phrase's mean pitch, pitch range and log voiced length (:func:`_energy_features`);
   the input segment gets the prediction ``e_hat_i`` and the candidate pays
   ``|e_j - e_hat_i| / s_e`` (``s_e`` the fit's residual standard deviation).
5. **Blending** (:func:`blend_segments`): time warp (by at most ``max_warp``: a database segment
   much longer than the input segment is cut short, a much shorter one runs on into the motion
   that follows it in its take), chain, drift correction, optional smoothing; then
   ``amplitude`` scales the motion about the database's mean pose.
6. **Range** (``motion_range``, optional).  Without it the output moves as much as the database
   speakers whose segments were chosen: a database of one lively speaker turns the head of a calm
   one as far as its own (leave-one-speaker-out on the shared takes: yaw 52 deg where the held-out
   speaker's capture spans 22, and 22 where another spans 50).  Nothing in the pitch predicts how far
   a speaker turns the head (``docs/headmotion.md``), so the range is the caller's to give, e.g.
   :func:`rotation_range` of the speaker's tracked head.  Given a range, each stored take's rotation is
   divided by its own per-axis 5-95 % range before blending (segments of a lively and a calm
   speaker then move alike), and the blended rotation is scaled per axis to span ``motion_range``
   degrees between its 5th and 95th percentiles.

``seed=None`` returns the best path; an integer seed perturbs the unary costs with Gumbel noise
of scale ``temperature`` times their spread and so samples among near-best alternatives.

"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.interpolate import CubicSpline

from ..base import Model
from ..errors import InvalidDataError
from ..headpose import HeadPose, mirror_yxz
from ..performance import Performance
from ._blend import blend_segments
from ._pitch import PitchTrack, extract_pitch
from ._segments import PHRASE_STATS, Segmentation, segment_speech
from ._viterbi import viterbi

__all__ = ["HeadMotionDatabase", "HeadMotionResult", "PathWeights", "SynthesisInfo", "EULER", "take_duration",
           "rotation_range", "RANGE_PERCENTILES"]

#: The Euler angles the database compares and blends motion in: intrinsic yaw (Y), pitch (X), roll (Z).
EULER = "YXZ"
_GAP0 = 0.05  # s, softens the log ratio of short voiceless lengths
#: Percentiles whose difference is a motion's range (:func:`rotation_range`, ``motion_range``): robust to
#: a few stray frames, and the statistic the P5 benchmark reports.
RANGE_PERCENTILES = (5.0, 95.0)
_MIN_RANGE = 1e-3  # rad, floor of a stored take's range when its motion is divided by it


@dataclass
class PathWeights:
    """Weights of the path-search costs (all costs are unitless; see the module docstring).

    Attributes
    ----------
    pitch : float
        Segment match ``c_ij`` (pitch shape and voiced length, Eq. 4.5).
    gap : float
        Following voiceless length match.
    position, velocity, acceleration : float
        Continuity of the rotation at joins (each normalised by the database's RMS).
    consecutive : float
        Bonus (subtracted) for two segments that follow each other in a database take.
    reuse : float
        Penalty for using a database segment (or its mirror) again within ``reuse_window`` segments.
    reuse_window : int
    energy : float
        Motion energy match: ``|e_j - e_hat_i| / s_e``, with ``e_j`` the candidate's log mean angular
        speed relative to its take's median, ``e_hat_i`` the value the database's own regression on
        pitch features predicts for the input segment and ``s_e`` the regression's residual
        standard deviation (:meth:`HeadMotionDatabase._prepare`).
    """

    pitch: float = 1.0
    gap: float = 0.5
    position: float = 0.5
    velocity: float = 0.5
    acceleration: float = 0.25
    consecutive: float = 0.5
    reuse: float = 2.0
    reuse_window: int = 8
    energy: float = 1.0


def take_duration(take: Performance) -> float:
    """Seconds a head-motion take covers with both audio and motion."""
    return min(take.audio.size / take.audio_rate, (take.n_frames - 1) / take.fps)


def _range(rot: np.ndarray) -> np.ndarray:
    """(3,) the :data:`RANGE_PERCENTILES` range of each column of (T, 3) angles (same unit)."""
    lo, hi = np.percentile(rot, RANGE_PERCENTILES, axis=0)
    return hi - lo


def rotation_range(head: HeadPose | Performance) -> np.ndarray:
    """(3,) degrees: how far a head turns, the 5-95 % range of its yaw, pitch and roll.

    The angles are the intrinsic Y-X-Z Euler angles the database works in (:data:`EULER`), unwrapped
    over time; frames without a pose are ignored.  Give it as ``motion_range`` to
    :meth:`HeadMotionDatabase.transform` to synthesize motion that turns as far as ``head`` does
    (for example the tracked head of the speaker whose new speech is animated).

    Raises
    ------
    InvalidDataError
        No head pose, or no frame with a pose.
    """
    h = head.head if isinstance(head, Performance) else head
    if not isinstance(h, HeadPose):
        raise InvalidDataError(f"{getattr(head, 'source', head)}: no head pose to measure a range of")
    rot = h.to_euler(EULER)
    rot = rot[np.isfinite(rot).all(axis=1)]
    if rot.size == 0:
        raise InvalidDataError(f"{h.source}: no frame with a head pose to measure a range of")
    return np.degrees(_range(np.unwrap(rot, axis=0)))


@dataclass
class SynthesisInfo:
    """What :meth:`HeadMotionDatabase.transform` chose (:attr:`HeadMotionResult.info`).

    Attributes
    ----------
    segmentation : Segmentation
        Of the input audio (after merging segments shorter than one output frame).
    path : (N,) int
        The database segment chosen for each input segment.
    start_frames : (N,) int
        Output frame where each input segment starts.
    joins : (N - 1,) int
        Output frames where a new database segment starts.
    knots : (B,) int
        Output frames where sub-sequences start (drift correction).
    cost : float
        Path cost.
    pitch_seconds, search_seconds : float
        Time spent in pitch extraction and in everything after it.
    """

    segmentation: Segmentation
    path: np.ndarray
    start_frames: np.ndarray
    joins: np.ndarray
    knots: np.ndarray
    cost: float
    pitch_seconds: float = 0.0
    search_seconds: float = 0.0
    extra: dict = field(default_factory=dict)


@dataclass(eq=False)
class HeadMotionResult:
    """What :meth:`HeadMotionDatabase.transform` gives: the head-motion take and how it was found."""

    take: Performance
    info: SynthesisInfo


def _rel_diff(x: np.ndarray, y: np.ndarray, scale: float) -> np.ndarray:
    """(A, B) ``|x_a - y_b| / (scale + (|x_a| + |y_b|) / 2)`` for (A, 3) and (B, 3) vectors.

    Dividing by the magnitudes as well as the database's RMS keeps the cost from preferring
    slow segments merely because their velocities (accelerations) are small and so differ little.
    """
    d = np.linalg.norm(x[:, None] - y[None], axis=2)
    m = 0.5 * (np.linalg.norm(x, axis=1)[:, None] + np.linalg.norm(y, axis=1)[None])
    return d / (scale + m)


def _energy_features(shape: np.ndarray, voiced: np.ndarray, phrase_mean: np.ndarray) -> np.ndarray:
    """(S, 5) regressors of a segment's motion energy: 1, pitch peak (semitones re the take's median),
    peak above the phrase's mean pitch, pitch range within the voiced run, log voiced length."""
    peak = shape.max(axis=1)
    return np.stack([np.ones(len(shape)), peak, peak - phrase_mean, peak - shape.min(axis=1),
                     np.log(np.maximum(voiced, 1e-3))], axis=1)


class _TakeAnalysis(NamedTuple):
    """One take as :meth:`HeadMotionDatabase.fit` analyses it (:meth:`HeadMotionDatabase._analyse_take`).

    Attributes
    ----------
    seg : Segmentation
        Of the take's speech.
    motion : (n_f, 6) float
        Yaw, pitch, roll (rad), x, y, z (m) resampled to the database's ``fps``.
    keep_phrase : (n_phrases,) bool
        Phrases not overlapping an excluded stretch.
    idx : (S,) int
        The kept segments (of a kept phrase, at least 2 frames long, starting within the take).
    f0, f1 : (n_segments,) int
        First and last database frame of every segment, counted from the take's start.
    n_f : int
        Frames of ``motion``.
    """

    seg: Segmentation
    motion: np.ndarray
    keep_phrase: np.ndarray
    idx: np.ndarray
    f0: np.ndarray
    f1: np.ndarray
    n_f: int


#: The lists :meth:`HeadMotionDatabase.fit` collects: per stored copy (motion, offset, names,
#: mirrored, mean), per segment (copy, base, frames, time, shape, phrase, next) and per phrase
#: (phrase_stats, phrase_copy).
_TABLES = ("motion", "offset", "names", "mirrored", "mean", "copy", "base", "frames", "time", "shape",
           "phrase", "next", "phrase_stats", "phrase_copy")


def _checked_takes(takes: Iterable[Performance], pitch: Iterable[PitchTrack | None] | None
                   ) -> tuple[list[Performance], list[PitchTrack | None]]:
    """The takes and one pitch track (or None) per take, checked for :meth:`HeadMotionDatabase.fit`."""
    takes = list(takes)
    if not takes:
        raise InvalidDataError("HeadMotionDatabase.fit: no takes given")
    pitches = list(pitch) if pitch is not None else [None] * len(takes)
    if len(pitches) != len(takes):
        raise InvalidDataError(f"HeadMotionDatabase.fit: {len(pitches)} pitch tracks for {len(takes)} takes")
    for t in takes:
        if not isinstance(t, Performance) or t.head is None or t.audio is None:
            raise InvalidDataError(f"{getattr(t, 'source', t)}: a head-motion take needs audio and a "
                                   "head pose")
    return takes, pitches


def _resampled_motion(take: Performance, n_f: int, F: float) -> np.ndarray:
    """(n_f, 6) yaw, pitch, roll (rad, unwrapped), x, y, z (m, 0 where missing) of ``take`` at ``F`` fps
    (cubic spline)."""
    t_src = np.arange(take.n_frames) / take.fps
    t_db = np.arange(n_f) / F
    rot = np.unwrap(take.head.to_euler(EULER), axis=0)
    tr = take.head.translation
    tr = np.zeros_like(rot) if tr is None else np.where(np.isfinite(tr), tr, 0.0)
    m = np.concatenate([rot, tr], axis=1)
    return CubicSpline(t_src, m, axis=0)(t_db)


def _speech_samples(speech: Performance | np.ndarray, rate: float | None, source: str | None
                    ) -> tuple[np.ndarray, float, str]:
    """(N,) samples, sampling rate and take name of :meth:`HeadMotionDatabase.transform`'s input."""
    if isinstance(speech, Performance):
        if speech.audio is None:
            raise InvalidDataError(f"{speech.source}: the take has no audio to follow")
        x, rate, source = speech.audio, speech.audio_rate, source or speech.source
    else:
        if rate is None:
            raise InvalidDataError("give the audio's sampling rate (rate=)")
        x = np.asarray(speech, np.float32).reshape(-1)
    return x, rate, source or "headmotion"


def _checked_output(fps: float, amplitude: float) -> float:
    """The output frame rate as a float, after checking it and ``amplitude`` are usable."""
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise InvalidDataError(f"fps must be positive, got {fps}")
    if not np.isfinite(amplitude):
        raise InvalidDataError(f"amplitude must be finite, got {amplitude}")
    return fps


def _checked_range(motion_range) -> np.ndarray | None:
    """``motion_range`` as (3,) radians (None stays None), after checking it is usable."""
    if motion_range is None:
        return None
    try:
        r = np.broadcast_to(np.asarray(motion_range, np.float64), (3,))
    except (TypeError, ValueError) as e:
        raise InvalidDataError(f"motion_range must be one number or three (yaw, pitch, roll degrees), "
                               f"got {motion_range!r}") from e
    if not (np.isfinite(r).all() and (r >= 0).all()):
        raise InvalidDataError(f"motion_range must be finite and >= 0 degrees, got {r.tolist()}")
    return np.radians(r)


def _scaled_to_range(y: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``y`` (T, 6) with its rotation columns scaled per axis so their :data:`RANGE_PERCENTILES` range is
    ``target`` (3,) (an axis that does not move stays still), and the (3,) scale applied."""
    r = _range(y[:, :3])
    scale = np.where(r > 1e-12, target / np.maximum(r, 1e-12), 0.0)
    y = y.copy()
    y[:, :3] *= scale
    return y, scale


class HeadMotionDatabase(Model):
    """Synthesize head motion for new speech from a database of recorded phrases.

    Parameters
    ----------
    fps : float
        Database and default output frame rate.
    f0_min, f0_max : float
        Pitch range searched, Hz.
    pitch_step : float
        Seconds between pitch frames.
    pause : float
        Voiceless stretches longer than this (s) end a phrase.
    n_shape : int
        Points of the length-normalised pitch of a segment.
    mirror : bool
        Also store every take mirrored left-right.
    n_phrases : int
        M, database phrases kept per input phrase.
    n_candidates : int
        K, database segments kept per input segment.
    length_weight : float
        ``c`` of Eq. 4.5.
    weights : PathWeights, optional
        Path-search weights.
    max_subsequence : float
        Longest stretch (s) chained before the drift correction pulls back to database poses.
    max_warp : float
        Largest factor by which a database segment is sped up or slowed down to fit an input
        segment; beyond it the segment is cut short, or runs on into the motion that follows it in
        its take (so recorded speeds change by at most this factor).
    tau_velocity : float
        Fade time (s) of the velocity correction at joins.
    smooth : float
        Gaussian sigma (s) blended in around joins (default 0: the velocity correction already
        makes joins C1, and a Gaussian flattens the head's strokes, which fall at voiced onsets,
        i.e. at the joins).
    temperature : float
        Scale of the perturbation that ``seed`` applies (relative to the spread of the costs).
    unwarped_head : float
        Seconds at the start of each segment played at the recorded speed; only the rest is
        time-warped (0 = warp the whole segment; tried, not the default: ``docs/headmotion.md``).
    transition : {"after", "before", "split"}
        Where :func:`blend_segments` absorbs the velocity mismatch at a join: in the new segment's
        first frames, in the frames before the join, or half each.
    center_continuity : bool
        Double-centre each block of join costs over the candidate pairs (subtract row and column
        means): the search then weighs how well two segments fit each other, not how calm each is.
        Without it the continuity costs select calm segments (module docstring).

    Attributes
    ----------
    n_segments_, n_phrases_ : int
        Database size (mirrored copies included).
    take_names_ : list of str
        Stored takes (a mirrored copy is named ``name~mirror``).
    mean_pose_ : (6,) float
        Yaw, pitch, roll (rad, intrinsic Y-X-Z), x, y, z (m) around which synthesized motion moves.
    motion_ : (F, 6) float
        Every stored take's motion as yaw, pitch, roll (rad), x, y, z (m) minus the take's mean, at
        ``fps``, one after another (with the mirrored copies).
    copy_range_ : (C, 3) float
        Each stored take's 5-95 % range of yaw, pitch, roll (rad), what its rotation is divided by
        when :meth:`transform` is given a ``motion_range``.
    """

    def __init__(self, *, fps: float = 30.0, f0_min: float = 60.0, f0_max: float = 500.0,
                 pitch_step: float = 0.01, pause: float = 0.3, n_shape: int = 16, mirror: bool = True,
                 n_phrases: int = 10, n_candidates: int = 12, length_weight: float = 1.0,
                 weights: PathWeights | None = None, max_subsequence: float = 4.0, max_warp: float = 1.5,
                 tau_velocity: float = 0.1, smooth: float = 0.0, temperature: float = 0.3,
                 unwarped_head: float = 0.0, transition: str = "after", center_continuity: bool = True) -> None:
        self.fps = fps
        self.f0_min = f0_min
        self.f0_max = f0_max
        self.pitch_step = pitch_step
        self.pause = pause
        self.n_shape = n_shape
        self.mirror = mirror
        self.n_phrases = n_phrases
        self.n_candidates = n_candidates
        self.length_weight = length_weight
        self.weights = weights if weights is not None else PathWeights()
        self.max_subsequence = max_subsequence
        self.max_warp = max_warp
        self.tau_velocity = tau_velocity
        self.smooth = smooth
        self.temperature = temperature
        self.unwarped_head = unwarped_head
        self.transition = transition
        self.center_continuity = center_continuity


    def pitch(self, audio: np.ndarray, rate: float) -> PitchTrack:
        """Pitch of ``audio`` with the database's settings."""
        return extract_pitch(audio, rate, f0_min=self.f0_min, f0_max=self.f0_max, time_step=self.pitch_step)

    # ------------------------------------------------------------------------------------ build
    def fit(self, takes: Iterable[Performance], exclude: Iterable[tuple[str, float, float]] | None = None, *,
            pitch: Iterable[PitchTrack | None] | None = None) -> HeadMotionDatabase:
        """Analyse takes and store their phrases, segments and motion; returns self.

        Parameters
        ----------
        takes : iterable of Performance
            Takes with audio and a head pose (:func:`~faceretarget.io.read_head_take`); each take's
            ``source`` is its name.
        exclude : iterable of (name, t0, t1), optional
            Leave out every phrase of take ``name`` overlapping ``t0..t1`` seconds (for
            leave-one-out evaluation without re-extracting pitch).
        pitch : iterable of PitchTrack or None, optional
            Each take's pitch (:meth:`pitch`) when already extracted; computed when absent.
        """
        takes, pitches = _checked_takes(takes, pitch)
        excl: dict[str, list[tuple[float, float]]] = {}
        for nm, t0, t1 in exclude or ():
            excl.setdefault(nm, []).append((float(t0), float(t1)))
        tables: dict[str, list] = {k: [] for k in _TABLES}
        tables["offset"].append(0)
        base0 = 0
        for take, track in zip(takes, pitches, strict=True):
            analysis = self._analyse_take(take, track, excl.get(take.source, []))
            if analysis.idx.size == 0:
                continue
            self._store_take(tables, take.source, analysis, base0)
            base0 += analysis.idx.size
        if not tables["names"]:
            raise InvalidDataError("HeadMotionDatabase.fit: no voiced speech with head motion in the "
                                   f"takes ({', '.join(t.source for t in takes)})")
        self._set_tables(tables)
        self._prepare()
        return self

    def _analyse_take(self, take: Performance, track: PitchTrack | None,
                      spans: list[tuple[float, float]]) -> _TakeAnalysis:
        """Pitch, segmentation and motion of one take, and which of its segments are kept
        (``track`` is extracted here when None; ``spans`` are the excluded (t0, t1) seconds)."""
        F = float(self.fps)
        track = track if track is not None else self.pitch(take.audio, take.audio_rate)
        seg = segment_speech(track, pause=self.pause, n_shape=self.n_shape)
        dur = take_duration(take)
        n_f = int(np.floor(dur * F + 1e-9)) + 1
        m = _resampled_motion(take, n_f, F)
        # segments and phrases kept
        keep_ph = np.ones(seg.n_phrases, bool)
        for t0, t1 in spans:
            p_end = np.r_[seg.phrase_start[1:], seg.duration]
            keep_ph &= ~((seg.phrase_start < t1) & (p_end > t0))
        f0 = np.round(seg.start * F).astype(int)
        f1 = np.minimum(np.round(seg.end * F).astype(int), n_f - 1)
        ok = keep_ph[seg.phrase] & (f1 - f0 >= 2) & (seg.start < dur)
        idx = np.flatnonzero(ok)
        return _TakeAnalysis(seg, m, keep_ph, idx, f0, f1, n_f)

    def _store_take(self, tables: dict[str, list], name: str, analysis: _TakeAnalysis, base0: int) -> None:
        """Append one analysed take (:meth:`_analyse_take`), and its mirrored copy, to ``tables``.

        Each stored copy adds its motion (``(n_f, 6)`` minus its mean) and, per kept segment, its copy,
        base segment (``base0`` onwards, shared by the mirrored copy), frames ``(S, 2)`` in the
        concatenated motion, times ``(S, 3)``, pitch shape, renumbered phrase and the following
        segment of the same take (or -1); per kept phrase its statistics and copy.
        """
        seg, m, keep_ph, idx, f0, f1, n_f = analysis
        new_ph = np.cumsum(keep_ph) - 1  # renumber kept phrases
        copies = [(False, m)]
        if self.mirror:
            r2, t2 = mirror_yxz(m[:, :3], m[:, 3:])
            copies.append((True, np.concatenate([r2, t2], axis=1)))
        nxt_local = np.full(idx.size, -1)
        consec = np.diff(idx) == 1
        nxt_local[:-1][consec] = np.arange(1, idx.size)[consec]
        for is_mirror, mm in copies:
            c = len(tables["names"])
            mean = mm.mean(axis=0)
            row0 = tables["offset"][-1]
            tables["motion"].append(mm - mean)
            tables["offset"].append(row0 + n_f)
            tables["names"].append(name + ("~mirror" if is_mirror else ""))
            tables["mirrored"].append(is_mirror)
            tables["mean"].append(mean)
            s0 = sum(len(x) for x in tables["copy"])
            p0 = sum(len(x) for x in tables["phrase_copy"])
            tables["copy"].append(np.full(idx.size, c))
            tables["base"].append(base0 + np.arange(idx.size))
            tables["frames"].append(np.stack([f0[idx], f1[idx]], axis=1) + row0)
            tables["time"].append(np.stack([seg.start[idx], seg.voiced_end[idx], seg.end[idx]], axis=1))
            tables["shape"].append(seg.shape[idx])
            tables["phrase"].append(p0 + new_ph[seg.phrase[idx]])
            tables["next"].append(np.where(nxt_local >= 0, nxt_local + s0, -1))
            tables["phrase_stats"].append(seg.phrase_stats[keep_ph])
            tables["phrase_copy"].append(np.full(int(keep_ph.sum()), c))

    def _set_tables(self, tables: dict[str, list]) -> None:
        """Store the learned tables (:meth:`_store_take`'s lists, concatenated)."""
        self.motion_ = np.concatenate(tables["motion"])
        self.copy_offset_ = np.asarray(tables["offset"], int)
        self.take_names_ = tables["names"]
        self.copy_mirrored_ = np.asarray(tables["mirrored"], bool)
        self.copy_mean_ = np.asarray(tables["mean"])
        self.mean_pose_ = self.copy_mean_.mean(axis=0)
        self.seg_copy_ = np.concatenate(tables["copy"])
        self.seg_base_ = np.concatenate(tables["base"])
        self.seg_frames_ = np.concatenate(tables["frames"])
        self.seg_time_ = np.concatenate(tables["time"])
        self.seg_shape_ = np.concatenate(tables["shape"])
        self.seg_next_ = np.concatenate(tables["next"])
        self.seg_phrase_ = np.concatenate(tables["phrase"])
        self.phrase_stats_ = np.concatenate(tables["phrase_stats"])
        self.phrase_copy_ = np.concatenate(tables["phrase_copy"])

    def _prepare(self) -> None:
        """Derived tables (not stored): scales, boundary states, phrase-to-segment lists."""
        m = self.motion_
        F = float(self.fps)
        P = self.phrase_stats_.shape[0]
        sd = self.phrase_stats_.std(axis=0) if P > 1 else np.ones(len(PHRASE_STATS))
        self.stat_scale_ = np.where(sd > 1e-9, sd, 1.0)
        sp = self.seg_shape_.std()
        self.shape_scale_ = float(sp) if sp > 1e-9 else 1.0
        # rotation statistics within takes (no differences across take boundaries)
        rot = m[:, :3]
        inner = np.ones(len(m), bool)
        inner[self.copy_offset_[1:-1] - 1] = False
        inner[-1] = False
        d1 = np.diff(rot, axis=0)[inner[:-1]] * F
        inner2 = inner[:-1] & inner[1:]
        d2 = np.diff(rot, 2, axis=0)[inner2[:-1]] * F * F
        self.pos_scale_ = float(np.sqrt((rot**2).sum(axis=1).mean())) or 1.0
        self.vel_scale_ = float(np.sqrt((d1**2).sum(axis=1).mean())) or 1.0
        self.acc_scale_ = float(np.sqrt((d2**2).sum(axis=1).mean())) or 1.0
        f0 = self.seg_frames_[:, 0]
        self.seg_start_state_ = np.stack([rot[f0], (rot[f0 + 1] - rot[f0]) * F,
                                          (rot[f0 + 2] - 2 * rot[f0 + 1] + rot[f0]) * F * F], axis=1)
        self.seg_last_ = self.copy_offset_[self.seg_copy_ + 1] - 1  # last frame of the segment's take
        self.seg_len_ = self.seg_time_[:, 2] - self.seg_time_[:, 0]
        self.seg_voiced_ = np.maximum(self.seg_time_[:, 1] - self.seg_time_[:, 0], 1e-3)
        self.seg_gap_ = np.maximum(self.seg_time_[:, 2] - self.seg_time_[:, 1], 0.0)
        order = np.argsort(self.seg_phrase_, kind="stable")
        counts = np.bincount(self.seg_phrase_, minlength=P)
        self._phrase_order = order
        self._phrase_ptr = np.r_[0, np.cumsum(counts)]
        # per-frame rotation speed (deg/s) of the data, for continuity reports
        self.frame_step_ = np.degrees(np.linalg.norm(d1, axis=1)) / F
        # motion energy of each segment and its regression on pitch features
        speed = np.r_[np.linalg.norm(np.diff(rot, axis=0), axis=1), 0.0]
        speed[~inner] = np.nan  # no speed across take boundaries
        copy_of_row = np.repeat(np.arange(len(self.take_names_)), np.diff(self.copy_offset_))
        self._copy_of_row = copy_of_row
        self.copy_range_ = np.stack([_range(rot[copy_of_row == c]) for c in range(len(self.take_names_))])
        med = np.array([np.nanmedian(speed[copy_of_row == c]) for c in range(len(self.take_names_))])
        csum = np.r_[0.0, np.cumsum(np.nan_to_num(speed))]
        f1 = self.seg_frames_[:, 1]
        seg_speed = (csum[f1] - csum[f0]) / np.maximum(f1 - f0, 1)
        self.seg_energy_ = np.log(np.maximum(seg_speed, 1e-9) / np.maximum(med[self.seg_copy_], 1e-9))
        X = _energy_features(self.seg_shape_, self.seg_voiced_, self.phrase_stats_[self.seg_phrase_, 5])
        ridge = 1e-3 * len(X) * np.eye(X.shape[1])
        ridge[0, 0] = 0.0
        self.energy_coef_ = np.linalg.solve(X.T @ X + ridge, X.T @ self.seg_energy_)
        res = self.seg_energy_ - X @ self.energy_coef_
        self.energy_scale_ = float(res.std()) or 1.0

    @property
    def n_segments_(self) -> int:
        return int(self.seg_copy_.size)

    @property
    def n_phrases_(self) -> int:
        return int(self.phrase_stats_.shape[0])

    # ------------------------------------------------------------------------------ synthesis
    def _input_segments(self, track: PitchTrack, fps: float) -> tuple[Segmentation, np.ndarray, int]:
        seg = segment_speech(track, pause=self.pause, n_shape=self.n_shape)
        n_out = int(np.floor(track.duration * fps + 1e-9)) + 1
        if seg.n_segments == 0:
            return seg, np.zeros(0, int), n_out
        a = np.round(seg.start * fps).astype(int)
        keep = np.r_[True, np.diff(a) > 0] & (a < n_out)
        if not keep.all():  # merge segments shorter than one output frame into the previous one
            k = np.flatnonzero(keep)
            end = np.r_[seg.start[k[1:]], seg.duration]
            seg = Segmentation(seg.start[k], seg.voiced_end[k], end, seg.phrase[k], seg.shape[k],
                               seg.phrase_start, seg.phrase_end, seg.phrase_stats, seg.reference_hz,
                               seg.duration)
            a = a[k]
        return seg, a, n_out

    def _candidates(self, seg: Segmentation) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Per input segment: K candidate database segments and their match cost c_ij."""
        zdb = self.phrase_stats_ / self.stat_scale_
        K = self.n_candidates
        cands, costs = [], []
        for p in range(seg.n_phrases):
            z = seg.phrase_stats[p] / self.stat_scale_
            d = np.sqrt(((zdb - z) ** 2).sum(axis=1))
            M = min(self.n_phrases, d.size)
            top = np.argpartition(d, M - 1)[:M] if M < d.size else np.arange(d.size)
            pool = np.concatenate([self._phrase_order[self._phrase_ptr[q]:self._phrase_ptr[q + 1]] for q in top])
            if pool.size == 0:
                pool = np.arange(self.n_segments_)
            ins = seg.phrase_segments(p)
            dp = np.sqrt(((seg.shape[ins][:, None, :] - self.seg_shape_[pool][None]) ** 2).mean(axis=2))
            dl = np.abs(np.log(np.maximum(seg.voiced_len[ins], 1e-3)[:, None] / self.seg_voiced_[pool][None]))
            c = dp / self.shape_scale_ + self.length_weight * dl
            k = min(K, pool.size)
            for r in range(ins.size):
                sel = np.argpartition(c[r], k - 1)[:k] if k < pool.size else np.arange(pool.size)
                sel = sel[np.argsort(c[r, sel], kind="stable")]
                cands.append(pool[sel])
                costs.append(c[r, sel])
        return cands, costs

    def _warp(self, segs: np.ndarray, in_len: float | np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """How each database segment is played over ``in_len`` seconds of input.

        Returns
        -------
        end : (n,) float
            Database frame reached at the end of the input segment (where the motion would
            continue).
        head : (n,) float
            Database frames at the start played at their own speed (``unwarped_head``).
        start_scale, end_scale : (n,) float
            Speed-up of the database motion at the start and at the end of the input segment.

        Only the part after the head is warped, and by at most ``max_warp``: a longer database
        segment is cut short, a shorter one runs on into the motion that follows it in its take (up
        to the take's end).
        """
        F = float(self.fps)
        f0 = self.seg_frames_[segs, 0].astype(np.float64)
        L = self.seg_frames_[segs, 1] - f0
        Lin = np.maximum(np.asarray(in_len, np.float64) * F, 1e-9)
        h = np.minimum(np.minimum(self.unwarped_head * F, Lin), L)
        rest = Lin - h
        rho = np.clip((L - h) / np.maximum(rest, 1e-9), 1.0 / self.max_warp, self.max_warp)
        end = np.minimum(f0 + h + rho * rest, self.seg_last_[segs])
        end = np.maximum(end, f0 + 2)
        h = np.minimum(h, end - f0)
        tail = np.where(rest > 1e-9, (end - f0 - h) / np.maximum(rest, 1e-9), 1.0)
        start = np.where(h > 0, 1.0, tail)
        return end, h, start, tail

    def _end_state(self, end: np.ndarray) -> np.ndarray:
        """(n, 3, 3) rotation, velocity (/s), acceleration (/s^2) at (float) database frames."""
        F = float(self.fps)
        rot = self.motion_[:, :3]
        k = np.floor(end).astype(int)
        return np.stack([rot[k], (rot[k] - rot[k - 1]) * F, (rot[k] - 2 * rot[k - 1] + rot[k - 2]) * F * F],
                        axis=1)

    def _trellis(self, seg: Segmentation, cands: list[np.ndarray], costs: list[np.ndarray],
                 in_len: np.ndarray, rng: np.random.Generator | None):
        w = self.weights
        gap_in = seg.gap_len
        unary = []
        e_hat = _energy_features(seg.shape, seg.voiced_len, seg.phrase_stats[seg.phrase, 5]) @ self.energy_coef_
        for i, (cj, cc) in enumerate(zip(cands, costs, strict=True)):
            g = np.abs(np.log((gap_in[i] + _GAP0) / (self.seg_gap_[cj] + _GAP0)))
            u = w.pitch * cc + w.gap * g
            if w.energy:
                u = u + w.energy * np.abs(self.seg_energy_[cj] - e_hat[i]) / self.energy_scale_
            unary.append(u)
        if rng is not None and self.temperature > 0:
            allu = np.concatenate(unary)
            spread = float(allu.std()) or 1.0
            unary = [u - self.temperature * spread * rng.gumbel(size=u.size) for u in unary]
        pair = []
        for i in range(1, len(cands)):
            A, B = cands[i - 1], cands[i]
            endA, _, _, sa = self._warp(A, in_len[i - 1])  # where A ends and its time scale there
            sa = sa[:, None]
            sb = self._warp(B, in_len[i])[2][:, None]
            ea, sbs = self._end_state(endA), self.seg_start_state_[B]
            dp = np.linalg.norm(ea[:, None, 0] - sbs[None, :, 0], axis=2) / self.pos_scale_
            dv = _rel_diff(ea[:, 1] * sa, sbs[:, 1] * sb, self.vel_scale_)
            da = _rel_diff(ea[:, 2] * sa**2, sbs[:, 2] * sb**2, self.acc_scale_)
            P = w.position * dp + w.velocity * dv + w.acceleration * da
            if self.center_continuity and P.shape[0] > 1 and P.shape[1] > 1:
                # keep only how well A fits B, not how calm A or B is in general (module docstring)
                P = P - P.mean(axis=1, keepdims=True) - P.mean(axis=0, keepdims=True) + P.mean()
            P = P - w.consecutive * (self.seg_next_[A][:, None] == B[None, :])
            pair.append(P)
        labels = [self.seg_base_[c] for c in cands]
        return unary, pair, labels

    def transform(self, speech: Performance | np.ndarray, rate: float | None = None, *,
                  amplitude: float = 1.0, rotation: bool = True, translation: bool = True,
                  seed: int | None = None, fps: float | None = None, pitch: PitchTrack | None = None,
                  source: str | None = None, path: np.ndarray | None = None,
                  motion_range: float | Sequence[float] | None = None) -> HeadMotionResult:
        """Head motion for new speech (Chuang Ch. 4's synthesis).

        Parameters
        ----------
        speech : Performance or (N,) float
            A take with audio, or mono speech samples in [-1, 1].
        rate : float
            Sampling rate, Hz (for samples).
        amplitude : float
            Scale of the motion about the database's mean pose (1 = as recorded).
        rotation, translation : bool
            Switch the rotation (then zeros) and the translation (then None) on or off.
        seed : int, optional
            None: the best path.  An integer: a near-best alternative, reproducible per seed.
        fps : float, optional
            Output frame rate (default the database's).
        pitch : PitchTrack, optional
            Precomputed pitch of ``audio``.
        source : str, optional
            Name of the returned take (default the input take's, else ``"headmotion"``).
        path : (N,) int, optional
            Skip the search and blend these database segments, one per input segment (for
            baselines and experiments; N must equal the input's segment count).
        motion_range : float or (3,) float, optional
            Degrees the head should turn: the 5-95 % range of yaw, pitch and roll over the output
            (one number for all three), e.g. :func:`rotation_range` of the speaker's own tracked or
            captured head.  Default None: the motion moves as much as the database speakers whose
            segments were chosen (a database of one speaker gives that speaker's range, whoever
            speaks; module docstring, step 6).  Given, every stored take's rotation is divided by
            its own range (``copy_range_``) before blending and the result scaled per axis to this
            range; the search is the same.  ``amplitude`` still multiplies the result.  The
            translation is not changed.  The scale applied is ``info.extra["range_scale"]``.

        Returns
        -------
        HeadMotionResult
            ``take``: ``times`` (T,) covering the audio at ``fps``, ``head`` (a
            :class:`~faceretarget.headpose.HeadPose`, translation in metres or None) and the
            ``audio``; ``info``: what the search chose and the time it took.

        Raises
        ------
        InvalidDataError
            No voiced speech in the audio, a database not built, or a ``motion_range`` that is not
            one or three finite numbers >= 0.
        """
        self._check_fitted()
        x, rate, source = _speech_samples(speech, rate, source)
        fps = _checked_output(self.fps if fps is None else fps, amplitude)
        target = _checked_range(motion_range)
        t0 = time.perf_counter()
        track = pitch if pitch is not None else self.pitch(x, rate)
        t1 = time.perf_counter()
        y, info = self._synthesize_track(track, fps, seed, path, normalise=target is not None)
        if target is not None:
            y, info.extra["range_scale"] = _scaled_to_range(y, target)
        info.pitch_seconds = t1 - t0
        rot, tr = self._absolute_pose(y, amplitude, rotation, translation)
        info.search_seconds = time.perf_counter() - t1
        head = HeadPose.from_euler(EULER, rot, tr, source=source)
        take = Performance(times=np.arange(len(rot)) / fps, fps=fps, head=head, audio=x,
                           audio_rate=float(rate), source=source)
        return HeadMotionResult(take, info)

    def _absolute_pose(self, y: np.ndarray, amplitude: float, rotation: bool, translation: bool
                       ) -> tuple[np.ndarray, np.ndarray | None]:
        """Rotation (T, 3) yaw, pitch, roll wrapped to [-pi, pi) (zeros without ``rotation``) and
        translation (T, 3) (None without ``translation``) of the deviation ``y`` (T, 6) scaled by
        ``amplitude`` about the mean pose."""
        y = y * float(amplitude)
        pose = self.mean_pose_ + y
        n = len(pose)
        rot = pose[:, :3] if rotation else np.zeros((n, 3))
        rot = (rot + np.pi) % (2 * np.pi) - np.pi
        tr = pose[:, 3:] if translation else None
        return rot, tr

    def _normalised_motion(self) -> np.ndarray:
        """(F, 6) ``motion_`` with each stored take's rotation divided by its range (``copy_range_``,
        at least ``_MIN_RANGE``): unitless, every take spanning 1 between its 5th and 95th percentiles."""
        out = self.motion_.copy()
        out[:, :3] /= np.maximum(self.copy_range_, _MIN_RANGE)[self._copy_of_row]
        return out

    def _synthesize_track(self, track: PitchTrack, fps: float, seed: int | None,
                          path: np.ndarray | None = None, normalise: bool = False
                          ) -> tuple[np.ndarray, SynthesisInfo]:
        """Deviation trajectory (T, 6) about the mean pose, and what was chosen.

        ``path`` (one database segment per input segment) skips the search (used by baselines);
        ``normalise`` blends :meth:`_normalised_motion` instead of ``motion_`` (the rotation is then
        unitless).
        """
        seg, a, n_out = self._input_segments(track, fps)
        if seg.n_segments == 0:
            raise InvalidDataError(f"no voiced speech found in the audio ({track.duration:.2f} s, pitch "
                                   f"range {self.f0_min:g}-{self.f0_max:g} Hz): nothing to follow")
        b = np.r_[a[1:], n_out]
        in_len = (b - a) / fps
        cost = 0.0
        if path is None:
            cands, costs = self._candidates(seg)
            rng = None if seed is None else np.random.default_rng(seed)
            unary, pair, labels = self._trellis(seg, cands, costs, in_len, rng)
            w = self.weights
            states, cost = viterbi(unary, pair, labels=labels, history_penalty=w.reuse, window=w.reuse_window)
            path = np.array([cands[i][k] for i, k in enumerate(states)], dtype=int)
        path = np.asarray(path, int)
        if path.shape != (seg.n_segments,) or path.min() < 0 or path.max() >= self.n_segments_:
            raise InvalidDataError(f"path must hold {seg.n_segments} database segment indices in "
                                   f"0..{self.n_segments_ - 1}, got shape {path.shape}")
        # sub-sequence knots: phrase starts, and at least every max_subsequence seconds
        first = np.r_[True, np.diff(seg.phrase) > 0]
        knots = []
        last = a[0]
        for i in range(1, seg.n_segments):
            if first[i] or (a[i] - last) / fps >= self.max_subsequence:
                knots.append(a[i])
                last = a[i]
        knots = np.asarray(knots, int)
        f0 = self.seg_frames_[path, 0]
        f1, head = self._warp(path, in_len)[:2]
        step = float(self.fps) / fps  # database frames per output frame
        motion = self._normalised_motion() if normalise else self.motion_
        y, joins = blend_segments(motion, f0, f1, a, n_out, fps=fps, knots=knots,
                                  tau_velocity=self.tau_velocity, smooth=self.smooth,
                                  head=head / step, step=step, transition=self.transition)
        return y, SynthesisInfo(seg, path, a, joins, knots, float(cost))

    def _after_load(self) -> None:
        self._prepare()

    def summary(self) -> str:
        """One line: takes, phrases, segments and minutes of motion."""
        self._check_fitted()
        mins = len(self.motion_) / self.fps / 60
        return (f"{len(self.take_names_)} stored take(s) ({int((~self.copy_mirrored_).sum())} recorded"
                f"{', mirrored' if self.copy_mirrored_.any() else ''}), {self.n_phrases_} phrases, "
                f"{self.n_segments_} segments, {mins:.1f} min of head motion at {self.fps:g} fps")

