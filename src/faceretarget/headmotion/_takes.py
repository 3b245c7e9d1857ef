"""Recorded head motion with its speech: readers for BVH, SMPL-X and rigid marker clusters.

Head motion convention (everywhere in :mod:`faceretarget.headmotion`)
---------------------------------------------------------------------
The head's orientation **relative to the upper torso**, in the torso's rest-pose axes: +Y up, +X the
character's left, +Z forward (out of the face), right-handed (the axes of the shared BVH and of
SMPL-X).  Rotations are ``(T, 3)`` **yaw, pitch, roll in radians**, the intrinsic Y-X-Z Euler angles
of the rotation matrix (``scipy Rotation.from_euler("YXZ", [yaw, pitch, roll])``):

* yaw about +Y: positive turns the face toward the character's left;
* pitch about +X: positive tips the face down (a nod down);
* roll about +Z: positive tilts the top of the head toward the character's right.

Translations are ``(T, 3)`` in **centimetres**, the displacement of the head joint from its rest
position in the same axes.

Mirror (:func:`mirror_head_motion`): reflecting the performance left-right (``x -> -x``) maps a
rotation ``R`` to ``M R M`` with ``M = diag(-1, 1, 1)``; in these Euler angles that is exactly
``(yaw, pitch, roll) -> (-yaw, pitch, -roll)``, and a translation ``(x, y, z) -> (-x, y, z)``.
"""

from __future__ import annotations

import os
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputFileError, InvalidDataError
from ..files import input_file
from ..io import Bvh, bvh_chain, read_audio, read_bvh
from ..performance import Performance
from ._pitch import PitchTrack

__all__ = ["HeadTake", "head_motion_from_bvh", "head_motion_from_smplx", "head_motion_from_markers",
           "read_head_take", "mirror_head_motion", "EULER"]

#: scipy Euler sequence of head rotations: intrinsic yaw (Y), pitch (X), roll (Z).
EULER = "YXZ"
#: centimetres per unit
_CM = {"mm": 0.1, "millimeter": 0.1, "millimetre": 0.1, "cm": 1.0, "centimeter": 1.0, "centimetre": 1.0,
       "m": 100.0, "meter": 100.0, "metre": 100.0, "in": 2.54, "inch": 2.54}


@dataclass
class HeadTake:
    """One recorded take: speech audio and the synchronised head motion.

    Attributes
    ----------
    audio : (N,) float
        Mono samples in [-1, 1], starting with the motion's first frame.
    rate : float
        Audio sampling rate, Hz.
    rotation : (T, 3) float
        Yaw, pitch, roll in radians relative to the upper torso (module docstring).
    fps : float
        Motion frame rate.
    translation : (T, 3) float, optional
        Head displacement in centimetres (zeros when absent).
    name : str
        Take name (used by ``exclude`` in :meth:`HeadMotionDatabase.build` and in messages).
    pitch : PitchTrack, optional
        Precomputed pitch of ``audio`` (computed on demand when absent).
    """

    audio: np.ndarray
    rate: float
    rotation: np.ndarray
    fps: float
    translation: np.ndarray | None = None
    name: str = "take"
    pitch: PitchTrack | None = None

    def __post_init__(self) -> None:
        self.audio = np.asarray(self.audio, np.float32).reshape(-1)
        r = np.asarray(self.rotation, np.float64)
        if r.ndim != 2 or r.shape[1] != 3 or r.shape[0] < 2:
            raise InvalidDataError(f"{self.name}: rotation must be (T, 3) with T >= 2, got {r.shape}")
        if not np.isfinite(r).all():
            f = int(np.flatnonzero(~np.isfinite(r).all(axis=1))[0])
            raise InvalidDataError(f"{self.name}: head rotation of frame {f} is not finite")
        self.rotation = r
        if self.translation is None:
            self.translation = np.zeros_like(r)
        else:
            t = np.asarray(self.translation, np.float64)
            if t.shape != r.shape:
                raise InvalidDataError(f"{self.name}: translation must be {r.shape}, got {t.shape}")
            self.translation = np.where(np.isfinite(t), t, 0.0)
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise InvalidDataError(f"{self.name}: fps must be positive, got {self.fps}")
        if not (np.isfinite(self.rate) and self.rate > 0):
            raise InvalidDataError(f"{self.name}: audio rate must be positive, got {self.rate}")

    @property
    def duration(self) -> float:
        """Seconds covered by both audio and motion."""
        return min(self.audio.size / self.rate, (self.rotation.shape[0] - 1) / self.fps)


