"""Head motion files: recorded head motion in (BVH, SMPL-X, rigid marker clusters) and any head pose out.

Every reader gives a :class:`~faceretarget.Performance` whose ``head`` is a
:class:`~faceretarget.headpose.HeadPose` in the package's one frame (+Y up, +Z forward, +X the
character's left; translation in metres); :func:`read_head_take` adds the speech that goes with it.

Writers by extension (:func:`~faceretarget.io.write_head_motion`):

==========  ==========================================================================================
``.bvh``    One root joint ``Head``: channels ``Yrotation Xrotation Zrotation`` in degrees (and
            ``Xposition Yposition Zposition`` in centimetres first, with a translation), at the
            take's frame rate (:func:`~faceretarget.io.make_head_bvh`).
``.glb``    A node ``head`` with a ``rotation`` channel (quaternions ``x, y, z, w``) and, with a
            translation, a ``translation`` channel in metres (:func:`~faceretarget.io.write_glb_head`);
            ``write_glb(..., head=pose)`` puts the same node above a face.
``.csv``    Live Link Face columns ``HeadYaw, HeadPitch, HeadRoll`` in radians, Live Link Face's
            signs (:meth:`~faceretarget.headpose.HeadPose.to_livelinkface`); the 52 blendshape
            columns are the take's weights, or zero; no translation (the format has no column for it).
==========  ==========================================================================================
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import DataWarning, InputFileError, InvalidDataError, excerpt
from ..files import input_file, load_npz_arrays
from ..formats import BVH, C3D, CSV, GLB, NPZ
from ..headpose import HeadPose
from ..names import find_joints
from ..performance import Performance
from ..timebase import frame_times
from ..units import normalize_unit, scale
from ._arrays import npz_array, npz_scalar
from ._audio import read_audio
from ._bvh import Bvh, bvh_chain, read_bvh

__all__ = ["read_bvh_head", "read_glb_skin_head", "read_smplx_head", "read_marker_head", "read_head_motion", "read_head_take",
           "HEAD_READ_FORMATS"]

HEAD_READ_FORMATS = (BVH, NPZ, C3D, GLB, CSV)


def _head_chain(names: list[str], parents, source: str, joints: tuple[str, ...] | None) -> list[int]:
    """The neck-to-head chain of a skeleton (indices, parent first).

    ``joints`` None: found by role (:func:`~faceretarget.names.find_joints`: ``Head``, ``mixamorig:Head``,
    ``Bip01 Head``, ``J_Bip_C_Head``, ``DEF-head``...), from the first neck joint above the head down to
    it (the head alone when no neck is an ancestor).  Otherwise the named chain, joints a skeleton lacks
    skipped, as long as the last one exists.
    """
    parents = [int(x) for x in parents]
    if joints is None:
        roles = find_joints(names, parents)
        if "head" not in roles:
            raise InvalidDataError(f"{source}: no head joint found (by name, through exporters' prefixes such as "
                                   f"mixamorig:, Bip01, J_Bip_C_, DEF-); joints: "
                                   f"{', '.join(excerpt(n, bare=True) for n in names[:30])}"
                                   f"{', ...' if len(names) > 30 else ''}")
        chain = [roles["head"]]
        if "neck" in roles:
            while chain[0] != roles["neck"] and parents[chain[0]] >= 0:
                chain.insert(0, parents[chain[0]])
        return chain
    present = [j for j in joints if j in names]
    if not present or present[-1] != joints[-1]:
        raise InvalidDataError(f"{source}: no '{joints[-1]}' joint; head motion needs the chain "
                               f"{' > '.join(joints)} (joints: "
                               f"{', '.join(excerpt(n, bare=True) for n in names[:30])})")
    chain = [names.index(present[-1])]          # the contiguous part of the chain that ends at the head
    for j in reversed(present[:-1]):
        if parents[chain[0]] == names.index(j):
            chain.insert(0, names.index(j))
        else:
            break
    return chain


def read_bvh_head(bvh: Bvh | str | os.PathLike, joints: tuple[str, ...] | None = None,
                  unit: str = "cm") -> Performance:
    """Head motion relative to the upper torso from a BVH take.

    Parameters
    ----------
    bvh : Bvh or path
    joints : sequence of str, optional
        The neck-to-head chain; the rotation is the composition of their local rotations (the
        head's orientation in the frame of the first joint's parent, the upper torso).  By default
        the chain is found by role: the head joint by its name through exporters' namespaces and
        prefixes (``Head``, ``mixamorig:Head``, ``Bip01 Head``, ``J_Bip_C_Head``...) and every joint
        from the first neck above it (``Neck``, ``Neck1``...).  Joints a given chain lacks are
        skipped (e.g. a skeleton with ``Neck`` and ``Head`` only), as long as the last one exists.
    unit : str
        The BVH's length unit (the shared takes are in centimetres).

    Returns
    -------
    Performance
        ``head``: the chain's rotation, and the head joint's displacement from its rest position
        (the offsets) in the torso frame (metres); at the file's frame rate.
    """
    b = bvh if isinstance(bvh, Bvh) else read_bvh(bvh)
    idx = _head_chain(b.names, [j.parent for j in b.joints], b.source, None if joints is None else tuple(joints))
    chain = tuple(b.names[i] for i in idx)
    R, p = bvh_chain(b, chain)
    rest = np.sum([b.joints[i].offset for i in idx], axis=0)
    head = HeadPose.from_matrix(R, (p - rest) * scale(normalize_unit(unit), "m"), source=b.source)
    return Performance.from_head(head, fps=b.fps, source=b.source)


def read_glb_skin_head(path: str | os.PathLike) -> Performance:
    """Head motion relative to the upper torso from the skin animation of a ``.glb`` (a character's
    body animation): the neck-to-head chain found by role as in :func:`read_bvh_head`.

    Returns
    -------
    Performance
        ``head``: the chain's rotation relative to its rest rotation (the nodes' own), expressed in
        the torso frame, and the head joint's displacement from its rest position (metres).
    """
    from ._gltf_skin import read_glb_skeleton

    path = input_file(path)
    s = read_glb_skeleton(path)
    idx = _head_chain(list(s.names), s.parents, str(path), None)
    T = len(s.times)
    R = np.broadcast_to(np.eye(3), (T, 3, 3)).copy()
    p = np.zeros((T, 3))
    R0, p0 = np.eye(3), np.zeros(3)
    for i in idx:
        p = p + np.einsum("tij,tj->ti", R, s.translations[:, i])
        R = R @ Rotation.from_quat(s.rotations[:, i]).as_matrix()
        p0 = p0 + R0 @ s.rest[i]
        R0 = R0 @ Rotation.from_quat(s.rest_rotations[i]).as_matrix()
    head = HeadPose.from_matrix(R @ R0.T, p - p0, source=str(path))
    return Performance.from_head(head, times=s.times, source=str(path))


def read_smplx_head(path: str | os.PathLike, neck_length: float = 0.10) -> Performance:
    """Head rotation (and an approximate translation) from an SMPL-X parameter file.

    Parameters
    ----------
    path : path-like
        ``.npz`` with ``poses`` (T, 165) axis-angle (neck joint in columns 36-38, head in 45-47);
        the frame rate from ``mocap_frame_rate`` (or ``mocap_framerate``, ``fps``), else 30.
    neck_length : float
        Neck-to-head distance in metres used for the translation: the SMPL-X body model (which
        would give the real joint positions) is not bundled, so the head joint is taken as
        ``neck_length`` above the neck joint and moved by the neck rotation.

    Returns
    -------
    Performance
        ``head``: ``R_neck @ R_head``, the head's orientation relative to the neck's parent (the
        upper spine); SMPL-X's canonical frame is +Y up, +Z forward, +X left, the package's.
    """
    path = input_file(path)
    z = load_npz_arrays(path)
    if "poses" not in z:
        raise InputFileError(f"{path}: no 'poses' array; expected SMPL-X parameters (poses (T, 165))")
    poses = npz_array(path, z, "poses", "f")
    key = next((k for k in ("mocap_frame_rate", "mocap_framerate", "fps", "frame_rate") if k in z), None)
    fps = 30.0 if key is None else npz_scalar(path, z, key, "f")
    if poses.ndim != 2 or poses.shape[1] < 48 or len(poses) == 0:
        raise InputFileError(f"{path}: 'poses' must be (T, 165) axis-angle, got {poses.shape}")
    if not np.isfinite(poses[:, 36:48]).all():
        f = int(np.flatnonzero(~np.isfinite(poses[:, 36:48]).all(axis=1))[0])
        raise InvalidDataError(f"{path}: frame {f} neck/head pose is not finite")
    if not (np.isfinite(fps) and fps > 0):
        raise InputFileError(f"{path}: invalid frame rate {fps}")
    Rn = Rotation.from_rotvec(poses[:, 36:39])
    Rh = Rotation.from_rotvec(poses[:, 45:48])
    o = np.array([0.0, neck_length, 0.0])
    head = HeadPose.from_rotation(Rn * Rh, Rn.apply(o) - o, source=str(path))
    return Performance.from_head(head, fps=fps, source=str(path))


def read_marker_head(perf: Performance, subset=None, n_auto: int = 8) -> Performance:
    """Head motion of a rigid marker cluster (:class:`~faceretarget.numerics.RigidAligner`, SVD).

    Parameters
    ----------
    perf : Performance
        3D marker points (T, P, 3) in the package's axes (+Y up, +Z forward); ideally markers on
        the head (a cap, or the skull-rigid facial markers).  The rotation is relative to the
        cluster's reference pose (its robust median), so a torso-fixed capture gives the head
        relative to the torso.
    subset : labels or indices, optional
        Markers moving with the skull; chosen automatically when omitted, among the markers of a take
        that is a face (:func:`~faceretarget.numerics.face_markers`: a full-body take is refused, stray
        and mostly-missing markers are left out with a warning).
    n_auto : int
        Size of the automatic subset.

    Returns
    -------
    Performance
        ``head`` with the displacement of the cluster centroid (metres, from ``perf.unit``;
        millimetres assumed when it is unknown); frames without a pose are interpolated from
        their neighbours.
    """
    from ..numerics import RigidAligner, face_markers, select_rigid_markers

    if subset is None and perf.points is not None and perf.points.shape[2] == 3:
        # chosen automatically: only on a face (a full-body take's most rigid markers are a leg), without strays
        chk = face_markers(perf.points, perf.labels, perf.unit, source=perf.source)
        if not chk.keep.all():
            warnings.warn(chk.message(perf.source), DataWarning, stacklevel=2)
            subset = [int(i) for i in select_rigid_markers(perf.points[:, chk.keep], min(n_auto, int(chk.keep.sum())))]
            subset = [int(np.flatnonzero(chk.keep)[i]) for i in subset]
    al = RigidAligner(subset=subset, n_auto=n_auto)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = al.fit(perf).transform(perf)
    R, d = res.rotations, res.translations
    ok = np.isfinite(R).all(axis=(1, 2))
    if ok.sum() < 2:
        raise InvalidDataError(f"{perf.source}: fewer than 2 frames have a head pose from the markers")
    t = np.arange(len(R))
    rot = np.full((len(R), 3), np.nan)
    rot[ok] = Rotation.from_matrix(R[ok]).as_euler("YXZ")
    rot[ok] = np.unwrap(rot[ok], axis=0)
    rot = np.stack([np.interp(t, t[ok], rot[ok, k]) for k in range(3)], axis=1)
    dd = np.stack([np.interp(t, t[ok], d[ok, k]) for k in range(3)], axis=1)
    head = HeadPose.from_euler("YXZ", rot, dd * scale(normalize_unit(perf.unit or "mm", what=perf.source), "m"),
                               source=perf.source)
    return Performance(perf.times, perf.fps, head=head, source=perf.source)


def read_head_motion(path: str | os.PathLike, *, neck_length: float = 0.10) -> Performance:
    """Head motion from ``.bvh`` (the neck-to-head chain, found by role), SMPL-X ``.npz``, ``.c3d`` markers,
    a ``.glb`` ``head`` node (the files ``headmotion synth`` writes) or a ``.glb`` skin's head joint (a
    character's animation), or Live Link Face ``.csv`` head columns.

    Returns
    -------
    Performance
        ``head`` at the file's times (a ``.csv`` keeps its ``timecode``).
    """
    from ._c3d import read_c3d

    path = input_file(path)
    ext = path.suffix.lower()
    if ext == BVH:
        return read_bvh_head(path)
    if ext == NPZ:
        return read_smplx_head(path, neck_length=neck_length)
    if ext == C3D:
        return read_marker_head(read_c3d(path))
    if ext == GLB:
        from ._gltf import read_glb_head
        from ._gltf_skin import glb_skin_and_nodes

        skin, nodes = glb_skin_and_nodes(path)
        if skin and "head" not in nodes:
            return read_glb_skin_head(path)           # a character's body animation: its head joint by role
        times, head = read_glb_head(path)
        return Performance.from_head(head, times=times, source=str(path))
    if ext == CSV:
        from ._livelinkface import read_livelinkface

        take = read_livelinkface(path)
        if take.head is None:
            raise InputFileError(f"{path}: no HeadYaw, HeadPitch, HeadRoll columns; no head motion to read")
        return take.select("head")
    raise InputFileError(f"{path}: unknown head-motion format '{ext}' (use {', '.join(HEAD_READ_FORMATS)})")


#: How far the speech and the head motion of one take may differ in length: the larger of 0.5 s and
#: 2 % of the longer (recordings are cut by hand; more is another take's audio or a truncated file).
MISMATCH_S, MISMATCH_SHARE = 0.5, 0.02


def read_head_take(audio_path: str | os.PathLike, motion_path: str | os.PathLike, *,
                   name: str | None = None, neck_length: float = 0.10,
                   allow_mismatch: bool = False) -> Performance:
    """Speech audio and its head motion as one take (``head`` and ``audio``; ``source`` the name).

    Parameters
    ----------
    audio_path : path-like
        The speech (``.wav``, or anything :func:`~faceretarget.io.read_audio` reads).
    motion_path : path-like
        ``.bvh``, SMPL-X ``.npz`` or ``.c3d`` (:func:`read_head_motion`).
    name : str, optional
        Take name (default: the motion file's stem).
    neck_length : float
        For SMPL-X, metres (:func:`read_smplx_head`).
    allow_mismatch : bool
        Durations that differ by more than :data:`MISMATCH_S` / :data:`MISMATCH_SHARE` are an
        error (another take's audio, a truncated file); with ``allow_mismatch`` a warning.
    """
    motion_path = Path(motion_path)
    motion = read_head_motion(motion_path, neck_length=neck_length)
    audio, rate = read_audio(audio_path)
    a_s, m_s = len(audio) / rate, motion.n_frames / motion.fps
    tol = max(MISMATCH_S, MISMATCH_SHARE * max(a_s, m_s))
    if abs(a_s - m_s) > tol:
        msg = (f"{audio_path} lasts {a_s:.2f} s but its head motion {motion_path} lasts {m_s:.2f} s "
               f"(more than {tol:.2f} s apart): not the same take?")
        if not allow_mismatch:
            raise InvalidDataError(msg + " (--allow-mismatch to use them anyway)")
        warnings.warn(msg, DataWarning, stacklevel=2)
    return Performance(frame_times(motion.n_frames, motion.fps), motion.fps, head=motion.head, audio=audio,
                       audio_rate=rate, source=name or motion_path.stem)
