"""Restyling the video itself (Chuang, thesis Ch. 2, Fig. 2.6): the emotion of a face in video changed
through the appearance model, and the edited faces rendered back into the frames.

* :class:`AppearanceStyleModel` is one model file holding an
  :class:`~faceretarget.capture.AppearanceModel` (shape + shape-free texture PCA, one configuration
  vector per frame, Eq. 2.3) and a :class:`~faceretarget.style.StyleModel` fitted on the
  configuration vectors of takes of one text in several styles.  The capture and style methods
  never import each other; this composite, in the pipelines layer, joins them.  The takes are
  aligned to the reference take's timeline by their 68 face points (head motion removed,
  :func:`~faceretarget.pipelines.face_take`; DTW of face features refined by re-alignment by
  style, as ``style fit`` aligns face takes), and the style model is fitted on the aligned
  configuration vectors.
* :func:`fit_appearance_style` does it from videos (``faceretarget appearance fit --take
  neutral=N.mp4 --take angry=A.mp4 ...``): every take is tracked once, the appearance model is
  fitted on all their frames with a face (and any extra videos), each take is encoded, the takes
  are aligned and the style model fitted.
* :func:`restyle_video` (``faceretarget restyle --video IN.mp4 --appearance M.npz --to angry``):
  the input is tracked, every frame with a face encoded, the vectors restyled (known expression
  with ``source``, else unknown), and each edited vector decoded to a shape and a texture, warped
  onto the edited shape at the face's place in the frame (inverse of the frame's Procrustes
  similarity), and composited into the input frame, feathered at the face's boundary
  (:class:`~faceretarget.capture.FaceCompositor`); frames without a face are copied unchanged, the
  input's audio stream is copied in, and the mp4 appears whole or not at all.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from itertools import chain
from pathlib import Path

import numpy as np

from ..base import Model
from ..capture import AppearanceModel, Capture, FaceCompositor
from ..errors import InvalidDataError
from ..files import atomic_path, check_output_path
from ..io import iter_frames, probe_video, write_video
from ..performance import Performance
from ..retarget import neutral_face
from ..style import (
    Restyled,
    SpeakerStyleModel,
    StyleModel,
    align_performances,
    frame_vectors,
    realign_by_style,
    warp_performance,
)
from ._animate import face_frame, face_take, tracked_take
from ._capture import _check_memory, _frames_stated, _valid_frames, capture_take, tracked_videos

__all__ = ["AppearanceStyleModel", "RestyledVideo", "fit_appearance_style", "restyle_video", "write_face_video",
           "composited_frames", "align_vector_takes", "speaker_edited_landmarks"]


def _quiet(*_a) -> None:
    return None


def align_vector_takes(vectors: Mapping[str, Performance], faces: Mapping[str, Performance] | None = None,
                       reference: str | None = None, *, realign: int = 2,
                       window_s: float | None = None) -> dict[str, Performance]:
    """Configuration-vector takes of one text put on the reference take's timeline.

    Parameters
    ----------
    vectors : mapping of style to Performance
        Weight takes of configuration vectors (:meth:`AppearanceModel.to_performance`).
    faces : mapping of style to Performance, optional
        The same takes' 68 face points (:func:`~faceretarget.pipelines.face_take`, same times as
        ``vectors[style]``): aligned by DTW of their face features, refined by ``realign``
        iterations of re-alignment by style.  Without them, the vectors' own face features.
    reference : str, optional
        The style whose timeline the others are put on (default: the first).
    realign : int
        Iterations of :func:`~faceretarget.style.realign_by_style` (0: none).
    window_s : float, optional
        Sakoe-Chiba band of the DTW, seconds.

    Returns
    -------
    dict of style to Performance
        Every take resampled at the reference's times (the reference as given).
    """
    if len(vectors) < 2:
        raise InvalidDataError(f"give configuration-vector takes in at least 2 styles, got {len(vectors)}")
    ref = reference or next(iter(vectors))
    if ref not in vectors:
        raise InvalidDataError(f"reference style '{ref}' is not among the takes ({', '.join(vectors)})")
    if faces is not None:
        missing = [k for k in vectors if k not in faces]
        if missing:
            raise InvalidDataError(f"no face take for style(s) {', '.join(missing)}")
        for k, p in vectors.items():
            if faces[k].n_frames != p.n_frames:
                raise InvalidDataError(f"{p.source}: {p.n_frames} vectors but {faces[k].n_frames} face frames")
    out = {}
    for k, p in vectors.items():
        if k == ref:
            out[k] = p
            continue
        if faces is not None:
            al = align_performances(faces[ref], faces[k], by="face", window_s=window_s)
            if realign > 0:
                al = realign_by_style(faces[ref], faces[k], al, iterations=int(realign), window_s=window_s)
        else:
            al = align_performances(vectors[ref], p, by="face", window_s=window_s)
        out[k] = warp_performance(p, al)
    return out


class AppearanceStyleModel(Model):
    """An appearance model and a style model fitted on its configuration vectors (module docstring).

    Parameters
    ----------
    style : dict, optional
        :class:`~faceretarget.style.StyleModel` parameters (default: its defaults, the settings
        chosen by cross-validation on the training frames).
    realign : int
        Iterations of re-alignment by style when the takes are aligned by their face points.

    Attributes
    ----------
    appearance_ : AppearanceModel
    style_ : StyleModel
        Fitted on the aligned configuration vectors; frames are ``(D,)`` vectors named by
        ``appearance_.names_``.
    reference_ : str
        The style the takes were aligned to.
    """

    def __init__(self, style: dict | None = None, realign: int = 2):
        self.style = style
        self.realign = realign

    @property
    def styles_(self) -> list[str]:
        """The style model's styles."""
        self._check_fitted("styles_")
        return list(self.style_.styles_)

    def fit(self, appearance: AppearanceModel, vectors: Mapping[str, Performance],
            faces: Mapping[str, Performance] | None = None, reference: str | None = None) -> AppearanceStyleModel:
        """Align configuration-vector takes (:func:`align_vector_takes`) and fit the style model.

        Parameters
        ----------
        appearance : AppearanceModel
            Fitted; it encoded ``vectors``.  Kept as it is (not refitted).
        vectors : mapping of style to Performance
            Weight takes of ``(T_s, D)`` configuration vectors named by ``appearance.names_``.
        faces : mapping of style to Performance, optional
            The takes' 68 face points, to align by (see :func:`align_vector_takes`).
        reference : str, optional
            Default: the first style.

        Returns
        -------
        self
        """
        ref = reference or next(iter(vectors))
        aligned = align_vector_takes(vectors, faces, ref, realign=self.realign)
        return self.fit_aligned(appearance, {k: frame_vectors(p) for k, p in aligned.items()}, reference=ref)

    def fit_aligned(self, appearance: AppearanceModel, frames: Mapping[str, np.ndarray],
                    reference: str | None = None) -> AppearanceStyleModel:
        """Fit the style model on configuration vectors already aligned frame by frame.

        Parameters
        ----------
        appearance : AppearanceModel
            Fitted.
        frames : mapping of style to (C, D) float
            Same ``C`` for every style; ``D = len(appearance.names_)``.
        reference : str, optional
            The style the frames were aligned to (default: the first).

        Returns
        -------
        self
        """
        appearance._check_fitted("fit_aligned")
        D = len(appearance.names_)
        arrs = {}
        for k, v in frames.items():
            a = np.asarray(v, np.float64)
            if a.ndim != 2 or a.shape[1] != D:
                raise InvalidDataError(f"style '{k}': configuration vectors must be (C, {D}), got {a.shape}")
            arrs[k] = a
        ref = reference or next(iter(arrs))
        if ref not in arrs:
            raise InvalidDataError(f"reference style '{ref}' is not among the takes ({', '.join(arrs)})")
        order = {ref: arrs[ref], **{k: v for k, v in arrs.items() if k != ref}}
        first = order[ref]
        template = appearance.to_performance(first[:2], times=np.arange(2) / 25.0, fps=25.0)
        self.style_ = StyleModel(**dict(self.style or {})).fit_frames(order, template=template)
        self.appearance_ = appearance
        self.reference_ = ref
        return self

    def _check_style(self, name: str, what: str) -> None:
        if name not in self.style_.styles_:
            raise InvalidDataError(f"unknown {what} style '{name}'; the model has {', '.join(self.style_.styles_)}")

    def transform(self, vectors: np.ndarray, to: str, amount: float = 1.0, *, source: str | None = None,
                  window: int | None = None, margin: float = 0.5, warn: bool = True) -> Restyled:
        """Configuration vectors restyled to ``to`` (known expression with ``source``, else unknown).

        Parameters
        ----------
        vectors : (T, D) float
            Configuration vectors of consecutive frames (:meth:`AppearanceModel.transform`).
        to : str
            Target style.
        amount : float
            0 keeps the input (exactly), 1 is the target, > 1 exaggerates (Eq. 2.15).
        source : str, optional
            The input's style when known (asymmetric model); else inferred (symmetric model).
        window : int, optional
            Frames over which an inferred style is held constant (default: all).
        margin : float
            Range guard threshold (:class:`~faceretarget.style.RangeReport`).

        Returns
        -------
        Restyled
            ``frames`` (T, D): the edited vectors (signed; never clipped).
        """
        self._check_fitted()
        self._check_style(to, "target")
        if source is not None:
            self._check_style(source, "source")
        x = np.asarray(vectors, np.float64)
        D = len(self.appearance_.names_)
        if x.ndim != 2 or x.shape[1] != D:
            raise InvalidDataError(f"configuration vectors must be (T, {D}), got {x.shape}")
        if source is not None:
            return self.style_.known(x, source, to, amount, margin=margin, warn=warn)
        return self.style_.unknown(x, to, amount, window=window, margin=margin, warn=warn)


