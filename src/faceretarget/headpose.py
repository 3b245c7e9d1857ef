"""``HeadPose``: the one representation of head motion in the package.

Frame
-----
Right-handed, **+Y up, +Z forward** (out of the face), **+X the character's left**: the axes of
glTF, of ARKit's face anchor, of MediaPipe's canonical face and of the rest pose of the shared BVH
and SMPL-X skeletons.

* **Rotation** (``scipy.spatial.transform.Rotation`` per frame): the head's orientation relative to
  its rest pose (upright, facing +Z); a vector ``h`` in head coordinates points along ``R h``.
  For skeletal takes the rest pose is the upper torso's (the rotation is the neck-to-head chain),
  for video capture it is facing the camera.
* **Translation** (``(T, 3)``, **metres**, optional): the head's position in the same axes; its
  origin is the source's own (the head joint's rest position for skeletal takes, the camera for
  video capture, the rigid markers' reference centroid for marker takes).
* A frame without a pose (a lost face, too few markers) holds NaN and is ``False`` in
  :attr:`HeadPose.valid`.

Angles in a rotation are only a file's business.  Converters at the file boundary:

=============================== ==========================================================================
Live Link Face                  :meth:`HeadPose.from_livelinkface` / :meth:`to_livelinkface`:
                                ``HeadYaw, HeadPitch, HeadRoll`` radians, ``R = Ry(yaw) Rx(-pitch) Rz(roll)``
                                (yaw > 0 turns to the character's left, pitch > 0 is chin up,
                                roll > 0 tilts toward the right shoulder)
BVH                             :meth:`to_euler` ``("YXZ", degrees=True)``: ``Yrotation Xrotation
                                Zrotation`` channels (intrinsic, the order they are listed); pitch > 0
                                is a nod down (right-hand about +X)
glTF                            :meth:`as_quat`: ``x, y, z, w`` node rotations; translation in metres
=============================== ==========================================================================

Examples
--------
A nod down by 10 degrees and a turn to the character's left by 20 degrees:

>>> pose = HeadPose.from_euler("YXZ", [[20.0, 10.0, 0.0]], degrees=True)
>>> np.round(pose.to_livelinkface()[0], 4).tolist()   # HeadYaw, HeadPitch (chin up +), HeadRoll
[0.3491, -0.1745, 0.0]
>>> np.round(pose.to_euler("YXZ", degrees=True)[0], 6).tolist()   # BVH Yrotation Xrotation Zrotation
[20.0, 10.0, 0.0]
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InvalidDataError

__all__ = ["continuous_quaternions", "HeadPose", "LIVELINKFACE_SIGNS", "mirror_yxz"]

#: Live Link Face's ``HeadYaw, HeadPitch, HeadRoll`` are the intrinsic Y-X-Z angles with pitch negated.
LIVELINKFACE_SIGNS = np.array([1.0, -1.0, 1.0])


def mirror_yxz(angles, translation=None) -> tuple[np.ndarray, np.ndarray | None]:
    """Left-right mirror of head motion as intrinsic Y-X-Z angles (and a translation).

    Reflecting the performance (``x -> -x``) maps a rotation ``R`` to ``M R M`` with
    ``M = diag(-1, 1, 1)``; in these angles that is exactly ``(yaw, pitch, roll) -> (-yaw, pitch,
    -roll)``, and a translation ``(x, y, z) -> (-x, y, z)``.  Applying it twice gives the input back.

    >>> r, t = mirror_yxz(np.array([[0.1, 0.2, 0.3]]), np.array([[1.0, 2.0, 3.0]]))
    >>> r.tolist(), t.tolist()
    ([[-0.1, 0.2, -0.3]], [[-1.0, 2.0, 3.0]])
    """
    r = np.asarray(angles, np.float64) * np.array([-1.0, 1.0, -1.0])
    t = None if translation is None else np.asarray(translation, np.float64) * np.array([-1.0, 1.0, 1.0])
    return r, t


def _nan_rows(a: np.ndarray) -> np.ndarray:
    return ~np.isfinite(a.reshape(len(a), -1)).all(axis=1)


class HeadPose:
    """Head orientation (and position) per frame, in the frame of the module docstring.

    Parameters
    ----------
    quaternions : (T, 4) float
        Unit quaternions ``x, y, z, w`` (scalar last, scipy's and glTF's order); a row of NaN is a
        frame without a pose.  Normalised on construction.
    translation : (T, 3) float, optional
        Metres; NaN where there is no pose.
    source : str
        Where the pose came from, for messages.
    """

    __slots__ = ("quaternions", "translation", "source")

    def __init__(self, quaternions, translation=None, *, source: str = "head pose") -> None:
        q = np.array(quaternions, dtype=np.float64, copy=True)
        if q.ndim == 1:
            q = q[None]
        if q.ndim != 2 or q.shape[1] != 4:
            raise InvalidDataError(f"{source}: head rotations must be (T, 4) quaternions, got {q.shape}")
        bad = _nan_rows(q)
        n = np.linalg.norm(np.where(bad[:, None], 1.0, q), axis=1)
        if (n[~bad] < 1e-9).any():
            f = int(np.flatnonzero(~bad & (n < 1e-9))[0])
            raise InvalidDataError(f"{source}: frame {f} head rotation is a zero quaternion")
        q = q / n[:, None]
        q[bad] = np.nan
        t = None
        if translation is not None:
            t = np.array(translation, dtype=np.float64, copy=True)
            if t.ndim == 1:
                t = t[None]
            if t.shape != (len(q), 3):
                raise InvalidDataError(f"{source}: head translation must be ({len(q)}, 3) metres, got {t.shape}")
            if np.isinf(t).any():
                f = int(np.flatnonzero(np.isinf(t).any(axis=1))[0])
                raise InvalidDataError(f"{source}: frame {f} head translation is infinite")
        self.quaternions = q
        self.translation = t
        self.source = source

    # ------------------------------------------------------------------------------ constructors
    @classmethod
    def from_rotation(cls, rotation: Rotation, translation=None, *, source: str = "head pose") -> HeadPose:
        """From a scipy ``Rotation`` holding one rotation per frame."""
        q = rotation.as_quat()
        return cls(q.reshape(-1, 4), translation, source=source)

    @classmethod
    def from_matrix(cls, matrices, translation=None, *, source: str = "head pose") -> HeadPose:
        """From ``(T, 3, 3)`` rotation matrices (NaN matrices: frames without a pose)."""
        R = np.asarray(matrices, dtype=np.float64).reshape(-1, 3, 3)
        q = np.full((len(R), 4), np.nan)
        ok = ~_nan_rows(R)
        if ok.any():
            q[ok] = Rotation.from_matrix(R[ok]).as_quat()
        return cls(q, translation, source=source)

    @classmethod
    def from_euler(cls, seq: str, angles, translation=None, *, degrees: bool = False,
                   source: str = "head pose") -> HeadPose:
        """From Euler angles ``(T, 3)`` in scipy's ``seq`` (upper case: intrinsic)."""
        a = np.asarray(angles, dtype=np.float64).reshape(-1, 3)
        q = np.full((len(a), 4), np.nan)
        ok = ~_nan_rows(a)
        if ok.any():
            q[ok] = Rotation.from_euler(seq, a[ok], degrees=degrees).as_quat()
        return cls(q, translation, source=source)

    @classmethod
    def from_livelinkface(cls, angles, translation=None, *, source: str = "head pose") -> HeadPose:
        """From Live Link Face ``HeadYaw, HeadPitch, HeadRoll`` radians (module docstring)."""
        a = np.asarray(angles, dtype=np.float64).reshape(-1, 3) * LIVELINKFACE_SIGNS
        return cls.from_euler("YXZ", a, translation, source=source)

    @classmethod
    def identity(cls, n: int, *, translation: bool = False, source: str = "head pose") -> HeadPose:
        """``n`` frames at rest."""
        q = np.zeros((int(n), 4))
        q[:, 3] = 1.0
        return cls(q, np.zeros((int(n), 3)) if translation else None, source=source)

    @classmethod
    def concatenate(cls, poses: Sequence[HeadPose]) -> HeadPose:
        """Frames of several poses one after another (translation kept when every pose has one)."""
        q = np.concatenate([p.quaternions for p in poses])
        tr = None
        if all(p.translation is not None for p in poses):
            tr = np.concatenate([p.translation for p in poses])
        return cls(q, tr, source=poses[0].source if poses else "head pose")

    # ------------------------------------------------------------------------------ views
    @property
    def n_frames(self) -> int:
        return int(len(self.quaternions))

    def __len__(self) -> int:
        return self.n_frames

    @property
    def valid(self) -> np.ndarray:
        """(T,) bool: frames that have a pose."""
        return ~_nan_rows(self.quaternions)

    def moves(self, *, degrees: float = 1e-6, metres: float = 1e-9) -> bool:
        """Whether the head moves over the take: some frame's rotation differs from another's by more
        than ``degrees``, or its translation by more than ``metres`` (a take whose head columns are all
        zero does not move)."""
        q = self.quaternions[self.valid]
        if len(q) > 1:
            cos = np.clip(np.abs(q @ q[0]), 0.0, 1.0)                 # |<q_t, q_0>| = cos(angle_t / 2)
            if np.degrees(2 * np.arccos(cos)).max() > degrees:
                return True
        if self.translation is not None:
            t = self.translation[np.isfinite(self.translation).all(axis=1)]
            if len(t) > 1 and np.ptp(t, axis=0).max() > metres:
                return True
        return False

    @property
    def rotation(self) -> Rotation:
        """The rotations as one scipy ``Rotation`` (every frame must have a pose)."""
        bad = ~self.valid
        if bad.any():
            raise InvalidDataError(f"{self.source}: frame {int(np.flatnonzero(bad)[0])} has no head pose")
        return Rotation.from_quat(self.quaternions)

    def __getitem__(self, index) -> HeadPose:
        """Frames ``index`` (a slice, an index array or a boolean mask) as a new pose."""
        q = self.quaternions[index]
        tr = None if self.translation is None else self.translation[index]
        return HeadPose(q, tr, source=self.source)

    def resample(self, times, new_times) -> HeadPose:
        """The pose at other times: rotations by slerp, translation linearly, between the frames that
        have a pose.

        Parameters
        ----------
        times : (T,) float
            Seconds of this pose's frames, strictly increasing.
        new_times : (N,) float
            Seconds to sample, inside ``[times[0], times[-1]]`` of the frames with a pose (1 us of
            slack at either end).

        Returns
        -------
        HeadPose
            ``N`` frames, every one with a pose.

        Raises
        ------
        InvalidDataError
            Times of the wrong length, fewer than two frames with a pose, or ``new_times`` outside
            the span they cover (naming both spans).
        """
        from scipy.spatial.transform import Slerp

        t = np.asarray(times, dtype=np.float64).reshape(-1)
        nt = np.asarray(new_times, dtype=np.float64).reshape(-1)
        if t.size != self.n_frames:
            raise InvalidDataError(f"{self.source}: {t.size} times for {self.n_frames} head poses")
        ok = self.valid
        if ok.sum() < 2:
            raise InvalidDataError(f"{self.source}: fewer than two frames have a head pose; cannot resample")
        tv = t[ok]
        if not np.all(np.diff(tv) > 0):
            raise InvalidDataError(f"{self.source}: head pose times must increase")
        lo, hi, eps = tv[0], tv[-1], 1e-6
        if nt.size and (nt.min() < lo - eps or nt.max() > hi + eps):
            raise InvalidDataError(f"{self.source}: head motion covers {lo:.3f}-{hi:.3f} s, asked for "
                                   f"{nt.min():.3f}-{nt.max():.3f} s")
        nt = np.clip(nt, lo, hi)
        q = Slerp(tv, Rotation.from_quat(self.quaternions[ok]))(nt).as_quat()
        tr = None
        if self.translation is not None:
            okt = ok & np.isfinite(self.translation).all(axis=1)
            tr = np.stack([np.interp(nt, t[okt], self.translation[okt, k]) for k in range(3)], axis=1) \
                if okt.any() else np.full((nt.size, 3), np.nan)
        return HeadPose(q.reshape(-1, 4), tr, source=self.source)

    def with_translation(self, translation) -> HeadPose:
        """The same rotations with another translation (metres, or None)."""
        return HeadPose(self.quaternions, translation, source=self.source)

    def __repr__(self) -> str:
        tr = "" if self.translation is None else ", with translation"
        return f"HeadPose({self.n_frames} frames{tr}, source={self.source!r})"

    def equals(self, other: HeadPose, atol: float = 0.0) -> bool:
        """Same frames, rotations (``q`` and ``-q`` alike) and translation within ``atol``."""
        if not isinstance(other, HeadPose) or other.n_frames != self.n_frames:
            return False
        if (self.translation is None) != (other.translation is None):
            return False
        a, b = self.quaternions, other.quaternions
        va, vb = self.valid, other.valid
        if not np.array_equal(va, vb):
            return False
        dot = np.abs(np.sum(a[va] * b[vb], axis=1))
        if (dot < 1.0 - max(atol, 1e-15)).any() and not np.allclose(np.abs(a[va]), np.abs(b[vb]), atol=atol):
            return False
        if self.translation is not None:
            return bool(np.allclose(self.translation, other.translation, atol=atol, equal_nan=True))
        return True

    # ------------------------------------------------------------------------------ conversions
    def as_quat(self) -> np.ndarray:
        """(T, 4) quaternions ``x, y, z, w`` (glTF's rotation order); NaN without a pose."""
        return self.quaternions.copy()

    def as_matrix(self) -> np.ndarray:
        """(T, 3, 3) rotation matrices; NaN without a pose."""
        out = np.full((self.n_frames, 3, 3), np.nan)
        ok = self.valid
        if ok.any():
            out[ok] = Rotation.from_quat(self.quaternions[ok]).as_matrix()
        return out

    def to_euler(self, seq: str = "YXZ", *, degrees: bool = False) -> np.ndarray:
        """(T, 3) Euler angles in scipy's ``seq`` (default intrinsic yaw, pitch, roll); NaN without a pose."""
        out = np.full((self.n_frames, 3), np.nan)
        ok = self.valid
        if ok.any():
            out[ok] = Rotation.from_quat(self.quaternions[ok]).as_euler(seq, degrees=degrees)
        return out

    def to_livelinkface(self) -> np.ndarray:
        """(T, 3) Live Link Face ``HeadYaw, HeadPitch, HeadRoll`` radians (module docstring)."""
        return self.to_euler("YXZ") * LIVELINKFACE_SIGNS

    def translation_in(self, unit: str) -> np.ndarray | None:
        """The translation in ``unit`` (``"cm"`` for BVH files), or None."""
        if self.translation is None:
            return None
        from .units import scale

        return self.translation * scale("m", unit)

    def mirrored(self) -> HeadPose:
        """Left-right mirror (``x -> -x``, :func:`mirror_yxz`)."""
        r, t = mirror_yxz(self.to_euler("YXZ"), self.translation)
        return HeadPose.from_euler("YXZ", r, t, source=self.source)

    def relative_to(self, rest: Rotation) -> HeadPose:
        """The rotations expressed relative to ``rest`` (``rest^-1 * R``), translation unchanged."""
        ok = self.valid
        q = np.full_like(self.quaternions, np.nan)
        if ok.any():
            q[ok] = (rest.inv() * Rotation.from_quat(self.quaternions[ok])).as_quat()
        return HeadPose(q, self.translation, source=self.source)

    def in_axes(self, axes) -> HeadPose:
        """The same motion expressed in other axes: ``axes`` (3, 3) maps this pose's axes to the new
        ones (``R -> A R A^T``, ``t -> A t``), for example a Z-up capture into the package's Y-up frame."""
        A = np.asarray(axes, dtype=np.float64)
        if A.shape != (3, 3) or not np.allclose(A @ A.T, np.eye(3), atol=1e-9):
            raise InvalidDataError(f"{self.source}: axes must be a (3, 3) rotation or reflection matrix")
        R = A @ self.as_matrix() @ A.T
        tr = None if self.translation is None else self.translation @ A.T
        return HeadPose.from_matrix(R, tr, source=self.source)


def continuous_quaternions(q: np.ndarray) -> np.ndarray:
    """Quaternions ``(T, 4)`` (x, y, z, w) with w >= 0 at the first key and every key on the same
    hemisphere as the one before, so linear or spherical interpolation between keys takes the short way."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    q = q * np.where(q[:, 3:] < 0, -1.0, 1.0)
    flip = np.cumprod(np.where(np.r_[1.0, np.sign((q[1:] * q[:-1]).sum(axis=1))] < 0, -1.0, 1.0))
    return q * flip[:, None]
