"""Evaluation metrics of the protocols in ``EVALUATION.md``.

================================ ================================================================
:mod:`._animation_errors`        P1 (and P3): ``rel_motion_pct``, Pyun's Eq. 12 ``err_pct`` and per
                                 axis, vertex and lip errors, the key-blend oracle
:mod:`._head_motion`             P5 head motion: angular speed, motion beats, pitch accents, beat
                                 alignment, the smooth-noise baseline
:mod:`._figures`                 how a command prints a number: meaning, what is good, advice
                                 (``figure_line``)
================================ ================================================================
"""

from ._animation_errors import (
    LIP_LANDMARKS,
    err_pct,
    err_pct_axis,
    lip_vertices,
    lve_mm,
    metrics,
    mve_mm,
    mve_pct_diag,
    oracle_blend,
    oracle_rel_motion_pct,
    rel_motion_pct,
)
from ._figures import FIGURES, Figure, figure_line
from ._head_motion import (
    accent_onsets,
    angular_speed,
    beat_alignment,
    motion_beats,
    perlin_noise,
    pitch_peaks,
    summarize_alignment,
)

__all__ = [
    "rel_motion_pct", "err_pct", "err_pct_axis", "mve_mm", "mve_pct_diag", "lve_mm", "lip_vertices",
    "oracle_blend", "oracle_rel_motion_pct", "metrics", "LIP_LANDMARKS",
    "angular_speed", "motion_beats", "accent_onsets", "pitch_peaks", "beat_alignment", "perlin_noise",
    "summarize_alignment", "Figure", "FIGURES", "figure_line",
]
