"""Biovision Hierarchy (``.bvh``) motion: read and write skeletons with their channel curves.

Conventions (the ones every common exporter follows):

* Rotations are in degrees.  A joint's rotation channels are applied in the order they are listed:
  ``CHANNELS 3 Zrotation Xrotation Yrotation`` means the local rotation ``R = Rz @ Rx @ Ry`` (column
  vectors; scipy's intrinsic ``Rotation.from_euler("ZXY", [z, x, y])``).  Each joint's own channel
  order is honoured.
* A joint's local transform is its translation followed by its rotation: a point ``p`` in the
  joint's frame is at ``t + R @ p`` in the parent's frame.  The translation is the ``OFFSET``, except
  on the axes the joint has position channels for: those hold the full local translation (not a
  displacement added to the offset), as Blender, three.js, bvhio and every exporter we know read and
  write them.  The two readings differ when an ``OFFSET`` with position channels is not zero: a root
  offset (the feet float by it) or every joint with six channels (Bandai Namco's takes: bones twice
  their length).
* In the rest pose every joint frame is parallel to the world frame, so composed rotations are
  expressed in the rest-pose axes (Y up in the shared takes, X the character's left, +Z forward).

:func:`make_head_bvh` builds the minimal skeleton :mod:`faceretarget.headmotion` writes: one root
joint ``Head`` with channels ``Yrotation Xrotation Zrotation`` (so its three rotation values per
frame are exactly yaw, pitch and roll in degrees, intrinsic Y-X-Z) and, when a translation is given,
``Xposition Yposition Zposition`` before them.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import DataWarning, InputFileError, InvalidDataError, excerpt
from ..files import atomic_path, check_output_path, input_file, read_text
from ..formats import CSV, JSON
from ..headpose import HeadPose

__all__ = ["Bvh", "BvhJoint", "read_bvh", "write_bvh", "bvh_chain", "make_head_bvh", "bvh_pose", "bvh_world_positions",
           "bvh_with_pose", "read_key_frames"]

_ROT = {"xrotation": "X", "yrotation": "Y", "zrotation": "Z"}
#: Largest magnitude of a value read (no angle or length is near it; sums of larger ones could overflow).
_MAX_VALUE = 1e15
_POS = {"xposition": 0, "yposition": 1, "zposition": 2}


@dataclass
class BvhJoint:
    """One joint of a BVH hierarchy.

    Attributes
    ----------
    name : str
    parent : int
        Index of the parent joint, -1 for a root.
    offset : (3,) float
        Position of the joint's origin in its parent's frame (rest pose).
    channels : tuple of str
        Channel names as written (``Xposition``, ``Zrotation``, ...).
    end_site : (3,) float or None
        ``End Site`` offset, when the joint has one.
    """

    name: str
    parent: int
    offset: np.ndarray
    channels: tuple[str, ...] = ()
    end_site: np.ndarray | None = None


@dataclass
class Bvh:
    """A BVH skeleton and its motion.

    Attributes
    ----------
    joints : list of BvhJoint
        In file order (a parent always precedes its children).
    frame_time : float
        Seconds per frame.
    motion : (T, C) float
        Channel values per frame, columns in joint order then channel order.
    source : str
        File name, for messages.
    """

    joints: list[BvhJoint]
    frame_time: float
    motion: np.ndarray
    source: str = "bvh"
    _start: list[int] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        self.motion = np.asarray(self.motion, dtype=np.float64)
        starts, c = [], 0
        for j in self.joints:
            starts.append(c)
            c += len(j.channels)
        self._start = starts
        if self.motion.ndim != 2 or self.motion.shape[1] != c:
            raise InvalidDataError(f"{self.source}: motion must be (T, {c}) for {c} channels, "
                                   f"got {self.motion.shape}")
        if not (np.isfinite(self.frame_time) and self.frame_time > 0):
            raise InvalidDataError(f"{self.source}: frame time must be positive, got {self.frame_time}")

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    def index(self, name: str) -> int:
        """Index of joint ``name`` (raises :class:`InvalidDataError` naming the joints present)."""
        for i, j in enumerate(self.joints):
            if j.name == name:
                return i
        raise InvalidDataError(f"{self.source}: no joint '{name}' (joints: {', '.join(excerpt(n, bare=True) for n in self.names[:40])}"
                               f"{', ...' if len(self.joints) > 40 else ''})")

    def local_rotations(self, joint: str | int) -> np.ndarray:
        """(T, 3, 3) local rotation matrices of a joint (identity when it has no rotation channels)."""
        i = int(joint) if isinstance(joint, int | np.integer) else self.index(joint)
        j = self.joints[i]
        cols = [(self._start[i] + k, _ROT[c.lower()]) for k, c in enumerate(j.channels) if c.lower() in _ROT]
        T = self.n_frames
        if not cols:
            return np.broadcast_to(np.eye(3), (T, 3, 3)).copy()
        seq = "".join(a for _, a in cols)
        ang = self.motion[:, [c for c, _ in cols]]
        return Rotation.from_euler(seq, ang, degrees=True).as_matrix().reshape(T, 3, 3)

    def local_translations(self, joint: str | int) -> np.ndarray:
        """(T, 3) the joint's local translation: its position channels where it has them, its offset
        on the other axes (module docstring)."""
        i = int(joint) if isinstance(joint, int | np.integer) else self.index(joint)
        j = self.joints[i]
        out = np.broadcast_to(np.asarray(j.offset, np.float64), (self.n_frames, 3)).copy()
        for k, c in enumerate(j.channels):
            if c.lower() in _POS:
                out[:, _POS[c.lower()]] = self.motion[:, self._start[i] + k]
        return out


def bvh_chain(bvh: Bvh, joints: tuple[str, ...] | list[str] = ("Neck", "Neck1", "Head")
              ) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and position of the last joint of a chain relative to the parent of the first.

    Parameters
    ----------
    bvh : Bvh
    joints : sequence of str
        A parent-to-child chain, each joint the child of the one before.

    Returns
    -------
    rotation : (T, 3, 3) float
        ``R_0 @ R_1 @ ... @ R_n`` of the chain's local rotations: the last joint's orientation in
        the frame of the first joint's parent.
    position : (T, 3) float
        The last joint's origin in that frame, in the file's length unit.

    Raises
    ------
    InvalidDataError
        A joint is missing, or the joints do not form a parent-to-child chain.
    """
    idx = [bvh.index(n) for n in joints]
    for a, b in zip(idx[:-1], idx[1:], strict=True):
        if bvh.joints[b].parent != a:
            raise InvalidDataError(f"{bvh.source}: joint '{bvh.joints[b].name}' is not a child of "
                                   f"'{bvh.joints[a].name}'")
    T = bvh.n_frames
    R = np.broadcast_to(np.eye(3), (T, 3, 3)).copy()
    p = np.zeros((T, 3))
    for i in idx:
        p = p + np.einsum("tij,tj->ti", R, bvh.local_translations(i))
        R = R @ bvh.local_rotations(i)
    return R, p


