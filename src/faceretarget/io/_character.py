"""Characters from any file a user has: one reader by extension, each giving a :class:`~faceretarget.character.Character`.

============================ =============================================== ===============================
input                         route                                           needs
============================ =============================================== ===============================
``.glb``, ``.gltf``, ``.vrm`` :func:`~faceretarget.io.read_gltf_character`     core (``meshopt``, ``DracoPy``
                                                                              for compressed files)
``.fbx``                      :func:`~faceretarget.io.read_fbx_character`      ``ufbx`` (core); Blender when
                              (ufbx), or Blender's importer                   ufbx is missing
``.blend``                    Blender itself (``bpy``)                        ``make blender``
``.usd .usda .usdc .usdz``    usd-core (UsdSkel blend shapes)                 the ``usd`` extra
folder of OBJ files           :func:`~faceretarget.io.read_rig`                core
``.npz`` rig                  :func:`~faceretarget.io.read_rig_npz`            core
============================ =============================================== ===============================

:func:`character_from_rig` turns a :class:`~faceretarget.rig.Rig` (an OBJ folder, a ``.npz`` rig, a demo
character) into a one-mesh character whose landmarks (when the rig has its 68) are points at those
vertices, facing +Z with +Y up as the project's rigs do.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..character import Character, SceneMesh, SurfacePoints
from ..errors import InputFileError
from ..formats import CHARACTER_EXTENSIONS, character_format_of, extension
from ..mesh import Mesh
from ..rig import Rig

__all__ = ["read_character", "character_from_rig", "CHARACTER_EXTENSIONS", "is_character_file", "character_format",
           "check_character_route"]


def is_character_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a character file (not a folder, not a ``.npz`` rig) by its extension."""
    f = character_format_of(path)
    return f is not None and not f.folder and f.name != "npz"


def character_format(path: str | os.PathLike) -> str:
    """The :attr:`~faceretarget.character.Character.format` a character file will have, by extension
    (``"vrm"`` for either VRM version; a folder is ``"obj"``; ``""`` when it is no character format)."""
    f = character_format_of(path)
    return "" if f is None else f.name


def check_character_route(path: str | os.PathLike, out: str | os.PathLike | None = None) -> None:
    """Refuse, before any work, a character route whose optional package is missing: reading ``path``
    and (with ``out``) writing the animation back into a copy of it (the needs its
    :class:`~faceretarget.formats.CharacterFormat` declares).

    Raises
    ------
    MissingDependencyError
        Naming what needs it and the install line that works (:func:`faceretarget.optional.install_line`).
    """
    from ..optional import has_module, require

    f = character_format_of(path)
    if f is None:
        return
    needs = f.needs_for(has_module)
    if needs:
        via = " or ".join("+".join(n) for n in (f.read_needs, f.read_fallback) if n)
        require(f"{path} (a {f.name} character, read by {f.route}; needs {via})", *needs)
    if out is None or extension(out) not in f.writes_back:
        return
    write_needs = f.write_needs_for(out)
    why = ""
    if not write_needs and f.write_needs and Path(path).is_file():   # a direct writer: can it edit this file?
        from ._fbx_write import direct_file_problem

        why = direct_file_problem(Path(path)) if f.name == "fbx" else None
        write_needs = f.write_needs if why else ()
    if write_needs:
        require(f"{out} (written back into a copy of the {f.name} character{f': {why}' if why else ''})",
                *write_needs)


def character_from_rig(rig: Rig, path: str | os.PathLike | None = None, route: str = "rig") -> Character:
    """A one-mesh character of a rig (unit converted to metres, shape names as the files gave them)."""
    s = rig.mm_per_unit / 1000.0
    m = rig.neutral
    uvs = None if m.uvs is None else np.stack([m.uvs[:, 0], 1.0 - m.uvs[:, 1]], axis=1)
    mesh = Mesh(m.vertices * s, m.face_counts, m.face_indices, uvs, m.face_uv_indices if uvs is not None else None,
                name=rig.name)
    names = list(rig.source_names) if rig.source_names is not None and len(set(rig.source_names)) == rig.n_shapes \
        else list(rig.names)
    sm = SceneMesh(rig.name, str(path) if path is not None else rig.name, mesh, names,
                   (rig.deltas * s).astype(np.float32))
    lm = None
    if rig.landmarks is not None and len(rig.landmarks) == 68:
        idx = np.asarray(rig.landmarks, dtype=np.int64)
        lm = SurfacePoints(0, np.stack([idx, idx, idx], axis=1), np.tile([1.0, 0.0, 0.0], (68, 1)),
                           "the rig's landmark file")
    return Character(None if path is None else Path(path), "obj" if route == "OBJ folder" else "npz"
                     if route == ".npz rig" else "rig", route, [sm], up=np.array([0.0, 1.0, 0.0]),
                     front=np.array([0.0, 0.0, 1.0]), landmarks=lm, source_unit=rig.unit, name=rig.name)


def read_character(path: str | os.PathLike, *, prefer: str | None = None) -> Character:
    """Read a character from any supported file or an OBJ folder (module docstring).

    Parameters
    ----------
    path : path-like
    prefer : str, optional
        ``"blender"`` to read ``.fbx`` through Blender instead of ufbx.

    Raises
    ------
    InputFileError
        Missing file, an unsupported extension (the message lists the supported ones), or a file the
        route cannot read.
    MissingDependencyError
        The route's optional package is not installed (the message says what to install).
    """
    p = Path(path)
    if not p.is_dir() and not p.exists():
        raise InputFileError(f"{p}: character file not found")
    f = character_format_of(p)
    if f is None:
        exts = ", ".join(CHARACTER_EXTENSIONS)
        raise InputFileError(f"{p}: '{p.suffix or p.name}' is not a character format; give a {exts} file "
                             "or a folder of OBJ files")
    return f.read(p, prefer)


# --------------------------------------------------------------------- the routes CHARACTER_FORMATS names
def read_gltf_route(p: Path, prefer: str | None = None) -> Character:
    from ._gltf_scene import read_gltf_character

    return read_gltf_character(p)


def read_fbx_route(p: Path, prefer: str | None = None) -> Character:
    from ..optional import has_module

    if prefer != "blender" and has_module("ufbx"):
        from ._fbx_scene import read_fbx_character

        return read_fbx_character(p)
    return read_blender_route(p)


def read_blender_route(p: Path, prefer: str | None = None) -> Character:
    from ._blender_scene import read_blender_character

    return read_blender_character(p)


def read_usd_route(p: Path, prefer: str | None = None) -> Character:
    from ._usd_scene import read_usd_character

    return read_usd_character(p)


def read_npz_route(p: Path, prefer: str | None = None) -> Character:
    from ._rig import read_rig_npz

    return character_from_rig(read_rig_npz(p), p, ".npz rig")


def read_obj_folder_route(p: Path, prefer: str | None = None) -> Character:
    from ._rig import read_rig

    return character_from_rig(read_rig(p), p, "OBJ folder")
