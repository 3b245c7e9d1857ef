"""Example-based expression cloning (Pyun, Kim, Chae, Kang and Shin 2003).

================================ ================================================================
:mod:`._tables`                  emotion and viseme key-models as ARKit weight vectors (FACS)
:mod:`._composition`             Sec. 2 and Appendix: per-vertex importance, composition (Eq. 13)
:mod:`._features`                Sec. 3: feature-point displacements, PCA parameter space
:mod:`._cardinal`                Sec. 4: cardinal basis weight functions (linear + cubic B-spline)
:mod:`._cloner`                  :class:`ExpressionCloner`: runtime blending of a whole take
:mod:`._keysets`                 the standard key-model sets of two ARKit-style rigs (P1, ``--keys``)
:mod:`._noh`                     Noh & Neumann 2001, the peer baseline
================================ ================================================================
"""

from ._cardinal import CardinalBasis, cubic_bspline
from ._cloner import METHODS, CloneResult, ExpressionCloner
from ._composition import (
    Importance,
    blend_weight,
    build_key_models,
    compose_displacements,
    compose_key_models,
    propagate_importance,
    raw_importance,
    vertex_importance,
)
from ._features import FeaturePCA, feature_vectors
from ._keysets import KEYSETS, keymodel_pair, keymodel_rig, keyset_weights
from ._noh import NohNeumannCloner, closest_points_on_mesh
from ._tables import (
    EMOTIONS,
    VISEMES,
    combined_weight_vectors,
    emotion_vectors,
    table_shapes,
    viseme_vectors,
    weight_vector,
)

__all__ = [
    "ExpressionCloner", "CloneResult", "METHODS", "CardinalBasis", "cubic_bspline", "FeaturePCA", "feature_vectors",
    "build_key_models", "compose_key_models", "compose_displacements", "vertex_importance", "raw_importance",
    "propagate_importance", "blend_weight", "Importance", "KEYSETS", "keymodel_pair", "keymodel_rig",
    "keyset_weights", "EMOTIONS", "VISEMES", "combined_weight_vectors", "emotion_vectors", "viseme_vectors",
    "weight_vector", "table_shapes", "NohNeumannCloner", "closest_points_on_mesh",
]