# ------------------------------------------------------------------------------------------ reading
def _num(path: Path, lineno: int, s: str) -> float:
    try:
        v = float(s)
    except ValueError:
        raise InputFileError(f"{path}: line {lineno}: {excerpt(s)} is not a number") from None
    if not abs(v) <= _MAX_VALUE:
        raise InputFileError(f"{path}: line {lineno}: value {excerpt(s)} is not finite" if not np.isfinite(v) else
                             f"{path}: line {lineno}: value {excerpt(s)} is beyond +-{_MAX_VALUE:g}")
    return v


def _hierarchy_tokens(path: Path, lines: list[str]) -> tuple[list[tuple[str, int]], int]:
    """Split the lines before ``MOTION`` into tokens; also return the index of the ``MOTION`` line."""
    # tokens of the hierarchy with their line numbers
    toks: list[tuple[str, int]] = []
    motion_line = None
    for i, line in enumerate(lines):
        if line.strip().upper().startswith("MOTION"):
            motion_line = i
            break
        if _comment(line):
            continue
        toks.extend((t, i + 1) for t in line.replace("{", " { ").replace("}", " } ").split())
    if not toks or toks[0][0].upper() != "HIERARCHY":
        raise InputFileError(f"{path}: not a BVH file (it must start with 'HIERARCHY')")
    if motion_line is None:
        raise InputFileError(f"{path}: no MOTION section")
    return toks, motion_line


