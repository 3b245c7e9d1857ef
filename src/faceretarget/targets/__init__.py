"""Retargeting targets of any parameterisation (Chuang Ch. 3): one abstraction for every kind of character.

The source side of cloning and retargeting (keyshape weights per frame, by any solver, with regions,
smoothing and the consistency check) is the same for every target; a :class:`Target` turns the
``(T, K)`` key weights into its own parameters and writes them.

=========================== ==========================================================================
:class:`MeshTarget`         mesh keyshapes (a :class:`~faceretarget.rig.Rig`): morph targets, as before
:class:`ControlTarget`      keys posed with the target rig's own sliders (a control table): control
                            curves ``c0 + W (C - c0)``, Live Link Face CSV for ARKit controls, the rig's
                            shapes driven by them when the rig is given
:class:`SkeletonTarget`     keys posed on a skeleton (BVH frames, a glTF skin's poses): joint rotations
                            blended in the log map about the rest pose, roots translated linearly, bone
                            lengths kept; BVH and skinned glTF out
:class:`DrawingTarget`      keys drawn in 2-D (SVG paths of one structure, or point sets): points blended
                            linearly; animated SVG (SMIL), per-frame SVGs, PNG / MP4 previews
=========================== ==========================================================================

:func:`read_target` reads any of them from a path (``--target-keys``); ``docs/targets.md`` has the
file formats, the maths and the artist's workflow.
"""

from ._base import MeshTarget, Target
from ._controls import CONTROL_RANGES, ControlTarget, RangeReport
from ._drawing import DrawingTarget
from ._read import TARGET_KINDS, read_target, target_kind
from ._skeleton import SkeletonTarget, bone_lengths

__all__ = ["Target", "MeshTarget", "ControlTarget", "RangeReport", "CONTROL_RANGES", "SkeletonTarget", "DrawingTarget", "bone_lengths",
           "read_target", "target_kind", "TARGET_KINDS", "as_target"]


def as_target(keys) -> Target:
    """``keys`` as a :class:`Target` (a :class:`~faceretarget.rig.Rig` becomes a :class:`MeshTarget`)."""
    from ..rig import Rig

    if isinstance(keys, Target):
        return keys
    if isinstance(keys, Rig):
        return MeshTarget(keys)
    from ..errors import InvalidDataError

    raise InvalidDataError(f"target keys must be a Rig or a Target, got {type(keys).__name__}")
