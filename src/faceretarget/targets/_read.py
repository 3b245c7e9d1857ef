"""``--target-keys PATH``: which kind of target a path holds, and reading it."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..errors import InputFileError, InvalidDataError, MissingShapeError
from ..formats import BVH, GLB, SVG
from ..io import (
    CONTROL_TABLE_FORMATS,
    POINT_SET_FORMATS,
    Bvh,
    BvhJoint,
    is_keyshape_folder,
    read_bvh,
    read_control_table,
    read_glb_skeleton,
    read_key_frames,
    read_keys,
    read_point_set,
    read_svg_drawing,
)
from ..rig import Rig
from ._base import MeshTarget, Target
from ._controls import ControlTarget
from ._drawing import DrawingTarget
from ._skeleton import SkeletonTarget

__all__ = ["read_target", "target_kind", "TARGET_KINDS"]

TARGET_KINDS = ("mesh", "controls", "skeleton", "drawing")


def target_kind(path: str | os.PathLike) -> str:
    """The kind of target ``path`` holds, from its name and a folder's listing (nothing is read):
    ``"controls"`` (a ``.csv`` / ``.json`` table), ``"skeleton"`` (``.bvh``, ``.glb``), ``"drawing"``
    (a folder of ``.svg`` files or ``.npy`` / ``.csv`` point sets) or ``"mesh"`` (a keyshape or rig
    folder of OBJ files, anything else)."""
    p = Path(path)
    if p.is_dir():
        if is_keyshape_folder(p) or any(p.glob("*.obj")):
            return "mesh"
        if any(p.glob("*.svg")) or any(p.glob("*.npy")):
            return "drawing"
        if any(p.glob("*.csv")):
            return "drawing"
        return "mesh"
    ext = p.suffix.lower()
    if ext in CONTROL_TABLE_FORMATS:
        return "controls"
    if ext in (BVH, GLB):
        return "skeleton"
    return "mesh"


def _frames_arg(frames, path: Path) -> tuple[dict[str, int], int | None]:
    if frames is None:
        raise InvalidDataError(f"{path}: a skeleton target needs the frames holding the key poses (--target-frames "
                               "FILE: a JSON/CSV mapping key name -> frame, or key names in frame order)")
    if isinstance(frames, Mapping):
        d = {str(k): v for k, v in frames.items()}
        n = d.pop("neutral", None)
        return d, n
    if isinstance(frames, str | os.PathLike):
        return read_key_frames(frames)
    if isinstance(frames, Sequence):
        names = [str(f) for f in frames]
        start = 0 if "neutral" in names else 1
        d = {n: i + start for i, n in enumerate(names)}
        return d, d.pop("neutral", 0)
    raise InvalidDataError(f"{path}: frames must be a mapping, a list of key names or a file, got {type(frames).__name__}")


def _glb_as_bvh(path: Path) -> tuple[Bvh, str]:
    """A glTF skin's animation as a BVH-like hierarchy: rotation channels on every joint, position
    channels on the roots (glTF is in metres)."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    s = read_glb_skeleton(path)
    joints = []
    for i, n in enumerate(s.names):
        ch = ("Xposition", "Yposition", "Zposition") if s.parents[i] < 0 else ()
        joints.append(BvhJoint(n, int(s.parents[i]), s.rest[i].copy(), ch + ("Zrotation", "Xrotation", "Yrotation")))
    for i, j in enumerate(joints):
        if j.parent >= i:
            raise InputFileError(f"{path}: joint '{j.name}' comes before its parent in the skin")
    T = len(s.times)
    cols = []
    for i in range(len(joints)):
        if s.parents[i] < 0:
            cols.append(s.translations[:, i])            # position channels: the full local translation
        cols.append(Rotation.from_quat(s.rotations[:, i]).as_euler("ZXY", degrees=True))
    motion = np.concatenate(cols, axis=1) if cols else np.zeros((T, 0))
    dt = float(np.median(np.diff(s.times))) if T > 1 else 1.0 / 30.0
    return Bvh(joints, dt if dt > 0 else 1.0 / 30.0, motion, source=str(path)), "m"


def read_target(path: str | os.PathLike, *, rig: Rig | None = None, frames=None, neutral=None,
                landmarks=None, unit: str | None = None, ranges: str = "solve") -> Target:
    """Read the target keys at ``path`` (:func:`target_kind` decides how).

    Parameters
    ----------
    path : path-like
        A control table (``.csv`` / ``.json``, :func:`~faceretarget.io.read_control_table`); a pose
        file (``.bvh``, or a ``.glb`` with a skin) with ``frames``; a folder of key drawings
        (``neutral.svg`` + ``<key>.svg``) or 2-D point sets (``neutral.npy`` + ``<key>.npy``, or
        ``.csv``); or a folder of mesh keyshapes / a rig (:func:`~faceretarget.io.read_keys`).
    rig : Rig, optional
        A control table's rig (its shapes named like the controls).
    frames : path-like, mapping or list of str, optional
        For a pose file: key name -> frame (``neutral`` the rest pose, default frame 0), or a file
        of them (:func:`~faceretarget.io.read_key_frames`).
    neutral : path-like, optional
        A mesh folder's neutral OBJ, or a drawing folder's neutral file (default ``neutral.*``).
    landmarks : path-like, optional
        A mesh folder's landmark index file.
    unit : str, optional
        A skeleton's length unit (default ``cm`` for BVH, ``m`` for glTF).
    ranges : {"solve", "report", "clip", "project"}
        What a control target does with controls outside their declared ranges (:class:`ControlTarget`).

    Raises
    ------
    InputFileError, InvalidDataError, MissingShapeError
        Naming the file, row, path or frame at fault.
    """
    p = Path(path)
    if not p.exists():
        raise InputFileError(f"{p}: target keys not found")
    kind = target_kind(p)
    if kind == "controls":
        return ControlTarget(read_control_table(p), rig, ranges=ranges)
    if kind == "skeleton":
        keys, nf = _frames_arg(frames, p)
        if p.suffix.lower() == BVH:
            bvh, u = read_bvh(p), "cm"
        else:
            bvh, u = _glb_as_bvh(p)
        return SkeletonTarget(bvh, keys, 0 if nf is None else nf, unit=unit or u, source=str(p))
    if kind == "drawing":
        return _read_drawings(p, neutral)
    keys, _ = read_keys(p, neutral=neutral, landmarks=landmarks)
    return MeshTarget(keys)


def _read_drawings(folder: Path, neutral=None) -> DrawingTarget:
    files = sorted(f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in (SVG,) + POINT_SET_FORMATS)
    exts = {f.suffix.lower() for f in files}
    if SVG in exts and exts - {SVG}:
        files = [f for f in files if f.suffix.lower() == SVG]
    npath = Path(neutral) if neutral is not None else next((f for f in files if f.stem.lower() == "neutral"), None)
    if npath is None or not npath.is_file():
        raise MissingShapeError(f"{folder}: no neutral drawing (neutral.svg, neutral.npy or neutral.csv): the "
                                "character at rest, with the same paths as every key drawing")

    def read(f: Path):
        return read_svg_drawing(f) if f.suffix.lower() == SVG else read_point_set(f)

    base = read(npath)
    keys = {}
    for f in files:
        if f.resolve() == npath.resolve() or f.stem.lower() == "neutral":
            continue
        keys[f.stem] = read(f)
    return DrawingTarget(base, keys, source=str(folder))
