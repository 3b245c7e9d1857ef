"""Skeletal targets: keys are poses of a skeleton, blended as joint rotations (Chuang Fig. 3.15)."""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InvalidDataError
from ..formats import BVH, GLB
from ..io import Bvh, BvhJoint, bvh_pose, bvh_with_pose, bvh_world_positions, write_bvh, write_glb_skeleton
from ..mesh import Mesh
from ..numerics import blend_rotations
from ..rig import Rig
from ..timebase import infer_fps
from ..units import mm_per_unit, normalize_unit
from ._base import Target, _quiet

__all__ = ["SkeletonTarget", "bone_lengths"]


def bone_lengths(positions: np.ndarray, parents) -> np.ndarray:
    """Lengths ``(T, B)`` of the bones (joint to parent) of world joint positions ``(T, J, 3)``, for the
    ``B`` joints that have a parent."""
    p = np.asarray(positions, dtype=np.float64)
    par = np.asarray(parents, dtype=np.int64)
    child = np.flatnonzero(par >= 0)
    return np.linalg.norm(p[:, child] - p[:, par[child]], axis=2)


class SkeletonTarget(Target):
    """Keys given as poses of a skeleton (frames of a BVH file, or of a glTF skin's animation).

    Blending (``params``): every joint's local rotation is blended in the log map about the rest
    pose, ``R_j(w) = R_j0 exp(sum_k w_k log(R_j0^-1 R_jk))``
    (:func:`~faceretarget.numerics.blend_rotations`): exact at each key, a proper rotation for any
    weights (negative ones and sums above 1 from a signed solve too), and a single key's weight
    turns the joint along the arc from rest to key.  The root's position channels are blended
    linearly, ``p(w) = p0 + sum_k w_k (p_k - p0)``; every other joint keeps its offset (and its
    position channels at the rest pose's values), so only rotations move joints and every bone
    keeps its length exactly.  Blending joint positions instead (control vertices) shortens limbs
    between differently bent keys (:func:`bone_lengths` measures it).

    :attr:`solve_keys` is the joints' world positions (forward kinematics) of the rest and key
    poses, a point set in the skeleton's unit.

    Parameters
    ----------
    skeleton : Bvh
        Hierarchy and the poses (frames).
    frames : mapping of str to int
        Key name -> frame holding its pose.
    neutral_frame : int
        The rest pose (weight 0 of every key).
    unit : str
        The skeleton's length unit (BVH files are usually in centimetres).
    source : str, optional
        For messages (default the BVH's file).
    """

    kind = "skeleton"
    key_word = "key poses"
    formats = (BVH, GLB)

    def __init__(self, skeleton: Bvh, frames: Mapping[str, int], neutral_frame: int = 0, *, unit: str = "cm",
                 source: str | None = None) -> None:
        src = source or skeleton.source
        names = list(frames)
        super().__init__(src, names, [f"frame {int(frames[n])}" for n in names])
        T = skeleton.n_frames
        for n, f in [*frames.items(), ("neutral", neutral_frame)]:
            if isinstance(f, bool) or int(f) != f or not 0 <= int(f) < T:
                raise InvalidDataError(f"{src}: key '{n}' is frame {f}, outside the file's frames 0..{T - 1}")
        self.skeleton = skeleton
        self.unit = normalize_unit(unit, what=src)
        self.frames = {n: int(f) for n, f in frames.items()}
        self.neutral_frame = int(neutral_frame)
        idx = [self.frames[n] for n in names]
        rot, pos = bvh_pose(skeleton)
        self.parents = np.array([j.parent for j in skeleton.joints], dtype=np.int64)
        self.rest_rotations = rot[self.neutral_frame]
        self.key_rotations = rot[idx]                                       # (K, J, 4)
        self.rest_positions = pos[self.neutral_frame]
        self.key_positions = pos[idx]
        self._roots = self.parents < 0
        moved = np.abs(self.key_positions[:, ~self._roots] - self.rest_positions[~self._roots]).max(initial=0.0)
        if moved > 0:
            j = int(np.flatnonzero(~self._roots)[np.argmax(
                np.abs(self.key_positions[:, ~self._roots] - self.rest_positions[~self._roots]).max(axis=(0, 2)))])
            warnings.warn(f"{src}: joint '{skeleton.joints[j].name}' has position channels that differ between the "
                          f"key poses (by up to {moved:.3g}); only the roots' positions are blended, so every bone "
                          "keeps its rest length", DataWarning, stacklevel=2)
        world0 = bvh_world_positions(skeleton, rot[[self.neutral_frame]], pos[[self.neutral_frame]])[0]
        worldk = bvh_world_positions(skeleton, self.key_rotations, self.key_positions)
        self.rest_world = world0
        self.key_world = worldk
        self._keys = Rig(Mesh(world0, name="joints"), names, worldk - world0, self.unit, None, None, src)

    @property
    def solve_keys(self) -> Rig:
        return self._keys

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.skeleton.joints]

    def describe(self) -> str:
        return (f"skeleton target {self.name}: {self.n_keys} key poses (frames "
                f"{', '.join(str(f) for f in list(self.frames.values())[:8])}{' ...' if self.n_keys > 8 else ''}), "
                f"rest pose frame {self.neutral_frame}, {len(self.skeleton.joints)} joints")

    def params(self, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local rotations ``(T, J, 4)`` (quaternions x, y, z, w) and translations ``(T, J, 3)``."""
        W = self._weights(weights)
        q = blend_rotations(self.rest_rotations, self.key_rotations, W)
        pos = np.broadcast_to(self.rest_positions, (len(W),) + self.rest_positions.shape).copy()
        r = self._roots
        pos[:, r] = self.rest_positions[r] + np.einsum("tk,kjc->tjc", W, self.key_positions[:, r] - self.rest_positions[r])
        return q, pos

    def world_positions(self, weights: np.ndarray) -> np.ndarray:
        """World joint positions ``(T, J, 3)`` of the rotation blend (forward kinematics)."""
        q, pos = self.params(weights)
        return bvh_world_positions(self.skeleton, q, pos)

    def vertex_blend(self, weights: np.ndarray) -> np.ndarray:
        """World joint positions ``(T, J, 3)`` of the control-vertex blend ``P0 + sum_k w_k (P_k - P0)``
        (for comparison: bones do not keep their lengths)."""
        W = self._weights(weights)
        return self.rest_world + np.einsum("tk,kjc->tjc", W, self.key_world - self.rest_world)

    def rest_bone_lengths(self) -> np.ndarray:
        """(B,) bone lengths of the skeleton (its offsets)."""
        return bone_lengths(self.rest_world[None], self.parents)[0]

    def to_bvh(self, weights: np.ndarray, times: np.ndarray) -> Bvh:
        """The blended poses as a :class:`~faceretarget.io.Bvh` of the skeleton's hierarchy and channels."""
        q, pos = self.params(weights)
        fps = infer_fps(np.asarray(times, dtype=np.float64), default=30.0) if len(times) > 1 else 30.0
        return bvh_with_pose(self.skeleton, q, pos, 1.0 / fps, source=self.name)

    def write(self, path: str | os.PathLike, weights: np.ndarray, times: np.ndarray, *, head=None,
              log=_quiet, **extra) -> Path:
        """Write the blended poses: ``.bvh`` (the skeleton's hierarchy and channel orders) or ``.glb``
        (a skin with joint rotation / translation channels, :func:`~faceretarget.io.write_glb_skeleton`)."""
        path = self.check_output(path)
        L = bone_lengths(self.world_positions(weights), self.parents)
        L0 = self.rest_bone_lengths()
        log(f"bone lengths kept: largest change {np.abs(L - L0).max(initial=0.0):.3g} {self.unit} over "
            f"{L.shape[1]} bones and {L.shape[0]} frames")
        if self.output_ext(path) == BVH:
            return write_bvh(path, self.to_bvh(weights, times))
        q, pos = self.params(weights)
        joints: list[BvhJoint] = self.skeleton.joints
        offsets = np.array([j.offset for j in joints], dtype=np.float64)
        return write_glb_skeleton(path, self.joint_names, self.parents, offsets, q, pos, times,
                                  scale=mm_per_unit(self.unit) / 1000.0, end_sites=[j.end_site for j in joints])