# --------------------------------------------------------------------------------------------- fitting
def fit_appearance_style(takes: Mapping[str, str | os.PathLike], *, videos: Sequence[str | os.PathLike] = (),
                         reference: str | None = None, shape_variance: float = 0.99,
                         texture_variance: float = 0.80, width: int = 128, style: dict | None = None,
                         realign: int = 2, log: Callable[..., None] = _quiet, **capture) -> AppearanceStyleModel:
    """An :class:`AppearanceStyleModel` from videos of one person saying one text in several styles.

    Parameters
    ----------
    takes : mapping of style to video path
        At least two styles.
    videos : sequence of paths
        More footage of the same person for the appearance model only.
    reference : str, optional
        The style the others are aligned to (default ``"neutral"`` when given, else the first).
    shape_variance, texture_variance, width
        :class:`~faceretarget.capture.AppearanceModel` parameters.
    style : dict, optional
        :class:`~faceretarget.style.StyleModel` parameters.
    realign : int
        Iterations of re-alignment by style.
    **capture
        :func:`~faceretarget.pipelines.capture_take` options (``landmarker``, ``max_frames``,
        ``max_gap``, ``smooth``, ``progress``).

    Raises
    ------
    InvalidDataError
        Fewer than two styles, a reference without a take, too little memory (before tracking).
    """
    if len(takes) < 2:
        raise InvalidDataError(f"give takes in at least 2 styles (--take STYLE=VIDEO), got {len(takes)}")
    ref = reference or ("neutral" if "neutral" in takes else next(iter(takes)))
    if ref not in takes:
        raise InvalidDataError(f"reference style '{ref}' has no take (styles: {', '.join(takes)})")
    paths = {k: Path(v) for k, v in takes.items()}
    extra = [Path(v) for v in videos]
    names = ", ".join(str(p) for p in [*paths.values(), *extra])
    _check_memory(width, sum(_frames_stated(v, capture.get("max_frames")) for v in [*paths.values(), *extra]), names)
    caps = {k: capture_take(p, audio=False, neutral_percentile=5.0, log=log, **capture) for k, p in paths.items()}
    more = list(tracked_videos(extra, log=log, **capture))
    sources = [(paths[k], c) for k, c in caps.items()] + more
    lms = np.concatenate([c.landmarks[c.valid] for _, c in sources])
    _check_memory(width, lms.shape[0], names)
    t0 = time.perf_counter()
    app = AppearanceModel(shape_variance, texture_variance, width=width)
    app.fit(chain.from_iterable(_valid_frames(v, c) for v, c in sources), lms)
    log(f"fitted the appearance model on {lms.shape[0]} frames in {time.perf_counter() - t0:.1f} s: "
        f"{app.n_shape} shape modes, texture modes R/G/B {'/'.join(map(str, app.n_texture))}, canvas "
        f"{app.warp_.shape[1]}x{app.warp_.shape[0]}")
    vectors = {k: _encode(paths[k], caps[k], app) for k in caps}
    n0 = neutral_face(tracked_take(caps[ref]).points, tracked_take(caps[ref]).weights)
    faces = {k: face_take(c, neutral=n0) for k, c in caps.items()}
    order = [ref] + [k for k in takes if k != ref]
    t0 = time.perf_counter()
    model = AppearanceStyleModel(style, realign).fit(app, {k: vectors[k] for k in order},
                                                      {k: faces[k] for k in order}, reference=ref)
    S = model.style_
    log(f"fitted the style model on {len(order)} takes aligned to '{ref}' by their face points in "
        f"{time.perf_counter() - t0:.1f} s: {S.n_components_} PCA components of {len(app.names_)}-dimensional "
        f"configuration vectors; settings {S.settings_}")
    return model


