"""Blendshape retargeting (Chuang Ch. 3): rigid head-motion removal, keyshape selection and export, batched
NNLS, the ``BlendshapeRetargeter`` with regions, and the consistency check of an artist's keyshapes."""

from .consistency import ConsistencyReport, check_consistency
from .export import export_keyshapes, read_marker_labels, read_target_keyshapes
from .nnls import extremes_removed, solve_nnls, temporal_filter
from .regions import Regions, default_regions, load_regions
from .retargeter import SOLVERS, BlendshapeRetargeter
from .rigid import RigidAligner, fit_rigid, select_rigid_markers
from .selection import (
    SELECTION_METHODS,
    hull_selection,
    kmeans_selection,
    nnls_greedy,
    pca_extrema,
    pivoted_qr,
    reconstruction_error,
    select_keyshapes,
)

__all__ = ["pca_extrema", "select_keyshapes", "SELECTION_METHODS", "RigidAligner", "fit_rigid",
           "select_rigid_markers", "solve_nnls", "temporal_filter", "extremes_removed", "hull_selection",
           "kmeans_selection", "nnls_greedy", "pivoted_qr", "reconstruction_error", "export_keyshapes", "read_target_keyshapes",
           "read_marker_labels", "BlendshapeRetargeter", "SOLVERS", "Regions", "default_regions", "load_regions",
           "check_consistency", "ConsistencyReport"]
