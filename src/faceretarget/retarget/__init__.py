"""Blendshape retargeting through keyshapes (Chuang 2004, Ch. 3).

================================ ================================================================
:mod:`._retargeter`              :class:`BlendshapeRetargeter`: signed or non-negative solve
                                 (Eq. 3.1/3.2), take-adaptive denoising, regions
:mod:`._regions`                 face regions solved separately, blended across smooth seams
:mod:`._consistency`             the consistency check of an artist's target keyshapes
:mod:`._landmarks`               :class:`LandmarkSolver`: a character's own shapes from tracked
                                 landmarks, the tracker's scores as prior (``animate``)
================================ ================================================================

Shared pieces live below the methods: rigid head-motion removal, keyshape selection and NNLS in
:mod:`faceretarget.numerics`, keyshape folders (export for the artist, read-back) in
:mod:`faceretarget.io`.
"""

from ._consistency import ConsistencyReport, check_consistency
from ._landmarks import STABLE68, LandmarkResult, LandmarkSolver, neutral_face, similarity_fit
from ._regions import Regions, default_regions, load_regions
from ._retargeter import SOLVERS, BlendshapeRetargeter, RetargetResult

__all__ = ["BlendshapeRetargeter", "RetargetResult", "SOLVERS", "Regions", "default_regions", "load_regions",
           "check_consistency", "ConsistencyReport",
           "LandmarkSolver", "LandmarkResult", "neutral_face", "similarity_fit", "STABLE68"]