def _encode(path: Path, cap: Capture, app: AppearanceModel) -> Performance:
    v = cap.valid
    vec = app.transform(_valid_frames(path, cap), cap.landmarks[v])
    return app.to_performance(vec, cap.times[v], fps=cap.fps, source=str(path))


# --------------------------------------------------------------------------------------------- rendering
@dataclass
class RestyledVideo:
    """What :func:`restyle_video` did.

    Attributes
    ----------
    path : Path
        The mp4 written.
    frames : int
        Frames written (the input's).
    face_frames : (F,) int
        Indices of the frames with a face (the others are copied unchanged).
    vectors : (F, D) float
        The input's configuration vectors.
    edited : (F, D) float
        The restyled ones.
    restyled : Restyled
        The style model's result (range report; inferred style weights for the unknown task).
    fps : float
    codec : str
    """

    path: Path
    frames: int
    face_frames: np.ndarray
    vectors: np.ndarray
    edited: np.ndarray
    restyled: Restyled | None
    fps: float
    codec: str


def composited_frames(video: str | os.PathLike, capture: Capture, appearance: AppearanceModel,
                      vectors: np.ndarray, *, feather: float = 0.08, morph: bool = True) -> Iterator[np.ndarray]:
    """The video's frames with the faces of ``vectors`` composited in (frames without a face unchanged).

    Parameters
    ----------
    video : path
    capture : Capture
        The video's tracking (its ``valid`` frames are the ones with a face).
    appearance : AppearanceModel
    vectors : (F, D) float
        One configuration vector per valid frame, in order.
    feather, morph
        :class:`~faceretarget.capture.FaceCompositor` options.

    Yields
    ------
    (H, W, 3) uint8
    """
    valid = capture.valid
    idx = np.flatnonzero(valid)
    vec = np.asarray(vectors, np.float64)
    if vec.shape != (len(idx), len(appearance.names_)):
        raise InvalidDataError(f"{video}: {vec.shape} vectors for {len(idx)} frames with a face and "
                               f"{len(appearance.names_)} model dimensions")
    L = capture.landmarks[valid]
    _, a, c = appearance.shape_params(L)
    tracked = L[:, appearance.points_, :2]
    comp = FaceCompositor(appearance, feather=feather, morph=morph)
    k = 0
    for i, _t, rgb in iter_frames(video, max_frames=capture.n_frames):
        if valid[i]:
            yield comp.render(rgb, vec[k], a[k], c[k], tracked=tracked[k])
            k += 1
        else:
            yield rgb


