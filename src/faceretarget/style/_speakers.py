"""Emotion on a speaker the model has never seen: style models in a space that does not depend on who
is speaking (issue 27; protocol P6 of ``../shared/EVALUATION.md``; ``docs/style.md``, "Across speakers").

A :class:`StyleModel` learns style (the emotion) and content (the speech) from one performer's takes.
Across performers the same emotion differs in two ways that are not the emotion: the face (identity,
size) and the intensity (one actor's angry moves the face 8 mm, another's 35 mm).  Measured on P6, the
speakers' offsets point the same way (cosine 0.4-0.9) but differ up to 4x in size, and nothing in a
speaker's neutral take says how strongly they act.  :class:`SpeakerStyleModel` keeps Chuang's
bilinear models (one :class:`StyleModel` per emotion, ``neutral`` and that emotion) and changes what
they are fitted on:

1. **Space** (``space``).  Every speaker's frames are expressed relative to that speaker's own rest
   (the mean of their neutral take), in one of:

   * ``"landmarks"``: the 68 face points' displacement from the rest, rotated and scaled onto one
     canonical face (generalised Procrustes of the training speakers' rests), plus the canonical
     face (frames of points: the style models' point-local translation stays available);
   * ``"range"``: the same, each region's displacement (jaw, brows, nose, eyes, mouth) divided by
     that region's RMS motion in the speaker's neutral take (times the training speakers' mean, so
     the units stay millimetres);
   * ``"arkit"``: the tracker's ARKit scores minus the speaker's rest scores (MediaPipe's scores are
     already normalised for identity and scale); an edit comes back to the points through a ridge
     regression from score changes to canonical point displacements, pooled over the training
     speakers (ridge chosen by leaving one speaker out);
   * ``"both"``: the landmark displacements and the score changes side by side, each block divided
     by its RMS over the training frames; the points come back from the landmark block, the scores
     from the score block.

2. **Intensity** (``intensity="equalise"``).  Each training speaker's emotion take is rescaled about
   their neutral take so that its mean offset has the emotion's typical size (the mean over the
   training speakers): the style models learn the emotion's direction and how it shapes the speech,
   not who acted it more strongly.  ``intensity_[e]`` is that typical size, in the space's units.
   When a take is recognised, its own intensity is estimated from the take (its change along the
   emotion, over ``intensity_``).

3. **Calibration** (``calibrate=True``).  How far the training speakers agree on an emotion decides
   how much of it carries to a new face.  Leaving one training speaker out at a time, the models of
   the others translate that speaker's neutral take, and the scale that best fits their
   (intensity-equalised) real take is ``gain_[e]`` (in [0, 1]; pooled over the held-out speakers).
   An emotion only one training speaker shows gets the median gain of the others.  These are
   settings chosen inside the training speakers only, so a speaker nobody has seen gets the same
   treatment as the held-out ones of the protocol.

An edit of a new speaker's take to emotion ``e`` is ``x + amount * gain_[e] * (M_e(x) - x)`` in the
space (``M_e``: the emotion's style model, Eq. 2.10, 2.11), mapped back to the speaker's own face:
``amount`` 1 is the training speakers' typical intensity of what they share of the emotion, on any
speaker, and ``amount`` 2 doubles it.  Recognition (:meth:`SpeakerStyleModel.recognise`): every
emotion's model translates the speaker's neutral take, and the emotion whose mean change, at the
intensity that fits best (Eq. 2.15 with a free amount), leaves the least of the take's mean change
unexplained is the take's style.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..base import Model
from ..errors import InvalidDataError
from ..names import normalize_name
from ..numerics import similarity_fit
from ..performance import Performance
from ._align import align_performances, realign_by_style, resample
from ._model import RangeReport, Restyled, StyleModel

__all__ = ["SpeakerStyleModel", "Recognition", "align_speaker_takes", "canonical_face", "SPACES", "REGIONS68",
           "DECODER_RIDGES"]

#: The spaces a :class:`SpeakerStyleModel` can learn in (module docstring).
SPACES = ("both", "landmarks", "range", "arkit")
#: How each training speaker's intensity is treated.
INTENSITY = ("equalise", "keep")
#: The regions of the 68 Multi-PIE points (the ``"range"`` space's normalisation).
REGIONS68 = {"jaw": np.arange(0, 17), "brows": np.arange(17, 27), "nose": np.arange(27, 36),
             "eyes": np.arange(36, 48), "mouth": np.arange(48, 68)}
#: Ridges (relative to the mean squared score change) searched for the ``"arkit"`` decoder.
DECODER_RIDGES = (1e-2, 1e-1, 1.0, 10.0)
_P = 68


def canonical_face(rests: Mapping[str, np.ndarray] | list, iters: int = 10) -> np.ndarray:
    """Generalised Procrustes mean ``(68, 3)`` of rest faces (each speaker's, ``(68, 3)``)."""
    R = [np.asarray(r, np.float64) for r in (rests.values() if isinstance(rests, Mapping) else rests)]
    if not R:
        raise InvalidDataError("canonical_face: no rest face given")
    can = R[0].copy()
    for _ in range(iters):
        al = []
        for r in R:
            s, rot, c = similarity_fit(can, r[None])
            al.append(((r - c[0]) @ rot[0]) / s[0])
        can = np.mean(al, axis=0)
    return can


def _check_speaker_take(p: Performance, what: str, scores: bool) -> None:
    if not isinstance(p, Performance) or p.points is None or p.points.shape[1:] != (_P, 3):
        raise InvalidDataError(f"{what}: expected a take of the 68 face points (x, y, z), head motion removed "
                               "(pipelines.face_take), got "
                               f"{'no points' if getattr(p, 'points', None) is None else p.points.shape}")
    if scores and p.weights is None:
        raise InvalidDataError(f"{what}: this space needs the tracker's ARKit scores as the take's weights "
                               "(pipelines.tracked_take gives them)")
    if not np.isfinite(p.points).all():
        raise InvalidDataError(f"{what}: frame {int(np.flatnonzero(~np.isfinite(p.points).all((1, 2)))[0])} has "
                               "non-finite points")


def align_speaker_takes(takes: Mapping[str, Mapping[str, Performance]], reference: str = "neutral", *,
                        realign: int = 2, window_s: float | None = None) -> dict[str, dict[str, Performance]]:
    """Every speaker's takes put on the timeline of that speaker's ``reference`` take.

    By audio when both takes have it, else by face features re-aligned by style (``realign``
    iterations, :func:`~._align.realign_by_style`), as :meth:`StyleModel.fit` aligns point takes.

    Parameters
    ----------
    takes : {speaker: {style: Performance}}
        Takes of the 68 face points (``points`` ``(T, 68, 3)``), with the tracker's ARKit scores as
        ``weights`` where a space needs them; one text per speaker (speakers may differ).

    Returns
    -------
    {speaker: {style: Performance}}
        Points (and weights) resampled at the reference take's times; the reference as given.
    """
    out: dict[str, dict[str, Performance]] = {}
    for spk, d in takes.items():
        if reference not in d:
            raise InvalidDataError(f"speaker '{spk}': no '{reference}' take to align the others to "
                                   f"(styles: {', '.join(d)})")
        ref = d[reference]
        _check_speaker_take(ref, f"speaker '{spk}', {reference}", False)
        al_d = {reference: ref}
        for st, take in d.items():
            if st == reference:
                continue
            _check_speaker_take(take, f"speaker '{spk}', {st}", False)
            al = align_performances(ref, take, by="auto", window_s=window_s)
            if al.by == "face" and realign > 0:
                al = realign_by_style(ref, take, al, iterations=int(realign), window_s=window_s)
            q = al(ref.times)
            kw = {}
            if take.weights is not None:
                kw = {"weights": resample(take.weights, take.times, q), "names": list(take.names)}
            al_d[st] = Performance(ref.times.copy(), ref.fps, points=resample(take.points, take.times, q),
                                   labels=list(take.labels), unit=take.unit, source=f"{take.source} (aligned)",
                                   **kw)
        out[spk] = al_d
    return out


@dataclass
class Recognition:
    """The style of a take, recognised by :meth:`SpeakerStyleModel.recognise`.

    Attributes
    ----------
    style : str
        The best-explained emotion (``"neutral"`` when no emotion explains any of the change).
    unexplained : dict of str to float
        Share of the take's mean change (from the speaker's neutral) left unexplained by each
        emotion's model change at its best intensity (1 = nothing explained; neutral is 1).
    intensity : dict of str to float
        The take's change along each emotion's direction over the training speakers' typical
        intensity (1 = typical; estimated from the take itself).
    ranking : list of str
        Styles from best to worst.
    """

    style: str
    unexplained: dict
    intensity: dict
    ranking: list


class SpeakerStyleModel(Model):
    """Emotion across speakers: one :class:`StyleModel` per emotion, in a speaker-independent space.

    Parameters
    ----------
    space : {"both", "landmarks", "range", "arkit"}
        What the style models are fitted on (module docstring).  ``"both"`` (default) did best on P6,
        leaving one speaker out: translation 0.954 of the additive baseline's error, recognition 63 %
        (``docs/style.md``, "Across speakers").
    intensity : {"equalise", "keep"}
        Rescale each training speaker's emotion offsets to the emotion's typical size before fitting
        (``"keep"``: as acted).
    calibrate : bool
        Scale every emotion's edit by ``gain_``, chosen by leaving one training speaker out.
    decoder_ridge : float or "auto"
        Ridge of the ``"arkit"`` space's map from score changes to point displacements, relative to
        the mean squared score change; ``"auto"``: chosen from :data:`DECODER_RIDGES` by leaving one
        training speaker out.
    style : dict, optional
        :class:`StyleModel` parameters of every emotion's model (default: its defaults; with several
        training speakers the settings are chosen by leaving one speaker out).
    reference : str
        The neutral style every speaker's takes are aligned to and edits start from.

    Attributes
    ----------
    speakers_ : list of str
    styles_ : list of str
        ``reference`` and the emotions (any training speaker's).
    canonical_ : (68, 3) float
        The training speakers' Procrustes mean rest face.
    models_ : dict of str to StyleModel
        Per emotion, fitted on (``reference``, emotion) frames of the speakers who have that emotion.
    intensity_ : dict of str to float
        Typical size of each emotion's mean offset in the space (mean over training speakers).
    speaker_intensity_ : dict of str to dict of str to float
        Each training speaker's size of each emotion's mean offset.
    gain_ : dict of str to float
        The calibrated share of each emotion that carries to a new speaker (1 without ``calibrate``).
    gain_source_ : dict of str to str
        ``"held-out speakers"``, ``"median of the other emotions"`` or ``"not calibrated"``.
    decoder_ : (S, 204) float or None
        ``"arkit"``: score change -> canonical point displacement.
    decoder_ridge_ : float or None
    score_names_ : list of str
        The ARKit channels of the score spaces.
    region_scale_ : (68,) float or None
        ``"range"``: the training speakers' mean region motion per point.
    block_scale_ : (2,) float or None
        ``"both"``: RMS of the landmark and score blocks over the training frames.
    """

    def __init__(self, space: str = "both", intensity: str = "equalise", calibrate: bool = True,
                 decoder_ridge: float | str = "auto", style: dict | None = None, reference: str = "neutral"):
        self.space = space
        self.intensity = intensity
        self.calibrate = calibrate
        self.decoder_ridge = decoder_ridge
        self.style = style
        self.reference = reference

    # ------------------------------------------------------------------------------ speakers
    def _uses_scores(self) -> bool:
        return self.space in ("arkit", "both")

    def _check_params(self) -> None:
        if self.space not in SPACES:
            raise InvalidDataError(f"space must be one of {', '.join(SPACES)}, got {self.space!r}")
        if self.intensity not in INTENSITY:
            raise InvalidDataError(f"intensity must be one of {', '.join(INTENSITY)}, got {self.intensity!r}")
        r = self.decoder_ridge
        if not (r == "auto" or (isinstance(r, int | float) and not isinstance(r, bool) and r > 0)):
            raise InvalidDataError(f"decoder_ridge must be 'auto' or a number > 0, got {r!r}")

    def _speaker(self, neutral: Performance, what: str) -> dict:
        """A speaker's normalisation from their neutral take: rest face, similarity onto the canonical
        face, rest scores (in the model's channel order), region motion."""
        _check_speaker_take(neutral, what, self._uses_scores())
        rest = neutral.points.mean(axis=0)
        s, R, c = similarity_fit(self.canonical_, rest[None])
        spk = {"rest": rest, "s": float(s[0]), "R": R[0], "scores": None, "range": None}
        if self._uses_scores():
            spk["scores"] = self._score_columns(neutral, what).mean(axis=0)
        if self.space == "range":
            D = (neutral.points - rest) @ R[0] / s[0]
            rng = np.empty(_P)
            for idx in REGIONS68.values():
                rng[idx] = np.sqrt(np.mean(np.sum((D[:, idx] - D[:, idx].mean(0)) ** 2, axis=-1)))
            spk["range"] = np.maximum(rng, 1e-9 * max(float(rng.max()), 1e-300))
        return spk

    def _score_columns(self, p: Performance, what: str) -> np.ndarray:
        idx = {normalize_name(n): j for j, n in enumerate(p.names)}
        missing = [n for n in self.score_names_ if n not in idx]
        if missing:
            raise InvalidDataError(f"{what}: lacks {len(missing)} ARKit score(s) the model uses: "
                                   f"{', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}")
        return np.asarray(p.weights, np.float64)[:, [idx[n] for n in self.score_names_]]

    def _features(self, p: Performance, spk: dict, what: str) -> np.ndarray:
        """A take's frames in the space: ``(T, 68, 3)`` for the point spaces, else ``(T, F)``."""
        _check_speaker_take(p, what, self._uses_scores())
        D = (p.points - spk["rest"]) @ spk["R"] / spk["s"]                     # canonical displacement
        if self.space == "landmarks":
            return self.canonical_ + D
        if self.space == "range":
            return self.canonical_ + D * (self.region_scale_ / spk["range"])[:, None]
        W = self._score_columns(p, what) - spk["scores"]
        if self.space == "arkit":
            return W
        return np.concatenate([D.reshape(len(D), -1) / self.block_scale_[0], W / self.block_scale_[1]], axis=1)

    def _decode(self, dF: np.ndarray, spk: dict) -> tuple[np.ndarray, np.ndarray | None]:
        """A change in the space -> ``(point change (T, 68, 3) in the speaker's frame, score change or None)``."""
        dW = None
        if self.space == "landmarks":
            D = dF.reshape(len(dF), _P, 3)
        elif self.space == "range":
            D = dF.reshape(len(dF), _P, 3) * (spk["range"] / self.region_scale_)[:, None]
        elif self.space == "arkit":
            D, dW = (dF @ self.decoder_).reshape(len(dF), _P, 3), dF
        else:
            n = 3 * _P
            D, dW = (dF[:, :n] * self.block_scale_[0]).reshape(len(dF), _P, 3), dF[:, n:] * self.block_scale_[1]
        return spk["s"] * D @ spk["R"].T, dW

    # ------------------------------------------------------------------------------ fitting
    def fit(self, takes: Mapping[str, Mapping[str, Performance]], *, aligned: bool = False) -> SpeakerStyleModel:
        """Fit from several speakers' takes of one text each in several styles; returns self.

        Parameters
        ----------
        takes : {speaker: {style: Performance}}
            Each speaker's takes of the 68 face points with the head removed
            (:func:`~faceretarget.pipelines.face_take`), with the tracker's ARKit scores as weights
            for the score spaces; every speaker needs a ``reference`` (neutral) take and at least
            one other style.
        aligned : bool
            The takes are already on their speaker's reference timeline (:func:`align_speaker_takes`);
            otherwise they are aligned here.
        """
        self._check_params()
        if not takes:
            raise InvalidDataError("a speaker style model needs the takes of at least one speaker")
        ref = self.reference
        for spk, d in takes.items():
            if ref not in d or len(d) < 2:
                raise InvalidDataError(f"speaker '{spk}': needs a '{ref}' take and another style (has "
                                       f"{', '.join(d) or 'none'})")
        al = {s: dict(d) for s, d in takes.items()} if aligned else align_speaker_takes(takes, ref)
        for spk, d in al.items():
            C = {p.n_frames for p in d.values()}
            if len(C) != 1:
                raise InvalidDataError(f"speaker '{spk}': aligned takes differ in length ({sorted(C)}); align "
                                       "them first (align_speaker_takes)")
        self.speakers_ = [str(s) for s in al]
        first = al[self.speakers_[0]][ref]
        self.score_names_ = ([normalize_name(n) for n in first.names] if self._uses_scores() and first.weights
                             is not None else [])
        self.canonical_ = canonical_face({s: d[ref].points.mean(axis=0) for s, d in al.items()})
        self.region_scale_ = self.block_scale_ = self.decoder_ = self.decoder_ridge_ = None
        spk = {s: self._speaker(d[ref], f"speaker '{s}', {ref}") for s, d in al.items()}
        if self.space == "range":
            self.region_scale_ = np.mean([v["range"] for v in spk.values()], axis=0)
        if self.space == "both":
            self.block_scale_ = np.ones(2)
            raw = [self._features(p, spk[s], f"speaker '{s}', {st}") for s, d in al.items() for st, p in d.items()]
            R = np.concatenate(raw)
            n = 3 * _P
            self.block_scale_ = np.array([max(float(np.sqrt(np.mean(np.sum(R[:, :n] ** 2, 1)))), 1e-12),
                                          max(float(np.sqrt(np.mean(np.sum(R[:, n:] ** 2, 1)))), 1e-12)])
        F = {s: {st: self._features(p, spk[s], f"speaker '{s}', {st}") for st, p in d.items()} for s, d in al.items()}
        if self.space == "arkit":
            D = {s: {st: (p.points - spk[s]["rest"]) @ spk[s]["R"] / spk[s]["s"] for st, p in d.items()}
                 for s, d in al.items()}
            self.decoder_, self.decoder_ridge_ = _fit_decoder(F, D, self.decoder_ridge)
        emotions = list(dict.fromkeys(st for d in al.values() for st in d if st != ref))
        self.styles_ = [ref, *emotions]
        self.intensity_, self.speaker_intensity_, eq = {}, {}, {}
        for e in emotions:
            who = [s for s in self.speakers_ if e in F[s]]
            off = {s: np.mean(F[s][e] - F[s][ref], axis=0) for s in who}
            k = {s: float(np.linalg.norm(off[s])) for s in who}
            kbar = float(np.mean(list(k.values())))
            self.intensity_[e] = kbar
            for s in who:
                self.speaker_intensity_.setdefault(s, {})[e] = k[s]
            eq[e] = {s: (F[s][e] + (kbar / k[s] - 1.0) * off[s] if self.intensity == "equalise" and k[s] > 0
                         else F[s][e]) for s in who}
        self.models_ = {e: self._fit_emotion(F, eq[e], e, list(eq[e])) for e in emotions}
        self._calibrate(F, eq, emotions)
        return self

    def _fit_emotion(self, F: dict, Fe: dict, e: str, who: list[str]) -> StyleModel:
        ref = self.reference
        frames = {ref: np.concatenate([F[s][ref] for s in who]), e: np.concatenate([Fe[s] for s in who])}
        groups = np.concatenate([[s] * len(F[s][ref]) for s in who]) if len(who) > 1 else None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return StyleModel(**dict(self.style or {})).fit_frames(frames, groups=groups)

    def _calibrate(self, F: dict, eq: dict, emotions: list[str]) -> None:
        """``gain_``: per emotion, the scale of the model change that best predicts held-out training
        speakers (their intensity-equalised takes), the models fitted on the other speakers."""
        ref = self.reference
        self.gain_, self.gain_source_ = {}, {}
        if not self.calibrate:
            self.gain_ = {e: 1.0 for e in emotions}
            self.gain_source_ = {e: "not calibrated" for e in emotions}
            return
        for e in emotions:
            who = list(eq[e])
            if len(who) < 2:
                continue
            num = den = 0.0
            for h in who:
                rest = [s for s in who if s != h]
                m = self._fit_emotion(F, eq[e], e, rest)
                x = F[h][ref]
                d = _known(m, x, ref, e) - x
                r = eq[e][h] - x
                num += float(np.sum(d * r))
                den += float(np.sum(d * d))
            self.gain_[e] = float(np.clip(num / den, 0.0, 1.0)) if den > 0 else 0.0
            self.gain_source_[e] = "held-out speakers"
        pooled = float(np.median(list(self.gain_.values()))) if self.gain_ else 1.0
        for e in emotions:
            if e not in self.gain_:
                self.gain_[e] = pooled
                self.gain_source_[e] = ("median of the other emotions" if len(self.gain_source_) else
                                        "one training speaker: not calibrated")

    # ------------------------------------------------------------------------------ applying
    def _check_style(self, name: str, what: str) -> None:
        if name not in self.styles_:
            raise InvalidDataError(f"unknown {what} style '{name}'; the model has {', '.join(self.styles_)}")

    def change(self, take: Performance, to: str, *, neutral: Performance | None = None,
               source: str | None = None) -> tuple[np.ndarray, RangeReport]:
        """The calibrated change ``gain_[to] * (M_to(x) - x)`` of a take in the space, ``(T, F)``
        (flattened), and the style model's range report; ``source`` defaults to the reference."""
        self._check_fitted("change")
        self._check_style(to, "target")
        src = self.reference if source is None else source
        self._check_style(src, "source")
        spk = self._speaker(take if neutral is None else neutral, f"{(neutral or take).source} (rest)")
        x = self._features(take, spk, take.source)
        return self._change(x, src, to)

    def _change(self, x: np.ndarray, src: str, to: str) -> tuple[np.ndarray, RangeReport]:
        ref = self.reference
        flat = x.reshape(len(x), -1)
        total = np.zeros_like(flat)
        rep = RangeReport(0.0, False, 0.0, 0.5)
        if src != ref and src != to:                                   # back to neutral first
            m = self.models_[src]
            back = _known(m, x, src, ref, report=True)
            total += self.gain_[src] * (back[0].reshape(len(x), -1) - flat)
            rep = back[1]
            x = (flat + total).reshape(x.shape)
        if to != ref and src != to:
            fwd = _known(self.models_[to], x, ref, to, report=True)
            total += self.gain_[to] * (fwd[0].reshape(len(x), -1) - x.reshape(len(x), -1))
            rep = fwd[1] if fwd[1].score >= rep.score else rep
        return total, rep

    def transform(self, take: Performance, to: str, amount: float = 1.0, *, neutral: Performance | None = None,
                  source: str | None = None) -> Restyled:
        """A take of a speaker (any speaker) with its emotion changed to ``to``.

        Parameters
        ----------
        take : Performance
            The 68 face points with the head removed (and the ARKit scores as weights for the score
            spaces), in the speaker's own face frame.
        to : str
            Target style.
        amount : float
            1: the training speakers' typical intensity of what they share of the emotion (the same on
            every speaker); 0 returns the take; 2 doubles the change.
        neutral : Performance, optional
            A neutral take of the same speaker: their rest face (and rest scores) are its means.
            Default: the take's own means (right for a neutral take).
        source : str, optional
            The take's own style (default the reference, neutral); another emotion is first taken
            back to neutral by its own model.

        Returns
        -------
        Restyled
            ``frames`` ``(T, 68, 3)``: the edited points in the take's frame; ``take``: the take with
            those points (and, for the score spaces, the edited scores clipped to [0, 1]).
        """
        a = float(amount)
        if not np.isfinite(a):
            raise InvalidDataError(f"amount must be finite, got {amount}")
        self._check_fitted()
        self._check_style(to, "target")
        src = self.reference if source is None else source
        self._check_style(src, "source")
        spk = self._speaker(take if neutral is None else neutral,
                            f"{(take if neutral is None else neutral).source} (rest)")
        x = self._features(take, spk, take.source)
        dF, rep = self._change(x, src, to)
        dX, dW = self._decode(a * dF, spk)
        pts = take.points + dX
        new = take.with_points(pts)
        if dW is not None and take.weights is not None:
            idx = {normalize_name(n): j for j, n in enumerate(take.names)}
            W = np.array(take.weights, np.float64)
            cols = [idx[n] for n in self.score_names_]
            W[:, cols] = np.clip(W[:, cols] + dW, 0.0, 1.0)
            new = new.replace(weights=W, names=list(take.names))
        return Restyled(pts, rep, take=new)

    def recognise(self, take: Performance, neutral: Performance) -> Recognition:
        """The emotion of a take of a speaker (any speaker), given a neutral take of the same speaker.

        Every emotion's model translates the neutral take; the take's mean change from the neutral
        take is fitted by each emotion's mean model change at the best intensity ``a >= 0`` (Eq. 2.15
        with a free amount: the intensity comes from the take itself), and the emotion that leaves
        the least unexplained wins.  The two takes need not be aligned or of the same text.
        """
        self._check_fitted("recognise")
        spk = self._speaker(neutral, f"{neutral.source} (rest)")
        xn = self._features(neutral, spk, neutral.source)
        o = (self._features(take, spk, take.source).reshape(take.n_frames, -1).mean(0)
             - xn.reshape(len(xn), -1).mean(0))
        oo = float(o @ o)
        un, inten = {self.reference: 1.0}, {}
        for e, m in self.models_.items():
            p = (_known(m, xn, self.reference, e) - xn).reshape(len(xn), -1).mean(0)
            pp, op = float(p @ p), float(o @ p)
            # 1 - cos^2 at the best intensity a = max(0, o.p / p.p): what the emotion leaves unexplained
            un[e] = 1.0 - op * op / (oo * pp) if op > 0 and oo > 0 and pp > 0 else 1.0
            inten[e] = op / np.sqrt(pp) / self.intensity_[e] if pp > 0 and self.intensity_[e] > 0 else 0.0
        ranking = sorted(un, key=lambda k: (un[k], k != self.reference))
        return Recognition(ranking[0], un, inten, ranking)


def _known(m: StyleModel, x: np.ndarray, src: str, to: str, report: bool = False):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = m.known(x, src, to, warn=False)
    f = np.asarray(r.frames).reshape(x.shape)
    return (f, r.range) if report else f


def _fit_decoder(F: dict, D: dict, ridge) -> tuple[np.ndarray, float]:
    """Ridge map score change ``(S,)`` -> canonical point displacement ``(204,)`` over every training
    frame; ``ridge="auto"``: the one of :data:`DECODER_RIDGES` that best predicts held-out speakers."""

    def solve(speakers, lam):
        X = np.concatenate([F[s][st] for s in speakers for st in F[s]])
        Y = np.concatenate([D[s][st].reshape(len(D[s][st]), -1) for s in speakers for st in F[s]])
        G = X.T @ X
        scale = max(float(np.trace(G)) / max(len(G), 1), 1e-300)
        return np.linalg.solve(G + lam * scale * np.eye(len(G)), X.T @ Y)

    speakers = list(F)
    if ridge != "auto":
        return solve(speakers, float(ridge)), float(ridge)
    if len(speakers) < 2:
        lam = float(DECODER_RIDGES[len(DECODER_RIDGES) // 2 - 1])
        return solve(speakers, lam), lam
    err = {}
    for lam in DECODER_RIDGES:
        e = 0.0
        for h in speakers:
            G = solve([s for s in speakers if s != h], lam)
            for st in F[h]:
                e += float(np.sum((F[h][st] @ G - D[h][st].reshape(len(D[h][st]), -1)) ** 2))
        err[lam] = e
    lam = min(err, key=err.get)
    return solve(speakers, lam), float(lam)