def _comment(line: str) -> bool:
    """A whole-line comment (``#`` or ``//``), which some exporters write and every reader skips."""
    t = line.lstrip()
    return t.startswith(("#", "//"))


def _token(path: Path, toks: list[tuple[str, int]], j: int, what: str) -> tuple[str, int]:
    """Token ``j`` with its line number, or an error saying the hierarchy ends before ``what``."""
    if j >= len(toks):
        raise InputFileError(f"{path}: hierarchy ends early, expected {what}")
    return toks[j]


def _read_offset(path: Path, toks: list[tuple[str, int]], k: int, joints: list[BvhJoint],
                 stack: list[int]) -> None:
    """Store the 3 values after the ``OFFSET`` at ``toks[k]`` in the joint (or End Site) being read."""
    vals = np.array([_num(path, _token(path, toks, k + j, "3 offset values")[1],
                          _token(path, toks, k + j, "3 offset values")[0]) for j in (1, 2, 3)])
    if stack[-1] == -2:
        owner = next((s for s in reversed(stack) if s >= 0), None)
        if owner is not None:
            joints[owner].end_site = vals
    else:
        joints[stack[-1]].offset = vals


def _read_channels(path: Path, toks: list[tuple[str, int]], k: int, ln: int) -> tuple[int, tuple[str, ...]]:
    """The channel count and names after the ``CHANNELS`` at ``toks[k]`` (on line ``ln``)."""
    cnt_s, _ = _token(path, toks, k + 1, "a channel count")
    try:
        cnt = int(cnt_s)
    except ValueError:
        raise InputFileError(f"{path}: line {ln}: channel count {excerpt(cnt_s)} is not an integer") from None
    if cnt < 0:  # a negative count stepped the parser backwards: it never ended
        raise InputFileError(f"{path}: line {ln}: channel count {cnt} is negative")
    chans = []
    for j in range(cnt):
        c, cl = _token(path, toks, k + 2 + j, f"{cnt} channel names")
        if c.lower() not in _ROT and c.lower() not in _POS:
            raise InputFileError(f"{path}: line {cl}: unknown channel {excerpt(c)}")
        if c.lower() in (x.lower() for x in chans):  # 'Xrotation Xrotation': no Euler sequence
            raise InputFileError(f"{path}: line {cl}: channel {c} is listed twice")
        chans.append(c)
    return cnt, tuple(chans)


def _open_brace(path: Path, ln: int, pending: tuple[str, int] | None, joints: list[BvhJoint],
                stack: list[int]) -> None:
    """Open the block of the pending joint (appended to ``joints``) or End Site (``-2``)."""
    if pending is None:
        raise InputFileError(f"{path}: line {ln}: unexpected '{{'")
    if pending[1] == -2:
        stack.append(-2)
    else:
        joints.append(BvhJoint(pending[0], pending[1], np.zeros(3)))
        stack.append(len(joints) - 1)


