"""Blendshape retargeting (Chuang Ch. 3): keyshape selection, rigid head-motion removal and batched NNLS so far."""

from .nnls import extremes_removed, solve_nnls, temporal_filter
from .rigid import RigidAligner, fit_rigid, select_rigid_markers
from .selection import SELECTION_METHODS, pca_extrema, select_keyshapes

__all__ = ["pca_extrema", "select_keyshapes", "SELECTION_METHODS", "RigidAligner", "fit_rigid",
           "select_rigid_markers", "solve_nnls", "temporal_filter", "extremes_removed"]