def write_face_video(out: str | os.PathLike, video: str | os.PathLike, capture: Capture,
                     appearance: AppearanceModel, vectors: np.ndarray, *, feather: float = 0.08,
                     morph: bool = True, progress: bool = False) -> tuple[int, str, float]:
    """Write :func:`composited_frames` as an mp4 at the input's frame rate, with its audio copied in.

    Written whole or not at all (the input is never overwritten).

    Returns
    -------
    (frames written, codec, fps)
    """
    from tqdm.auto import tqdm

    out = check_output_path(out)
    info = probe_video(video)
    fps = float(capture.fps)
    with tqdm(total=capture.n_frames, disable=not progress, desc="render", unit="frame", leave=False) as bar:
        n = [0]

        def tick() -> None:
            n[0] += 1
            bar.update(1)

        with atomic_path(out, protect=(video,)) as tmp:
            codec = write_video(tmp, composited_frames(video, capture, appearance, vectors, feather=feather,
                                                       morph=morph), fps,
                                audio_from=video if info.has_audio else None,
                                audio_duration=capture.n_frames / fps if info.has_audio else None, on_frame=tick)
    return n[0], codec, fps


def speaker_edited_landmarks(capture: Capture, speakers: SpeakerStyleModel, to: str, amount: float = 1.0, *,
                             neutral: Capture | None = None) -> tuple[np.ndarray, Restyled]:
    """A capture's landmarks with the face edited by a speaker model (the video route of issue 27).

    The capture's 68 face points, head removed (:func:`~faceretarget.pipelines.face_take`), and its
    ARKit scores are edited by ``speakers`` (:meth:`SpeakerStyleModel.transform`, the person's rest
    from ``neutral``, a capture of them in neutral, or else from the take itself); the change of every
    frame is moved back into the image by that frame's similarity (:func:`face_frame`) and spread from
    the 68 points to all 478 landmarks piecewise linearly over the mean tracked face (nearest point
    outside the 68 points' hull).

    Returns
    -------
    landmarks : (F, 478, 3) float
        The edited landmarks of the ``F`` frames with a face (pixels, MediaPipe's axes).
    restyled : Restyled
        The speaker model's result (face-take points; range report).
    """
    from ..capture import MEDIAPIPE_68

    tr = tracked_take(capture)
    ntr = tracked_take(neutral) if neutral is not None else tr
    n0 = neutral_face(ntr.points, ntr.weights)
    face = face_take(tr, neutral=n0).replace(weights=tr.weights, names=list(tr.names))
    nface = None if neutral is None else face_take(ntr, neutral=n0).replace(weights=ntr.weights,
                                                                          names=list(ntr.names))
    res = speakers.transform(face, to, amount, neutral=nface)
    s, R, _ = face_frame(tr, neutral=n0)
    d68 = s[:, None, None] * np.einsum("tpj,tij->tpi", res.frames - face.points, R) * np.array([1.0, -1.0, -1.0])
    L = np.asarray(capture.landmarks[capture.valid], np.float64)
    W = _spread_weights(L[:, MEDIAPIPE_68, :2].mean(0), L[:, :, :2].mean(0))
    return L + np.einsum("lp,tpj->tlj", W, d68), res