def _parse_hierarchy(path: Path, toks: list[tuple[str, int]]) -> list[BvhJoint]:
    """The joints of the hierarchy tokens (``toks[0]`` is ``HIERARCHY``), in file order."""
    joints: list[BvhJoint] = []
    stack: list[int] = []  # joint index per open brace (-2 for an End Site)
    pending: tuple[str, int] | None = None  # (name, parent) of a joint whose brace is not open yet
    k = 1
    n = len(toks)
    while k < n:
        t, ln = toks[k]
        u = t.upper()
        if u in ("ROOT", "JOINT"):
            name, _ = _token(path, toks, k + 1, "a joint name")
            if name in ("{", "}"):
                raise InputFileError(f"{path}: line {ln}: {u} without a joint name")
            k += 2
            while k < n and toks[k][1] == ln and toks[k][0] not in ("{", "}"):   # 'Bip01 Head': one name
                name += " " + toks[k][0]
                k += 1
            if u == "JOINT" and not stack:
                raise InputFileError(f"{path}: line {ln}: JOINT outside of any ROOT")
            parent = -1 if u == "ROOT" else next((s for s in reversed(stack) if s >= 0), -1)
            if not (name.isprintable() and len(name) <= 200):
                raise InputFileError(f"{path}: line {ln}: joint name {excerpt(name)} is not a name")
            pending = (name, parent)
        elif u == "END":
            nxt, _ = _token(path, toks, k + 1, "'Site'")
            if nxt.upper() != "SITE":
                raise InputFileError(f"{path}: line {ln}: expected 'End Site'")
            pending = ("__end__", -2)
            k += 2
        elif t == "{":
            _open_brace(path, ln, pending, joints, stack)
            pending = None
            k += 1
        elif t == "}":
            if not stack:
                raise InputFileError(f"{path}: line {ln}: unbalanced '}}'")
            stack.pop()
            k += 1
        elif u == "OFFSET":
            if not stack:
                raise InputFileError(f"{path}: line {ln}: OFFSET outside of a joint")
            _read_offset(path, toks, k, joints, stack)
            k += 4
        elif u == "CHANNELS":
            if not stack or stack[-1] < 0:
                raise InputFileError(f"{path}: line {ln}: CHANNELS outside of a joint")
            cnt, chans = _read_channels(path, toks, k, ln)
            joints[stack[-1]].channels = chans
            k += 2 + cnt
        else:
            raise InputFileError(f"{path}: line {ln}: unexpected {excerpt(t)} in the hierarchy")
    if stack:
        raise InputFileError(f"{path}: the hierarchy has {len(stack)} unclosed '{{'")
    if not joints:
        raise InputFileError(f"{path}: the hierarchy has no joint")
    return joints


def _motion_header(path: Path, lines: list[str], motion_line: int) -> tuple[int, float, int]:
    """``Frames:`` and ``Frame Time:`` after the ``MOTION`` line, and the index of the next line."""
    i = motion_line + 1
    header: dict[str, tuple[str, int]] = {}
    while i < len(lines) and len(header) < 2:
        s = lines[i].strip()
        if s and not _comment(s):
            key, _, val = s.partition(":")
            key = key.strip().lower()
            if key not in ("frames", "frame time"):
                raise InputFileError(f"{path}: line {i + 1}: expected 'Frames:' and 'Frame Time:', got {excerpt(s)}")
            header[key] = (val.strip(), i + 1)
        i += 1
    if len(header) < 2:
        raise InputFileError(f"{path}: MOTION needs 'Frames:' and 'Frame Time:' lines")
    try:
        n_frames = int(header["frames"][0])
    except ValueError:
        raise InputFileError(f"{path}: line {header['frames'][1]}: frame count "
                             f"{excerpt(header['frames'][0])} is not an integer") from None
    if n_frames < 1:
        raise InputFileError(f"{path}: line {header['frames'][1]}: frame count {n_frames} is not positive")
    frame_time = _num(path, header["frame time"][1], header["frame time"][0])
    if frame_time <= 0:
        raise InputFileError(f"{path}: line {header['frame time'][1]}: frame time must be positive")
    return n_frames, frame_time, i