def mirror_head_motion(rotation: np.ndarray, translation: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray | None]:
    """Left-right mirror: ``(yaw, pitch, roll) -> (-yaw, pitch, -roll)``, ``(x, y, z) -> (-x, y, z)``.

    Exact for the Y-X-Z Euler convention of this package (module docstring); applying it twice
    gives the input back.

    Examples
    --------
    >>> r, t = mirror_head_motion(np.array([[0.1, 0.2, 0.3]]), np.array([[1.0, 2.0, 3.0]]))
    >>> r.tolist(), t.tolist()
    ([[-0.1, 0.2, -0.3]], [[-1.0, 2.0, 3.0]])
    """
    r = np.asarray(rotation, np.float64) * np.array([-1.0, 1.0, -1.0])
    t = None if translation is None else np.asarray(translation, np.float64) * np.array([-1.0, 1.0, 1.0])
    return r, t


def _euler(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_euler(EULER)


def head_motion_from_bvh(bvh: Bvh | str | os.PathLike, joints: tuple[str, ...] = ("Neck", "Neck1", "Head"),
                         cm_per_unit: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Head rotation and translation relative to the upper torso from a BVH take.

    Parameters
    ----------
    bvh : Bvh or path
    joints : sequence of str
        The neck-to-head chain; the rotation is the composition of their local rotations (the
        head's orientation in the frame of the first joint's parent, the upper torso).  Joints a
        skeleton lacks are skipped (e.g. a skeleton with ``Neck`` and ``Head`` only), as long as
        the last one exists.
    cm_per_unit : float
        Centimetres per BVH length unit (the shared takes are in centimetres).

    Returns
    -------
    rotation : (T, 3) float
        Yaw, pitch, roll, radians.
    translation : (T, 3) float
        The head joint's displacement from its rest position in the torso frame, centimetres.
    fps : float
    """
    b = bvh if isinstance(bvh, Bvh) else read_bvh(bvh)
    present = [j for j in joints if j in b.names]
    if not present or present[-1] != joints[-1]:
        raise InvalidDataError(f"{b.source}: no '{joints[-1]}' joint; head motion needs the chain "
                               f"{' > '.join(joints)} (joints: {', '.join(b.names[:30])})")
    # keep only the contiguous part of the chain that ends at the head
    chain = [present[-1]]
    for j in reversed(present[:-1]):
        if b.joints[b.index(chain[0])].parent == b.index(j):
            chain.insert(0, j)
        else:
            break
    R, p = bvh_chain(b, tuple(chain))
    rest = np.sum([b.joints[b.index(j)].offset for j in chain], axis=0)
    return _euler(R), (p - rest) * cm_per_unit, b.fps


def head_motion_from_smplx(path: str | os.PathLike, neck_length: float = 10.0
                           ) -> tuple[np.ndarray, np.ndarray, float]:
    """Head rotation (and an approximate translation) from an SMPL-X parameter file.

    Parameters
    ----------
    path : path-like
        ``.npz`` with ``poses`` (T, 165) axis-angle (neck joint in columns 36-38, head in 45-47);
        the frame rate from ``mocap_frame_rate`` (or ``mocap_framerate``, ``fps``), else 30.
    neck_length : float
        Neck-to-head distance in centimetres used for the translation: the SMPL-X body model
        (which would give the real joint positions) is not bundled, so the head joint is taken as
        ``neck_length`` above the neck joint and moved by the neck rotation.

    Returns
    -------
    rotation : (T, 3) float
        Yaw, pitch, roll (radians) of ``R_neck @ R_head``: the head's orientation relative to the
        neck's parent (the upper spine).  SMPL-X's canonical frame is +Y up, +Z forward, +X left.
    translation : (T, 3) float
        Centimetres (see ``neck_length``).
    fps : float
    """
    path = input_file(path)
    if not zipfile.is_zipfile(path):
        raise InputFileError(f"{path}: not an .npz archive")
    try:
        with np.load(path, allow_pickle=False) as z:
            if "poses" not in z.files:
                raise InputFileError(f"{path}: no 'poses' array; expected SMPL-X parameters (poses (T, 165))")
            poses = np.asarray(z["poses"], np.float64)
            fps = 30.0
            for k in ("mocap_frame_rate", "mocap_framerate", "fps", "frame_rate"):
                if k in z.files:
                    fps = float(np.asarray(z[k]).reshape(-1)[0])
                    break
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise InputFileError(f"{path}: cannot read as .npz ({e})") from e
    if poses.ndim != 2 or poses.shape[1] < 48:
        raise InputFileError(f"{path}: 'poses' must be (T, 165) axis-angle, got {poses.shape}")
    if not np.isfinite(poses[:, 36:48]).all():
        f = int(np.flatnonzero(~np.isfinite(poses[:, 36:48]).all(axis=1))[0])
        raise InvalidDataError(f"{path}: frame {f} neck/head pose is not finite")
    if not (np.isfinite(fps) and fps > 0):
        raise InputFileError(f"{path}: invalid frame rate {fps}")
    Rn = Rotation.from_rotvec(poses[:, 36:39])
    Rh = Rotation.from_rotvec(poses[:, 45:48])
    rot = (Rn * Rh).as_euler(EULER)
    o = np.array([0.0, neck_length, 0.0])
    trans = Rn.apply(o) - o
    return rot, trans, fps


def head_motion_from_markers(perf: Performance, subset=None, n_auto: int = 8
                             ) -> tuple[np.ndarray, np.ndarray, float]:
    """Head rotation and translation of a rigid marker cluster (:class:`RigidAligner`, SVD).

    Parameters
    ----------
    perf : Performance
        3D marker points (T, P, 3); ideally markers on the head (a cap, or the skull-rigid
        facial markers).  Capture axes are assumed +Y up, +Z forward; the rotation is relative to
        the cluster's reference pose (its robust median), so a torso-fixed capture gives the head
        relative to the torso.
    subset : labels or indices, optional
        Markers moving with the skull; chosen automatically when omitted.
    n_auto : int
        Size of the automatic subset.

    Returns
    -------
    rotation : (T, 3) float
        Radians; frames without a pose are interpolated from their neighbours.
    translation : (T, 3) float
        Displacement of the cluster centroid, centimetres (from ``perf.unit``; millimetres assumed
        when it is unknown).
    fps : float
    """
    from ..numerics import RigidAligner

    al = RigidAligner(subset=subset, n_auto=n_auto)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        al.fit(perf)
    R, d = al.rotations_, al.translations_
    ok = np.isfinite(R).all(axis=(1, 2))
    if ok.sum() < 2:
        raise InvalidDataError(f"{perf.source}: fewer than 2 frames have a head pose from the markers")
    t = np.arange(len(R))
    rot = np.full((len(R), 3), np.nan)
    rot[ok] = _euler(R[ok])
    rot[ok] = np.unwrap(rot[ok], axis=0)
    rot = np.stack([np.interp(t, t[ok], rot[ok, k]) for k in range(3)], axis=1)
    dd = np.stack([np.interp(t, t[ok], d[ok, k]) for k in range(3)], axis=1)
    scale = _CM.get((perf.unit or "mm").lower(), None)
    if scale is None:
        raise InvalidDataError(f"{perf.source}: unknown marker unit {perf.unit!r} (mm, cm, m)")
    return rot, dd * scale, float(perf.fps)


def read_head_take(audio_path: str | os.PathLike, motion_path: str | os.PathLike, *,
                   name: str | None = None, neck_length: float = 10.0) -> HeadTake:
    """Read speech audio and its head motion.

    Parameters
    ----------
    audio_path : path-like
        ``.wav``.
    motion_path : path-like
        ``.bvh`` (Neck/Neck1/Head chain), ``.npz`` (SMPL-X ``poses``) or ``.c3d`` (markers, rigid
        cluster by SVD).
    name : str, optional
        Take name (default: the motion file's stem).
    neck_length : float
        For SMPL-X, see :func:`head_motion_from_smplx`.
    """
    motion_path = Path(motion_path)
    ext = motion_path.suffix.lower()
    if not motion_path.is_file():
        raise InputFileError(f"{motion_path}: file not found" if not motion_path.exists()
                             else f"{motion_path}: not a file")
    if ext == ".bvh":
        rot, trans, fps = head_motion_from_bvh(motion_path)
    elif ext == ".npz":
        rot, trans, fps = head_motion_from_smplx(motion_path, neck_length=neck_length)
    elif ext == ".c3d":
        from ..io import read_c3d

        rot, trans, fps = head_motion_from_markers(read_c3d(motion_path))
    else:
        raise InputFileError(f"{motion_path}: unknown head-motion format '{ext}' (use .bvh, SMPL-X .npz or .c3d)")
    audio, rate = read_audio(audio_path)
    return HeadTake(audio, rate, rot, fps, trans, name=name or motion_path.stem)