def _spread_weights(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``(len(dst), len(src))`` piecewise-linear interpolation weights over the Delaunay triangles of
    the 2-D points ``src``; points of ``dst`` outside them take their nearest ``src`` point."""
    from scipy.spatial import Delaunay

    tri = Delaunay(src)
    simplex = tri.find_simplex(dst)
    W = np.zeros((len(dst), len(src)))
    inside = simplex >= 0
    T = tri.transform[simplex[inside]]
    b = np.einsum("nij,nj->ni", T[:, :2], dst[inside] - T[:, 2])
    bary = np.c_[b, 1.0 - b.sum(1)]
    rows = np.flatnonzero(inside)
    for k in range(3):
        W[rows, tri.simplices[simplex[inside], k]] += bary[:, k]
    out = np.flatnonzero(~inside)
    if out.size:
        W[out, np.argmin(((dst[out, None] - src[None]) ** 2).sum(-1), axis=1)] = 1.0
    return W


def restyle_video(video: str | os.PathLike, model: AppearanceStyleModel | AppearanceModel, to: str,
                  out: str | os.PathLike, *, source: str | None = None, amount: float = 1.0,
                  window: float | None = None, margin: float = 0.5, feather: float = 0.08, morph: bool = True,
                  speakers: SpeakerStyleModel | None = None, neutral: str | os.PathLike | None = None,
                  log: Callable[..., None] = _quiet, progress: bool = False, **capture) -> RestyledVideo:
    """Change the emotion of the face in a video and write the edited video (module docstring).

    Parameters
    ----------
    video : path
        Input video of the person the model's appearance model was fitted on.
    model : AppearanceStyleModel or AppearanceModel
        The person's appearance model (with their own style model; a plain appearance model with
        ``speakers``).
    to : str
        Target style.
    out : path
        Output ``.mp4``.
    source : str, optional
        The video's own style when known; else inferred.
    amount : float
        0 keeps the style (the output is the model's reconstruction of the input), 1 the target,
        > 1 exaggerates.
    window : float, optional
        Seconds over which an inferred style is held constant (default: the whole video).
    margin : float
        Range guard threshold (a :class:`~faceretarget.errors.StyleRangeWarning` beyond it).
    feather : float
        Blend width at the face boundary, share of the face width.
    morph : bool
        Warp the frame around the face with the edited outline.
    speakers : SpeakerStyleModel, optional
        Edit with a model learned from other speakers instead (issue 27): the face's shape is edited
        by it (:func:`speaker_edited_landmarks`) and re-encoded by the appearance model; the texture
        stays the input's (``source`` and ``window`` do not apply).
    neutral : path, optional
        With ``speakers``: a neutral video of the same person, their rest face (default the input).
    progress : bool
        Progress bars while tracking and rendering.
    **capture
        :func:`~faceretarget.pipelines.capture_take` options.

    Returns
    -------
    RestyledVideo

    Raises
    ------
    InvalidDataError
        Unknown style (before tracking).
    InputFileError
        Unreadable video or no face in it (naming the file).
    """
    model._check_fitted()
    if speakers is not None:
        speakers._check_fitted()
        speakers._check_style(to, "target")
        app = model.appearance_ if isinstance(model, AppearanceStyleModel) else model
    else:
        if not isinstance(model, AppearanceStyleModel):
            raise InvalidDataError("restyling a video needs an appearance model with its style model "
                                   "('appearance fit --take ...'), or a speaker style model (speakers)")
        model._check_style(to, "target")
        if source is not None:
            model._check_style(source, "source")
        app = model.appearance_
    out = check_output_path(out)
    cap = capture_take(video, audio=False, progress=progress, log=log, **capture)
    faces = np.flatnonzero(cap.valid)
    t0 = time.perf_counter()
    vec = app.transform(_valid_frames(Path(video), cap), cap.landmarks[cap.valid])
    log(f"encoded {len(faces)} frames with a face in {time.perf_counter() - t0:.1f} s")
    if speakers is not None:
        ncap = None if neutral is None else capture_take(neutral, audio=False, log=log, **capture)
        L, res = speaker_edited_landmarks(cap, speakers, to, amount, neutral=ncap)
        edited = vec.copy()
        edited[:, :app.n_shape] = app.shape_params(L)[0]
        log(f"edited the face's shape of {len(faces)} frames -> {to} at amount {amount:g} with the speaker model "
            f"({speakers.space}; x{speakers.gain_[to]:.2f} of the training speakers' typical {to}); range score "
            f"{res.range.score:.2f}")
        t0 = time.perf_counter()
        n, codec, fps = write_face_video(out, video, cap, app, edited, feather=feather, morph=morph,
                                         progress=progress)
        log(f"rendered {n} frames in {time.perf_counter() - t0:.1f} s ({codec})")
        return RestyledVideo(out, n, faces, vec, edited, res, fps, codec)
    win = None if window is None else max(1, int(round(window * cap.fps)))
    res = model.transform(vec, to, amount, source=source, window=win, margin=margin)
    if source is None and res.style_weights is not None:
        w = res.style_weights.mean(0)
        top = sorted(zip(model.styles_, w, strict=True), key=lambda x: -x[1])
        log("inferred style (mean weights): " + ", ".join(f"{k} {v:.2f}" for k, v in top))
    log(f"restyled {len(faces)} frames {source or '(inferred)'} -> {to} at amount {amount:g}; range score "
        f"{res.range.score:.2f}{' (outside the training range)' if res.range.outside else ''}")
    t0 = time.perf_counter()
    n, codec, fps = write_face_video(out, video, cap, app, res.frames, feather=feather, morph=morph,
                                     progress=progress)
    log(f"rendered {n} frames in {time.perf_counter() - t0:.1f} s ({codec})")
    return RestyledVideo(out, n, faces, vec, np.asarray(res.frames, np.float64), res, fps, codec)