def _motion_rows(path: Path, lines: list[str], start: int, n_frames: int, C: int) -> np.ndarray:
    """The (n_frames, C) channel values of the frame rows from ``lines[start]`` on."""
    rows_text = [(j + 1, lines[j]) for j in range(start, len(lines)) if lines[j].strip() and not _comment(lines[j])]
    if len(rows_text) < n_frames:
        raise InputFileError(f"{path}: 'Frames: {n_frames}' but only {len(rows_text)} frame rows")
    if len(rows_text) > n_frames:
        warnings.warn(f"{path}: {len(rows_text)} frame rows but 'Frames: {n_frames}'; the first {n_frames} are read "
                      f"(line {rows_text[n_frames][0]} on is not)", DataWarning, stacklevel=3)
    rows_text = rows_text[:n_frames]
    try:
        flat = np.array(" ".join(r for _, r in rows_text).split(), dtype=np.float64)
    except ValueError:
        flat = None
    if flat is None or flat.size != n_frames * C or not (np.abs(flat) <= _MAX_VALUE).all():
        for ln, r in rows_text:  # find the faulty row for the message
            parts = r.split()
            if len(parts) != C:
                raise InputFileError(f"{path}: line {ln}: {len(parts)} values, "
                                     f"the hierarchy has {C} channels")
            for p in parts:
                _num(path, ln, p)
        raise InputFileError(f"{path}: malformed motion data")
    return flat.reshape(n_frames, C)


def read_bvh(path: str | os.PathLike) -> Bvh:
    """Read a ``.bvh`` file.

    Returns
    -------
    Bvh
        Joints with offsets and channels, frame time, and the (T, C) channel values.

    Raises
    ------
    InputFileError
        Missing file, malformed hierarchy (naming the line), unknown channel names or a negative
        channel count, a frame row with the wrong number of values, a non-numeric, non-finite or
        absurd (beyond +-1e15) value (naming the line), or fewer frames than ``Frames:`` announces.

    Warns
    -----
    DataWarning
        More frame rows than ``Frames:`` announces (the first are read), or one name for several joints.
    """
    path = input_file(path)
    text = read_text(path)
    lines = text.splitlines()
    toks, motion_line = _hierarchy_tokens(path, lines)
    joints = _parse_hierarchy(path, toks)
    # MOTION: Frames: N / Frame Time: dt / rows
    n_frames, frame_time, first_row = _motion_header(path, lines, motion_line)
    C = sum(len(j.channels) for j in joints)
    motion = _motion_rows(path, lines, first_row, n_frames, C)
    seen: dict[str, int] = {}
    for j in joints:
        seen[j.name] = seen.get(j.name, 0) + 1
    twice = [n for n, k in seen.items() if k > 1]
    if twice:
        warnings.warn(f"{path}: joint name(s) {', '.join(excerpt(n, bare=True) for n in twice[:8])} used by more than "
                      "one joint; a name finds the first of them (head motion, key frames)", DataWarning, stacklevel=2)
    return Bvh(joints, frame_time, motion, source=str(path))


