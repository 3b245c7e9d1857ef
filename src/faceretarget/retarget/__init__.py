"""Blendshape retargeting (Chuang Ch. 3); so far the keyshape selection the cloning key sets use."""

from .selection import SELECTION_METHODS, pca_extrema, select_keyshapes

__all__ = ["pca_extrema", "select_keyshapes", "SELECTION_METHODS"]
