"""Every file extension the project knows, declared once: character formats and the extensions of motion files.

A character format is one :class:`CharacterFormat` declaration in :data:`CHARACTER_FORMATS`, the way trimesh's
``exchange`` declares its loaders: its extensions, the route that reads it, its reader and the writers that
put an animation or new shapes back into a copy of it (as ``"module:function"`` names, imported only when
used, so declaring a format needs none of its packages), what it needs installed, which output extensions
write back into a copy of the user's file, and whether reading it is slow enough to cache.  Every extension
check, every "needs bpy" message and every write-back decision in the package comes from here:
:func:`faceretarget.io.read_character` reads through :attr:`CharacterFormat.reader`,
:func:`faceretarget.io.writes_back` and :func:`faceretarget.io.check_character_route` read the declarations.
A new format is one declaration plus its reader (and writers).

Motion files (takes, head motion, animations) are read and written through :mod:`faceretarget.io`'s
extension registry (``READERS`` / ``WRITERS``); the extensions those and the rest of the package test for are
the constants below (:data:`GLB`, :data:`USD_WRITE`, ...).
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CharacterFormat", "CHARACTER_FORMATS", "character_format_of", "format_named", "extension",
           "CHARACTER_EXTENSIONS", "GLB", "GLTF", "VRM", "FBX", "BLEND", "NPZ", "OBJ", "BVH", "CSV", "C3D", "MP4",
           "USDA", "USDC", "USD", "USDZ", "USD_WRITE", "USD_READ", "BLENDER_FILES", "OUTPUT_NEEDS",
           "CLAMPED_IN_BLENDER", "BAKED_FORMATS", "VRMA", "NPY", "JSON", "SVG", "PNG", "WAV",
           "VIDEO_EXTENSIONS"]

GLB, GLTF, VRM, FBX, BLEND = ".glb", ".gltf", ".vrm", ".fbx", ".blend"
NPZ, OBJ, BVH, CSV, C3D, MP4 = ".npz", ".obj", ".bvh", ".csv", ".c3d", ".mp4"
USD, USDA, USDC, USDZ = ".usd", ".usda", ".usdc", ".usdz"
#: USD files the project writes (a ``.usdz`` package is read only).
USD_WRITE = (USD, USDA, USDC)
USD_READ = USD_WRITE + (USDZ,)
#: Files only Blender writes (and reads, for ``.blend``).
BLENDER_FILES = (BLEND, FBX)


@dataclass(frozen=True)
class CharacterFormat:
    """One character format (module docstring).

    Attributes
    ----------
    name : str
        :attr:`~faceretarget.character.Character.format` of the characters it reads (``aliases``: other
        values a reader may set, e.g. ``"vrm0"`` / ``"vrm1"`` for the two VRM versions).
    extensions : tuple of str
        Lower-case suffixes with the dot; empty for a folder format.
    route : str
        What reads it, for messages.
    reader : str
        ``"module:function"``: ``function(path, prefer=None) -> Character``.
    read_needs : tuple of str
        Import names reading needs (all of them), unless ``read_fallback`` is installed instead.
    read_fallback : tuple of str
        Import names of a second route when ``read_needs`` are missing (FBX: Blender when ufbx is not there).
    writes_back : tuple of str
        Output extensions that put an animation or new shapes into a copy of the user's file.
    write_needs : tuple of str
        Import names writing back needs (but for ``direct_writes``).
    direct_writes : tuple of str
        Output extensions among ``writes_back`` that a writer of the project's own puts into the copy
        without ``write_needs`` (FBX into ``.fbx``: the binary node tree is edited directly, no Blender).
    animation_writer, shapes_writer : str
        ``"module:function"`` of the write-back routes (empty: not supported).
    slow_read : bool
        Reading goes through a slow route (Blender): the read character is cached by content.
    folder : bool
        The format is a folder (of OBJ files), not a file.
    """

    name: str
    extensions: tuple[str, ...]
    route: str
    reader: str
    read_needs: tuple[str, ...] = ()
    read_fallback: tuple[str, ...] = ()
    writes_back: tuple[str, ...] = ()
    write_needs: tuple[str, ...] = ()
    direct_writes: tuple[str, ...] = ()
    animation_writer: str = ""
    shapes_writer: str = ""
    slow_read: bool = False
    folder: bool = False
    aliases: tuple[str, ...] = ()

    def read(self, path: str | os.PathLike, prefer: str | None = None):
        """Read ``path`` through this format's reader."""
        return _resolve(self.reader)(Path(path), prefer)

    def needs_for(self, installed) -> tuple[str, ...]:
        """The import names reading needs given ``installed(name) -> bool``: the main route's when it is
        complete or there is no fallback, else the fallback's."""
        if not self.read_fallback or all(installed(n) for n in self.read_needs):
            return self.read_needs
        return self.read_fallback

    def write_needs_for(self, out: str | os.PathLike) -> tuple[str, ...]:
        """The import names writing the animation back into ``out`` needs (none for a ``direct_writes``
        extension; the writer falls back to ``write_needs``' route only for a file it cannot edit)."""
        return () if extension(out) in self.direct_writes else self.write_needs