# ------------------------------------------------------------------------------------------ writing
def write_bvh(path: str | os.PathLike, bvh: Bvh, decimals: int = 6) -> Path:
    """Write a :class:`Bvh` to ``path``, whole or not at all.

    Parameters
    ----------
    decimals : int
        Decimals of every motion value (6 keeps angles to 5e-7 degrees).
    """
    path = check_output_path(path)
    if not np.isfinite(bvh.motion).all():
        f = int(np.flatnonzero(~np.isfinite(bvh.motion).all(axis=1))[0])
        raise InvalidDataError(f"{path}: frame {f} has a non-finite channel value")
    children: dict[int, list[int]] = {}
    for i, j in enumerate(bvh.joints):
        children.setdefault(j.parent, []).append(i)
    out = ["HIERARCHY"]

    def fmt3(v) -> str:
        return " ".join(f"{float(x):.6f}" for x in v)

    def emit(i: int, depth: int) -> None:
        j = bvh.joints[i]
        ind = "\t" * depth
        out.append(f"{ind}{'ROOT' if j.parent < 0 else 'JOINT'} {j.name}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET {fmt3(j.offset)}")
        if j.channels:
            out.append(f"{ind}\tCHANNELS {len(j.channels)} {' '.join(j.channels)}")
        for c in children.get(i, []):
            emit(c, depth + 1)
        if j.end_site is not None:
            out.extend([f"{ind}\tEnd Site", f"{ind}\t{{", f"{ind}\t\tOFFSET {fmt3(j.end_site)}", f"{ind}\t}}"])
        out.append(f"{ind}}}")

    for r in children.get(-1, []):
        emit(r, 0)
    out += ["MOTION", f"Frames: {bvh.n_frames}", f"Frame Time: {bvh.frame_time:.10g}"]
    m = np.where(bvh.motion == 0, 0.0, bvh.motion)  # no "-0.000000"
    fmt = " ".join([f"%.{int(decimals)}f"] * m.shape[1])
    body = "\n".join(fmt % tuple(r) for r in m.tolist())
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(out) + "\n" + body + ("\n" if body else ""), encoding="utf-8")
    return path


def make_head_bvh(head: HeadPose, fps: float, joint: str = "Head",
                  end_site: tuple[float, float, float] = (0.0, 10.0, 0.0)) -> Bvh:
    """The minimal head skeleton: one root joint animated by the head pose.

    Parameters
    ----------
    head : HeadPose
        Written as ``Yrotation Xrotation Zrotation`` channels, degrees (the intrinsic Y-X-Z angles
        of :mod:`faceretarget.headpose`: yaw, then pitch > 0 nodding down, then roll), preceded by
        ``Xposition Yposition Zposition`` in centimetres when the pose has a translation.
    fps : float
        Frame rate.
    joint : str
        Name of the joint.
    end_site : 3 floats
        The ``End Site`` offset in centimetres (the top of the head; for viewers that draw bones).
    """
    if not head.valid.all():
        raise InvalidDataError(f"{head.source}: frame {int(np.flatnonzero(~head.valid)[0])} has no head pose; "
                               "a BVH needs one in every frame")
    r = head.to_euler("YXZ", degrees=True)
    chans: tuple[str, ...] = ("Yrotation", "Xrotation", "Zrotation")
    motion = r
    tr = head.translation_in("cm")
    if tr is not None:
        chans = ("Xposition", "Yposition", "Zposition") + chans
        motion = np.concatenate([tr, r], axis=1)
    j = BvhJoint(joint, -1, np.zeros(3), chans, np.asarray(end_site, np.float64))
    return Bvh([j], 1.0 / float(fps), motion, source=joint)


# ------------------------------------------------------------------------------------ poses (skeletal keys)
def bvh_pose(bvh: Bvh) -> tuple[np.ndarray, np.ndarray]:
    """Every joint's local rotation and position channels per frame.

    Returns
    -------
    rotations : (T, J, 4) float
        Local rotations as unit quaternions ``x, y, z, w`` (identity for a joint without rotation
        channels), composed in each joint's own channel order.
    positions : (T, J, 3) float
        Every joint's local translation in the file's length unit (:meth:`Bvh.local_translations`:
        the position channels where a joint has them, its offset elsewhere); a joint sits at
        ``position`` in its parent's frame.
    """
    T, J = bvh.n_frames, len(bvh.joints)
    rot = np.empty((T, J, 4))
    pos = np.empty((T, J, 3))
    for i in range(J):
        rot[:, i] = Rotation.from_matrix(bvh.local_rotations(i)).as_quat()
        pos[:, i] = bvh.local_translations(i)
    return rot, pos


