"""Example-based expression cloning (Pyun et al. 2003).

Sec. 2 key-model composition (:mod:`.composition`, tables in :mod:`.tables`), Sec. 3 feature
parameterisation (:mod:`.features`), Sec. 4 cardinal basis weight functions (:mod:`.cardinal`) and
runtime blending (:class:`ExpressionCloner`), the standard key-model sets (:mod:`.keysets`), and the
Noh & Neumann peer baseline (:mod:`.noh`).
"""

from .cardinal import CardinalBasis, cubic_bspline
from .cloner import METHODS, ExpressionCloner
from .composition import build_key_models, compose_key_models, vertex_importance
from .features import FeaturePCA, feature_vectors, resolve_features
from .keysets import KEYSETS, keymodel_pair, keymodel_rig, keyset_weights
from .tables import EMOTIONS, VISEMES, combined_weight_vectors, emotion_vectors, viseme_vectors
from .temporal import denoise_take, estimate_noise_sigma, sure_whittaker

__all__ = [
    "ExpressionCloner", "METHODS", "CardinalBasis", "cubic_bspline", "FeaturePCA", "feature_vectors",
    "resolve_features", "build_key_models", "compose_key_models", "vertex_importance", "KEYSETS",
    "keymodel_pair", "keymodel_rig", "keyset_weights", "EMOTIONS", "VISEMES", "combined_weight_vectors",
    "emotion_vectors", "viseme_vectors", "denoise_take", "estimate_noise_sigma", "sure_whittaker",
]