def _resolve(spec: str):
    module, _, attr = spec.partition(":")
    return getattr(importlib.import_module(module), attr)


_IO = "faceretarget.io."
_ANIM, _SHAPES = _IO + "_character_write:write_character_animation", _IO + "_shapes_write:write_character_shapes"

#: Every character format, by :attr:`CharacterFormat.name`.
CHARACTER_FORMATS: dict[str, CharacterFormat] = {f.name: f for f in (
    CharacterFormat("gltf", (GLB, GLTF), "glTF 2.0 (core: meshopt, DracoPy for compressed files)",
                    _IO + "_character:read_gltf_route", writes_back=(GLB, GLTF),
                    animation_writer=_ANIM, shapes_writer=_SHAPES),
    CharacterFormat("vrm", (VRM,), "glTF 2.0 with VRM 0.x / 1.0 extensions", _IO + "_character:read_gltf_route",
                    writes_back=(VRM, GLB), animation_writer=_ANIM, shapes_writer=_SHAPES, aliases=("vrm0", "vrm1")),
    CharacterFormat("fbx", (FBX,), "ufbx (core), else Blender's importer", _IO + "_character:read_fbx_route",
                    read_needs=("ufbx",), read_fallback=("bpy",), writes_back=(FBX, BLEND), write_needs=("bpy",),
                    direct_writes=(FBX,), animation_writer=_ANIM, shapes_writer=_SHAPES, slow_read=True),
    CharacterFormat("blend", (BLEND,), "Blender itself (bpy)", _IO + "_character:read_blender_route",
                    read_needs=("bpy",), writes_back=(BLEND, FBX), write_needs=("bpy",),
                    animation_writer=_ANIM, shapes_writer=_SHAPES, slow_read=True),
    CharacterFormat("usd", USD_READ, "usd-core (UsdSkel blend shapes)", _IO + "_character:read_usd_route",
                    read_needs=("pxr",), writes_back=USD_WRITE, write_needs=("pxr",),
                    animation_writer=_ANIM, shapes_writer=_SHAPES),
    CharacterFormat("npz", (NPZ,), ".npz rig", _IO + "_character:read_npz_route"),
    CharacterFormat("obj", (), "OBJ folder", _IO + "_character:read_obj_folder_route", folder=True),
)}

#: Extensions :func:`faceretarget.io.read_character` reads (besides folders of OBJ files).
CHARACTER_EXTENSIONS = tuple(e for f in CHARACTER_FORMATS.values() for e in f.extensions)


def extension(path: str | os.PathLike) -> str:
    """``path``'s lower-case suffix with the dot (``""`` for none)."""
    return Path(path).suffix.lower()


def character_format_of(path: str | os.PathLike) -> CharacterFormat | None:
    """The character format of ``path`` (a folder is the OBJ-folder format), None when it is not one."""
    p = Path(path)
    if p.is_dir():
        return CHARACTER_FORMATS["obj"]
    ext = extension(p)
    return next((f for f in CHARACTER_FORMATS.values() if ext in f.extensions), None)


def format_named(name: str | None) -> CharacterFormat | None:
    """The format whose name or alias is ``name`` (a :attr:`~faceretarget.character.Character.format`)."""
    return next((f for f in CHARACTER_FORMATS.values() if name == f.name or name in f.aliases), None)


#: Optional packages an output file needs, by extension (``.mp4``: previews, overlays, restyled videos and
#: drawing animations are encoded with PyAV); an animation written back into a copy of a character file needs
#: what its format says instead (:meth:`CharacterFormat.write_needs_for`: an ``.fbx`` into ``.fbx``, nothing).
OUTPUT_NEEDS: dict[str, tuple[str, ...]] = {
    BLEND: ("bpy",), FBX: ("bpy",), **{e: ("pxr",) for e in USD_WRITE}, MP4: ("av",),
}
#: Motion-file formats whose importers in Blender play shape-key weights only inside [0, 1].
CLAMPED_IN_BLENDER: dict[str, str] = {GLB: "Blender's glTF importer",
                                      **{e: "Blender's USD importer" for e in USD_WRITE}}
#: Motion-file formats with a baked variant (mesh points per frame).
BAKED_FORMATS = USD_WRITE

# the other extensions the package tests for
VRMA, NPY, JSON, SVG, PNG, WAV = ".vrma", ".npy", ".json", ".svg", ".png", ".wav"
#: Video containers a take is tracked from (anything else is a motion file or a character).
VIDEO_EXTENSIONS = (MP4, ".mov", ".avi", ".mkv", ".flv", ".webm", ".m4v")