def bvh_world_positions(bvh: Bvh, rotations: np.ndarray | None = None,
                        positions: np.ndarray | None = None) -> np.ndarray:
    """World positions of every joint by forward kinematics (the skeleton's root frame is the world).

    Parameters
    ----------
    bvh : Bvh
        The hierarchy (offsets); its own motion unless ``rotations`` / ``positions`` are given.
    rotations : (T, J, 4) float, optional
        Local rotations (quaternions ``x, y, z, w``), as :func:`bvh_pose` gives them.
    positions : (T, J, 3) float, optional
        Local translations (:func:`bvh_pose`).

    Returns
    -------
    (T, J, 3) float
        In the file's length unit.
    """
    if rotations is None or positions is None:
        r0, p0 = bvh_pose(bvh)
        rotations = r0 if rotations is None else rotations
        positions = p0 if positions is None else positions
    q = np.asarray(rotations, dtype=np.float64)
    pos = np.asarray(positions, dtype=np.float64)
    T, J = q.shape[:2]
    if q.shape != (T, len(bvh.joints), 4) or pos.shape != (T, J, 3):
        raise InvalidDataError(f"{bvh.source}: rotations must be (T, {len(bvh.joints)}, 4) and positions (T, "
                               f"{len(bvh.joints)}, 3), got {q.shape} and {pos.shape}")
    local = Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(T, J, 3, 3)
    world_R = np.empty((T, J, 3, 3))
    world_p = np.empty((T, J, 3))
    for i, j in enumerate(bvh.joints):
        t = pos[:, i]
        if j.parent < 0:
            world_R[:, i] = local[:, i]
            world_p[:, i] = t
        else:
            world_p[:, i] = world_p[:, j.parent] + np.einsum("tij,tj->ti", world_R[:, j.parent], t)
            world_R[:, i] = world_R[:, j.parent] @ local[:, i]
    return world_p


def bvh_with_pose(bvh: Bvh, rotations: np.ndarray, positions: np.ndarray, frame_time: float | None = None,
                  source: str | None = None) -> Bvh:
    """A :class:`Bvh` of ``bvh``'s hierarchy and channels whose motion is the given pose per frame.

    Each joint's rotation becomes Euler angles (degrees) in the joint's own channel order; a joint
    without rotation channels must keep the identity (its rotation is not written).

    Parameters
    ----------
    bvh : Bvh
        The hierarchy and channel layout.
    rotations : (T, J, 4) float
        Local rotations, quaternions ``x, y, z, w``.
    positions : (T, J, 3) float
        Local translations (only the axes a joint has position channels for are written).
    frame_time : float, optional
        Seconds per frame (default ``bvh``'s).
    """
    import warnings

    q = np.asarray(rotations, dtype=np.float64)
    pos = np.asarray(positions, dtype=np.float64)
    T, J = q.shape[0], len(bvh.joints)
    if q.shape != (T, J, 4) or pos.shape != (T, J, 3):
        raise InvalidDataError(f"{bvh.source}: rotations must be (T, {J}, 4) and positions (T, {J}, 3), "
                               f"got {q.shape} and {pos.shape}")
    C = sum(len(j.channels) for j in bvh.joints)
    motion = np.zeros((T, C))
    for i, j in enumerate(bvh.joints):
        rot = [(k, _ROT[c.lower()]) for k, c in enumerate(j.channels) if c.lower() in _ROT]
        if rot:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)        # gimbal lock: any of the equal angle sets
                ang = Rotation.from_quat(q[:, i]).as_euler("".join(a for _, a in rot), degrees=True)
            for n, (k, _) in enumerate(rot):
                motion[:, bvh._start[i] + k] = ang[:, n]
        for k, c in enumerate(j.channels):
            if c.lower() in _POS:
                motion[:, bvh._start[i] + k] = pos[:, i, _POS[c.lower()]]
    return Bvh([BvhJoint(j.name, j.parent, np.asarray(j.offset).copy(), tuple(j.channels),
                         None if j.end_site is None else np.asarray(j.end_site).copy()) for j in bvh.joints],
               bvh.frame_time if frame_time is None else float(frame_time), motion, source=source or bvh.source)


