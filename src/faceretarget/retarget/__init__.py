"""Blendshape retargeting (Chuang Ch. 3): keyshape selection and rigid head-motion removal so far."""

from .rigid import RigidAligner, fit_rigid, select_rigid_markers
from .selection import SELECTION_METHODS, pca_extrema, select_keyshapes

__all__ = ["pca_extrema", "select_keyshapes", "SELECTION_METHODS", "RigidAligner", "fit_rigid",
           "select_rigid_markers"]
