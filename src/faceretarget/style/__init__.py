"""Emotion editing that keeps the lip sync: style/content models (Chuang 2004, Ch. 2 and 5).

Takes of the same text in several emotions are aligned (dynamic time warping of speech or face
features, :mod:`._align`), compressed by PCA and separated into *style* (the emotion) and
*content* (what is said) by bilinear models (Tenenbaum & Freeman 2000; :mod:`._bilinear`).  A
:class:`StyleModel` then changes the emotion of a new take whose emotion is known
(:meth:`StyleModel.known`) or not (:meth:`StyleModel.unknown`), learns an untrained emotion from
examples (:meth:`StyleModel.add_style`), and interpolates or exaggerates between emotions with a
guard that reports when the result leaves the range of the training data.
:class:`ExpressionSliders` blends per-emotion retargets over time (Ch. 5, Eq. 5.1).
:class:`SpeakerStyleModel` learns emotions from several speakers in a space that does not depend on
who is speaking, so that edits and recognition carry to a speaker it has never seen.
See ``docs/style.md``.
"""

from ._align import (
    Alignment,
    align_audio,
    align_features,
    align_performances,
    dtw_path,
    face_features,
    frame_vectors,
    path_to_times,
    realign_by_style,
    resample,
    warp_performance,
)
from ._bilinear import (
    AsymmetricBilinearModel,
    BilinearModel,
    InferResult,
    SymmetricBilinearModel,
    choose_dims,
)
from ._features import AUDIO_FEATURES, PiecewiseWarp, audio_features, time_warp_audio
from ._model import (
    RangeReport,
    Restyled,
    StyleFitWarning,
    StyleModel,
    StyleRangeWarning,
    bundle_frames,
    unbundle_frames,
)
from ._select import (
    GRID,
    STYLE_RIDGE_GRID,
    Selection,
    cv_folds,
    group_folds,
    kernel_fit,
    kernel_predict,
    kernel_rows,
    select_settings,
    select_style_ridge,
)
from ._sliders import AlphaCurves, ExpressionSliders, alpha_curves
from ._speakers import (
    DECODER_RIDGES,
    REGIONS68,
    SPACES,
    Recognition,
    SpeakerStyleModel,
    align_speaker_takes,
    canonical_face,
)

__all__ = [
    "StyleModel",
    "SpeakerStyleModel",
    "Recognition",
    "align_speaker_takes",
    "canonical_face",
    "SPACES",
    "REGIONS68",
    "DECODER_RIDGES",
    "Selection",
    "select_settings",
    "select_style_ridge",
    "STYLE_RIDGE_GRID",
    "GRID",
    "cv_folds",
    "group_folds",
    "kernel_fit",
    "kernel_rows",
    "kernel_predict",
    "Restyled",
    "RangeReport",
    "StyleRangeWarning",
    "StyleFitWarning",
    "bundle_frames",
    "unbundle_frames",
    "AsymmetricBilinearModel",
    "SymmetricBilinearModel",
    "InferResult",
    "choose_dims",
    "BilinearModel",
    "Alignment",
    "align_performances",
    "realign_by_style",
    "align_audio",
    "align_features",
    "dtw_path",
    "path_to_times",
    "face_features",
    "frame_vectors",
    "resample",
    "warp_performance",
    "audio_features",
    "time_warp_audio",
    "PiecewiseWarp",
    "AUDIO_FEATURES",
    "ExpressionSliders",
    "AlphaCurves",
    "alpha_curves",
]