def read_key_frames(path: str | os.PathLike) -> tuple[dict[str, int], int | None]:
    """Which frames of a pose file (BVH, glTF skin) are which keys.

    ``.json``: an object ``{"neutral": 0, "frame_00123": 57, ...}`` (key name -> frame) or a list of
    key names, entry ``i`` naming frame ``i``; ``.csv``: rows ``key,frame`` (a header line is
    skipped); ``.txt``: one key name per line, line ``i`` naming frame ``i``.  The key ``neutral``
    names the rest pose; a list without one starts at frame 1 after the rest pose in frame 0.

    Returns
    -------
    frames : dict of str to int
        Key name -> frame (0-based).
    neutral : int or None
        The rest frame when the file names one (a list without ``neutral``: 0).

    Raises
    ------
    InputFileError
        Unreadable, a frame that is not a non-negative integer, or a key named twice (naming the line).
    """
    import json

    path = input_file(path)
    ext = path.suffix.lower()
    text = read_text(path)
    pairs: list[tuple[str, object, str]] = []            # (name, frame, where)
    listed: list[tuple[str, str]] | None = None
    if ext == JSON:
        try:
            doc = json.loads(text)
        except ValueError as e:
            raise InputFileError(f"{path}: not JSON ({excerpt(e, 80)})") from None
        if isinstance(doc, dict):
            pairs = [(str(k), v, f"key '{excerpt(k, bare=True)}'") for k, v in doc.items()]
        elif isinstance(doc, list) and all(isinstance(v, str) for v in doc):
            listed = [(v, f"entry {i}") for i, v in enumerate(doc)]
        else:
            raise InputFileError(f"{path}: expected an object {{key: frame}} or a list of key names")
    elif ext == CSV:
        for n, line in enumerate(text.splitlines(), 1):
            s = line.strip()
            if not s:
                continue
            parts = [p.strip() for p in s.split(",")]
            if len(parts) != 2:
                raise InputFileError(f"{path}: line {n}: expected 'key,frame', got {excerpt(s)}")
            if n == 1 and not parts[1].lstrip("-").isdigit():
                continue                                    # a header
            pairs.append((parts[0], parts[1], f"line {n}"))
    elif ext == ".txt":
        listed = [(s.strip(), f"line {n}") for n, s in enumerate(text.splitlines(), 1) if s.strip()]
    else:
        raise InputFileError(f"{path}: unknown key-frame format '{ext}' (use .json, .csv or .txt)")
    if listed is not None:
        names = [n for n, _ in listed]
        start = 0 if "neutral" in names else 1
        pairs = [(n, i + start, w) for i, (n, w) in enumerate(listed)]
        if start == 1:
            pairs.append(("neutral", 0, "the rest pose"))
    frames: dict[str, int] = {}
    for name, v, where in pairs:
        if not name or not name.isprintable() or len(name) > 200:
            raise InputFileError(f"{path}: {where}: {excerpt(name)} is not a key name")
        try:
            f = int(v) if not isinstance(v, bool) and (isinstance(v, int) or str(v).strip().isdigit()) else None
        except (TypeError, ValueError):
            f = None
        if f is None or f < 0:
            raise InputFileError(f"{path}: {where}: frame {excerpt(v)} is not a frame number (0, 1, 2, ...)")
        if name in frames:
            raise InputFileError(f"{path}: {where}: key '{excerpt(name, bare=True)}' is named twice")
        frames[name] = f
    neutral = frames.pop("neutral", None)
    if not frames:
        raise InputFileError(f"{path}: names no key frame")
    return frames, neutral
