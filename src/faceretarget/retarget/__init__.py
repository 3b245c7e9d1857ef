"""Blendshape retargeting (Chuang Ch. 3): keyshape selection, rigid head-motion removal and batched NNLS so far."""

from .export import export_keyshapes, read_target_keyshapes
from .nnls import extremes_removed, solve_nnls, temporal_filter
from .rigid import RigidAligner, fit_rigid, select_rigid_markers
from .selection import (
    SELECTION_METHODS,
    hull_selection,
    kmeans_selection,
    nnls_greedy,
    pca_extrema,
    reconstruction_error,
    select_keyshapes,
)

__all__ = ["pca_extrema", "select_keyshapes", "SELECTION_METHODS", "RigidAligner", "fit_rigid",
           "select_rigid_markers", "solve_nnls", "temporal_filter", "extremes_removed", "hull_selection",
           "kmeans_selection", "nnls_greedy", "reconstruction_error", "export_keyshapes", "read_target_keyshapes"]
