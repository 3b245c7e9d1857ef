"""Shared numerics: the solvers and signal tools several methods use.

========================== ============================================================================
:mod:`._nnls_solve`        batched exact NNLS with bounds, L1/L2, temporal and missing-marker terms
                           (Chuang Eq. 3.1/3.2): mask patterns, rank handling, the solvers below
:mod:`._nnls_box_qp`       every frame's box-constrained QP: the compiled kernel in :mod:`._nnls_numba`,
                           else the vectorised active-set methods
:mod:`._nnls_active_set`   block principal pivoting and Lawson-Hanson, vectorised over frames
:mod:`._nnls_linalg`       stacked free-set solves, blocked products, least-squares data of the solvers
:mod:`._nnls_temporal`     the take-wide QP with temporal coupling (active set, projected Newton)
:mod:`._nnls_checks`       input checks of the NNLS solve and the weight filter
:mod:`._nnls_filter`       low-pass filter of the weight curves
:mod:`._bounded`           least squares inside a weight range for whole takes (the shift onto NNLS)
:mod:`._face`              is a take a face: its span, marker labels, stray and mostly-missing markers
:mod:`._denoise`           take-adaptive denoising: noise level from the take's spectrum, SURE-chosen
                           Whittaker smoothing in an ensemble of bases
:mod:`._rigid`             rigid fits (Kabsch/Umeyama, similarity), rigid marker selection,
                           :class:`RigidAligner` (Chuang Ch. 3 head-motion removal)
:mod:`._rotations`         nearest rotations of matrices, exp-map blending of key rotations
:mod:`._selection`         keyshape selection (Chuang Sec. 3.2: PCA extrema, convex hull, k-means, and
                           NNLS greedy pursuit, pivoted QR)
:mod:`._smooth`            smoothstep ramps
========================== ============================================================================
"""

from ._bounded import (
    EXAMPLE_RANGE,
    FACS_RANGE,
    WeightRange,
    auto_weight_range,
    range_metric,
    solve_bounded,
    solve_inequality,
    weight_range,
)
from ._denoise import denoise_take, estimate_noise_sigma, sure_whittaker
from ._face import FACE_MAX_MM, MESH_FACE_MAX_MM, FaceMarkers, face_markers, face_mesh
from ._nnls_box_qp import compile_kernels
from ._nnls_filter import extremes_removed, filter_cutoff_hz, temporal_filter
from ._nnls_solve import solve_nnls
from ._rigid import AlignResult, RigidAligner, fit_rigid, select_rigid_markers, similarity_fit
from ._rotations import blend_rotations, nearest_rotation
from ._runs import runs
from ._selection import (
    SELECTION_METHODS,
    hull_selection,
    kmeans_selection,
    nnls_greedy,
    nnls_greedy_path,
    nnls_weights,
    pca_extrema,
    pivoted_qr,
    reconstruction_error,
    select_keyshapes,
)
from ._smooth import smoothstep

__all__ = [
    "solve_nnls", "compile_kernels", "solve_bounded", "range_metric", "solve_inequality", "weight_range", "auto_weight_range", "WeightRange", "FACS_RANGE",
    "EXAMPLE_RANGE", "temporal_filter", "extremes_removed", "filter_cutoff_hz",
    "denoise_take", "estimate_noise_sigma", "sure_whittaker",
    "RigidAligner", "AlignResult", "fit_rigid", "similarity_fit", "select_rigid_markers", "nearest_rotation", "blend_rotations", "runs",
    "SELECTION_METHODS", "select_keyshapes", "pca_extrema", "hull_selection", "kmeans_selection", "nnls_greedy",
    "nnls_greedy_path", "nnls_weights", "pivoted_qr", "reconstruction_error",
    "smoothstep", "FaceMarkers", "face_markers", "face_mesh", "FACE_MAX_MM", "MESH_FACE_MAX_MM",
]
