"""A user's character made ready to drive: read, landmarks found (or read from the cache), checked.

:func:`load_character` is what ``--character FILE`` / ``--target-rig FILE`` do: read the file whatever its
format (:func:`faceretarget.io.read_character`), find its 68 landmarks on a render
(:func:`faceretarget.capture.find_landmarks`) unless a landmark file is given or the cache has them,
and check it can be driven (face shapes, one head).  :func:`drive_rig` chooses the shapes that drive
(``--shapes``) and builds the one rig the solvers work on.  :func:`inspect_character` is
``faceretarget character inspect``.

The landmark cache
------------------
Found landmarks are kept in the user's cache folder (:func:`faceretarget.files.cache_dir`:
``$FACERETARGET_CACHE``, by default ``~/.cache/faceretarget`` on Linux) as ``landmarks/<sha256>.json``,
named by the SHA-256 of the character file's content, never beside the file (a user's asset folder may be
read-only, under version control or on a network share).  An edited character is searched again; a copy
or a moved file is found in the cache.  ``faceretarget --no-cache`` (``$FACERETARGET_NO_CACHE=1``) or
``cache=False`` neither reads nor writes it.  Its layout (also what ``--landmarks FILE.json`` takes)::

    {"format": "faceretarget.landmarks/1", "sha256": "...", "mesh": "H_DDS_HighRes", "vertices": 22249,
     "triangles": [[a, b, c], ...68], "bary": [[u, v, w], ...68], "up": [0, 1, 0], "front": [0, 0, 1],
     "source": "found on a render", "finder": 2}

``finder`` is the version of the search that found them (:data:`faceretarget.capture.FINDER_VERSION`): an entry
found by another version (or without one: before issue 34) is searched again and replaced, so an improved search
reaches characters already cached.  Records given with ``--landmarks`` and those without ``"source": "found on a
render"`` are used whatever their ``finder``.

The read cache
--------------
The readers that run outside this process (``.fbx`` through ufbx in a child process, ``.fbx`` / ``.blend``
through Blender) take about a second before any work; what they read is kept in
``characters/<sha256>-<route>.pickle`` in the same cache folder and read back when the file's SHA-256 and
the reader's own code are unchanged.  ``cache=False``, ``--no-cache`` (or deleting the folder) reads the
file again.

``--landmarks FILE.txt`` takes 68 vertex indices of the face mesh (``landmarks68.txt``'s layout) or 68
lines of ``x y z`` (metres, the file's world frame), each put on the nearest point of the face mesh.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..character import (
    Character,
    ShapeChoice,
    SurfacePoints,
    channels,
    choose_shapes,
    expression_channels,
    face_rig,
)
from ..errors import FaceNotFoundError, InputFileError, InvalidDataError, MissingShapeError
from ..files import atomic_path, cache_dir, cache_enabled, file_sha256
from ..formats import JSON, character_format_of
from ..rig import Rig
from ._frame import face_pitch_turn, face_turn

__all__ = ["load_character", "drive_rig", "DriveRig", "inspect_character", "CharacterReport", "landmark_cache_path",
           "look_rig", "character_look", "CharacterLook", "character_weights", "landmark_record", "apply_landmark_record", "mesh_sha256",
           "read_landmark_file",
           "LANDMARKS_FORMAT"]

LANDMARKS_FORMAT = "faceretarget.landmarks/1"
#: Regions of the 68 points, for grouping shapes by what they move.
REGIONS = {"jaw line": range(0, 17), "brows": range(17, 27), "nose": range(27, 36), "eyes": range(36, 48),
           "mouth": range(48, 68)}


#: The ``source`` of landmarks :func:`faceretarget.capture.find_landmarks` found.
FOUND_ON_A_RENDER = "found on a render"


def _finder_version() -> int:
    from ..capture import FINDER_VERSION

    return FINDER_VERSION


def _quiet(*_a) -> None:
    return None


def _sha256(path: Path) -> str:
    """A character's content digest: the file's (:func:`~faceretarget.files.file_sha256`), or a rig folder's
    (every file's name and bytes, in order)."""
    if not path.is_dir():
        return file_sha256(path)
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def landmark_cache_path(path: str | os.PathLike, sha: str | None = None, *, for_writing: bool = False) -> Path:
    """Where the landmarks of the character ``path`` are cached: ``landmarks/<sha256>.json`` in the cache
    folder (module docstring), whatever folder the character is in.  ``for_writing`` is accepted for
    callers of earlier releases and changes nothing."""
    return cache_dir("landmarks") / f"{sha or _sha256(Path(path))}.json"


READ_CACHE_FORMAT = "faceretarget.character-read/1"


def _reader_code_hash() -> str:
    """A digest of the code that makes a character from a file: a change to it invalidates the read cache."""
    from .. import character, io

    h = hashlib.sha256(READ_CACHE_FORMAT.encode())
    here = Path(io.__file__).parent
    for f in (Path(character.__file__), here / "_character.py", here / "_fbx_scene.py", here / "_blender_scene.py"):
        h.update(f.read_bytes() if f.is_file() else f.name.encode())
    return h.hexdigest()[:16]


def _read_cache_path(sha: str, prefer: str | None) -> Path:
    return cache_dir("characters") / f"{sha}-{prefer or 'auto'}-{_reader_code_hash()}.pickle"


def _read_character_cached(path: Path, prefer: str | None, cache: bool, log) -> tuple[Character, str | None]:
    """``read_character(path)``, through the read cache for the slow routes; also the file's SHA-256 when it
    was computed."""
    import pickle

    from ..io import read_character

    if not (cache and cache_enabled() and path.is_file() and getattr(character_format_of(path), "slow_read", False)):
        return read_character(path, prefer=prefer), None
    sha = _sha256(path)
    cand = _read_cache_path(sha, prefer)
    if cand.is_file():
        try:
            ch = pickle.loads(cand.read_bytes())
        except Exception:  # a damaged or foreign cache entry is read again from the file
            ch = None
        if isinstance(ch, Character):
            ch.path = path
            log(f"read {path.name} from the cache {cand}")
            return ch, sha
    ch = read_character(path, prefer=prefer)
    try:
        cand.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(cand) as tmp:
            Path(tmp).write_bytes(pickle.dumps(ch, protocol=pickle.HIGHEST_PROTOCOL))
    except OSError:
        pass                                    # no writable cache folder: the file is read again next time
    return ch, sha


def _read_cache(character: Character, path: Path, sha: str, log) -> bool:
    if not cache_enabled():
        return False
    cand = landmark_cache_path(path, sha)
    try:
        d = json.loads(cand.read_text(encoding="utf-8"))
    except (OSError, ValueError):                          # not cached, or damaged: searched again
        return False
    if d.get("format") != LANDMARKS_FORMAT or d.get("sha256") != sha:
        return False
    if str(d.get("source", "")).startswith(FOUND_ON_A_RENDER) and d.get("finder") != _finder_version():
        log(f"landmarks: {cand} was found by an earlier search (finder {d.get('finder', 1)}): searched again")
        return False
    try:
        _apply(character, d, str(cand))
    except (InvalidDataError, InputFileError, KeyError, ValueError, TypeError):
        return False
    log(f"landmarks: read from the cache {cand}")
    return True


def _apply(character: Character, d: dict, where: str) -> None:
    names = [m.name for m in character.meshes]
    if d.get("mesh") not in names:
        raise InputFileError(f"{where}: mesh '{d.get('mesh')}' is not in the character (it has {', '.join(names)})")
    mi = names.index(d["mesh"])
    m = character.meshes[mi]
    if int(d.get("vertices", -1)) != m.mesh.n_vertices:
        raise InputFileError(f"{where}: made for {d.get('vertices')} vertices, mesh '{m.name}' has {m.mesh.n_vertices}")
    tri = np.asarray(d["triangles"], dtype=np.int64)
    bary = np.asarray(d["bary"], dtype=np.float64)
    if tri.shape != (68, 3) or bary.shape != (68, 3) or tri.min() < 0 or tri.max() >= m.mesh.n_vertices \
            or not np.isfinite(bary).all():
        raise InputFileError(f"{where}: 'triangles' and 'bary' must be 68 x 3 (vertices of '{m.name}', weights)")
    character.landmarks = SurfacePoints(mi, tri, bary, d.get("source", where))
    if character.neutral_head is not None and not character.face_meshes():
        character.neutral_head = mi               # no face shapes: the face is where its landmarks are
    if d.get("up") is not None:
        character.up = np.asarray(d["up"], dtype=np.float64)
    if d.get("front") is not None:
        character.front = np.asarray(d["front"], dtype=np.float64)


def landmark_record(character: Character, sha: str | None = None) -> dict:
    """The character's landmarks as the cache's JSON record (module docstring); ``sha`` defaults to
    :func:`mesh_sha256` of the mesh they lie on (what a character without a file is checked by)."""
    lm = character.landmarks
    if lm is None:
        raise InvalidDataError(f"{character.name}: no landmarks to record")
    m = character.meshes[lm.mesh]
    return {"format": LANDMARKS_FORMAT, "sha256": sha or mesh_sha256(m.mesh), "mesh": m.name,
            "vertices": m.mesh.n_vertices, "triangles": lm.triangles.tolist(), "bary": np.round(lm.bary, 9).tolist(),
            "up": None if character.up is None else np.asarray(character.up, float).tolist(),
            "front": None if character.front is None else np.asarray(character.front, float).tolist(),
            "source": lm.source}


def apply_landmark_record(character: Character, record: dict, where: str = "landmark record") -> bool:
    """Put a :func:`landmark_record` on the character when it was made for the same mesh (name, vertex
    count and, when the record holds :func:`mesh_sha256`, the same rest shape); False when it was not."""
    if record.get("format") != LANDMARKS_FORMAT:
        return False
    names = [m.name for m in character.meshes]
    if record.get("mesh") not in names:
        return False
    sha = record.get("sha256")
    mesh = character.meshes[names.index(record["mesh"])].mesh
    if sha and len(sha) == 64 and sha != mesh_sha256(mesh):
        return False
    try:
        _apply(character, record, where)
    except (InvalidDataError, InputFileError, KeyError, ValueError, TypeError):
        return False
    return True


def mesh_sha256(mesh) -> str:
    """SHA-256 of a mesh's rest shape (vertices rounded to 0.1 micrometre, faces): what identifies the
    face a character without a file had its landmarks found on."""
    h = hashlib.sha256()
    h.update(np.round(np.asarray(mesh.vertices, np.float64) * 1e7).astype(np.int64).tobytes())
    h.update(np.asarray(mesh.face_counts, np.int64).tobytes())
    h.update(np.asarray(mesh.face_indices, np.int64).tobytes())
    return h.hexdigest()


def _write_cache(character: Character, path: Path, sha: str, log) -> Path | None:
    if not cache_enabled():
        return None
    d = landmark_record(character, sha)
    if str(d.get("source", "")).startswith(FOUND_ON_A_RENDER):
        d["finder"] = _finder_version()
    cand = landmark_cache_path(path, sha)
    try:
        cand.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(cand) as tmp:
            Path(tmp).write_text(json.dumps(d), encoding="utf-8")
    except OSError as e:
        log(f"landmarks: the cache folder {cand.parent} is not writable ({e.strerror or e}); they will be searched "
            "again next time (set FACERETARGET_CACHE to a writable folder)")
        return None
    log(f"landmarks: cached in {cand}")
    return cand


def read_landmark_file(character: Character, path: str | os.PathLike) -> SurfacePoints:
    """Landmarks from ``--landmarks FILE`` (module docstring): the JSON layout, 68 vertex indices of the
    face mesh, or 68 ``x y z`` positions put on its nearest surface points."""
    p = Path(path)
    if not p.is_file():
        raise InputFileError(f"{p}: landmark file not found")
    if p.suffix.lower() == JSON:
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except ValueError as e:
            raise InputFileError(f"{p}: not JSON ({str(e)[:60]})") from e
        _apply(character, d, str(p))
        return character.landmarks
    toks = p.read_text(encoding="utf-8", errors="replace").split()
    mi = character.primary
    m = character.meshes[mi].mesh
    if len(toks) == 68:
        try:
            idx = np.array([int(t) for t in toks], dtype=np.int64)
        except ValueError:
            raise InputFileError(f"{p}: 68 values but not all integers (vertex indices)") from None
        if idx.min() < 0 or idx.max() >= m.n_vertices:
            raise InputFileError(f"{p}: a vertex index is outside 0..{m.n_vertices - 1} of the face mesh "
                                 f"'{character.meshes[mi].name}'")
        return SurfacePoints(mi, np.stack([idx] * 3, axis=1), np.tile([1.0, 0.0, 0.0], (68, 1)), str(p))
    if len(toks) == 204:
        try:
            X = np.array([float(t) for t in toks]).reshape(68, 3)
        except ValueError:
            raise InputFileError(f"{p}: 204 values but not all numbers (68 x, y, z)") from None
        tri, bary = _nearest_surface(m.vertices, m.triangles(), X)
        return SurfacePoints(mi, tri, bary, str(p))
    raise InputFileError(f"{p}: expected 68 vertex indices or 68 lines of x y z, found {len(toks)} values")


def _nearest_surface(V: np.ndarray, T: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangle and barycentrics of the nearest surface point to each of ``X`` (n, 3)."""
    from scipy.spatial import cKDTree

    cent = V[T].mean(axis=1)
    tree = cKDTree(cent)
    _, cand = tree.query(X, k=min(16, len(T)))
    cand = np.atleast_2d(cand)
    tri_out, bary_out = [], []
    for x, cs in zip(X, cand, strict=True):
        best = (np.inf, None, None)
        for t in cs:
            a, b, c = V[T[t]]
            lam = _closest_bary(x, a, b, c)
            d = np.linalg.norm(lam @ np.stack([a, b, c]) - x)
            if d < best[0]:
                best = (d, T[t], lam)
        tri_out.append(best[1])
        bary_out.append(best[2])
    return np.array(tri_out), np.array(bary_out)


def _closest_bary(p, a, b, c) -> np.ndarray:
    """Barycentric coordinates of the point of triangle abc nearest ``p`` (Ericson, Real-Time Collision)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return np.array([1.0, 0.0, 0.0])
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return np.array([0.0, 1.0, 0.0])
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        v = d1 / (d1 - d3)
        return np.array([1 - v, v, 0.0])
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return np.array([0.0, 0.0, 1.0])
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        w = d2 / (d2 - d6)
        return np.array([1 - w, 0.0, w])
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return np.array([0.0, 1 - w, w])
    den = 1.0 / (va + vb + vc)
    v, w = vb * den, vc * den
    return np.array([1 - v - w, v, w])


def _one_head(character: Character, mesh: str | None) -> None:
    """Restrict the face to ``mesh`` (``--mesh``), or refuse two separate heads in one file."""
    names = [m.name for m in character.meshes]
    if mesh is not None:
        hits = [i for i, n in enumerate(names) if n == mesh] or [i for i, n in enumerate(names)
                                                                 if n.lower() == mesh.lower()]
        if not hits:
            raise MissingShapeError(f"{character.path}: --mesh '{mesh}': no such mesh (the character has "
                                    f"{', '.join(names)})")
        character.face_filter = [hits[0]]
        return
    face = character.face_meshes()
    if len(face) < 2:
        return
    from ..capture import face_region

    big = [i for i in face if character.meshes[i].n_shapes >= max(1, character.meshes[face[0]].n_shapes // 2)]
    regions = [face_region(character, i) for i in big]
    heads = [big[0]]
    for i, r in zip(big[1:], regions[1:], strict=True):
        c = r.mean(axis=0)
        if all(np.linalg.norm(c - face_region(character, h).mean(axis=0)) >
               1.5 * np.ptp(face_region(character, h), axis=0).max() for h in heads):
            heads.append(i)
    if len(heads) > 1:
        raise InvalidDataError(f"{character.path}: {len(heads)} separate heads with face shapes "
                               f"({', '.join(names[i] for i in heads)}); choose one with --mesh NAME")


def load_character(character, *, landmarks: str | os.PathLike | None = None, mesh: str | None = None,
                   find: bool = True, cache: bool = True, prefer: str | None = None, tracker=None,
                   need_shapes: bool = True, log: Callable[..., None] = _quiet) -> Character:
    """A character ready to drive (module docstring).

    Parameters
    ----------
    character : path-like, Character or Rig
        A character file or OBJ folder, or one already read.
    landmarks : path-like, optional
        ``--landmarks``: a landmark file that overrides the cache and the search.
    mesh : str, optional
        ``--mesh``: the face mesh, when the file holds several heads.
    find : bool
        Search the landmarks on a render when neither the file, ``landmarks`` nor the cache gives them.
    cache : bool
        Read and write the landmark cache and the read cache (module docstring).
    need_shapes : bool
        False: a character with a face but no face shapes is accepted (to generate them,
        :mod:`faceretarget.transfer`): its head mesh is chosen (``mesh``, else
        :meth:`~faceretarget.character.Character.head_mesh`), set as
        :attr:`~faceretarget.character.Character.neutral_head`, and its landmarks found on it.

    Returns
    -------
    Character
        With :attr:`~faceretarget.character.Character.landmarks` (when found) and ``timings``
        (``read``, ``landmarks`` seconds).

    Raises
    ------
    MissingShapeError
        No face shapes.
    FaceNotFoundError
        The landmarks are not found on the render (the message names ``--landmarks``).
    InvalidDataError
        Two heads and no ``mesh``.
    """
    from ..io import character_from_rig

    t0 = time.perf_counter()
    sha = None
    if isinstance(character, Character):
        ch = character
        path = ch.path
    elif isinstance(character, Rig):
        ch = character_from_rig(character)
        path = None
    else:
        path = Path(character)
        ch, sha = _read_character_cached(path, prefer, cache, log)
        log(f"read {path.name} ({ch.route}): {len(ch.meshes)} mesh(es), {len(ch.joints)} joint(s) in "
            f"{time.perf_counter() - t0:.1f} s")
    timings = {"read": time.perf_counter() - t0}
    if not ch.face_meshes():
        if need_shapes:
            raise MissingShapeError(ch.no_shapes_message())
        if mesh is not None:
            _one_head(ch, mesh)
        ch.neutral_head = ch.head_mesh()
        log(f"no face shapes: the head mesh is '{ch.meshes[ch.neutral_head].name}' "
            f"({ch.meshes[ch.neutral_head].mesh.n_vertices} vertices)")
    else:
        _one_head(ch, mesh)
    t0 = time.perf_counter()
    if landmarks is not None:
        ch.landmarks = read_landmark_file(ch, landmarks)
        log(f"landmarks: read from {landmarks}")
    elif ch.landmarks is None and path is not None:
        sha = sha or _sha256(path)
        if not (cache and _read_cache(ch, path, sha, log)) and find:
            _search(ch, tracker, log)
            if cache:
                _write_cache(ch, path, sha, log)
    elif ch.landmarks is None and find:
        _search(ch, tracker, log)
    if ch.search is None:                       # given, in the file or cached: a head held turned in its file
        face_turn(ch, log)                      # gets the face's own frame (the search turns it itself)
    timings["landmarks"] = time.perf_counter() - t0
    ch.timings = timings
    return ch


def _search(ch: Character, tracker, log) -> None:
    """The landmarks found on renders; a face the file holds turned (:func:`face_turn`) is looked at again,
    square to it (a head nodding in its file, by the landmarker's pitch, :func:`face_pitch_turn`): on a head turned 25 degrees the far side's points are foreshortened, and its generated
    left and right shapes came out 4.5 % from mirror images (0.0 % found square)."""
    from ..capture import face_pitch, find_landmarks

    log(f"landmarks: looking for the face on renders of '{ch.meshes[ch.primary].name}' (once: then cached)")
    res = find_landmarks(ch, tracker=tracker, log=log)
    ch.landmarks = res.landmarks
    ch.up, ch.front = res.up, res.front
    ch.search = res
    turned = face_turn(ch, log) is not None
    if res.pose is not None:
        turned = face_pitch_turn(ch, face_pitch(res.pose), log) is not None or turned
    if turned:
        log("landmarks: looking again, square to the face")
        res = find_landmarks(ch, tracker=tracker, log=log)
        ch.landmarks = res.landmarks
        ch.search = res
        face_turn(ch, log)


# ------------------------------------------------------------------------------------- driving
@dataclass(eq=False)
class DriveRig:
    """What drives a character: the solve rig, the channels and which of them drive.

    Attributes
    ----------
    rig : Rig
        The face meshes side by side plus the 68 landmark points (:func:`~faceretarget.character.face_rig`),
        one shape per driving channel, names exact.
    channels : list of Channel
        Every channel of the character.
    choice : ShapeChoice
    """

    rig: Rig
    channels: list
    choice: ShapeChoice
    character: Character = field(repr=False, default=None)

    @property
    def summary(self) -> str:
        return self.choice.summary(self.channels)

    def full_weights(self, W: np.ndarray) -> np.ndarray:
        """``(T, C)`` weights of every channel (0 for those at rest) from the driving ones ``(T, D)``."""
        out = np.zeros((len(W), len(self.channels)))
        out[:, self.choice.drive] = W
        return out


def drive_rig(character: Character, shapes: str = "auto", *, need_landmarks: bool = True) -> DriveRig:
    """Choose the shapes that drive (``--shapes``) and build the solve rig.

    With the landmarks, shapes that move none of them and near-duplicates stay at rest and the rig carries
    the 68 points as vertices; ``need_landmarks=False`` (a target rig of key-model sets) builds it without
    them when they are not known."""
    if character.landmarks is None and need_landmarks:
        raise InvalidDataError(f"{character.name}: the landmarks are not known yet (load_character finds them)")
    spec = (shapes or "auto").strip()
    who = str(character.path or character.name)
    chans, skipped = None, {}
    if spec in ("auto", "expressions") and character.format.startswith("vrm"):
        ex, why = expression_channels(character)
        if len(ex) >= 3 or spec == "expressions":        # a VRM is driven through its expressions, as VRM apps do
            if not ex:
                raise MissingShapeError(f"{who}: --shapes expressions: no VRM expression binds morph targets")
            chans, spec, skipped = ex, "all", {"_": ""} | why
    if chans is None:
        if spec == "expressions":
            raise MissingShapeError(f"{who}: --shapes expressions: not a VRM with expressions")
        chans = channels(character)
    motion = None if character.landmarks is None else character._landmark_deltas(chans)
    choice = choose_shapes(chans, spec, motion, who=who)
    if skipped:
        choice.basis = "VRM expressions"
        for name, why in skipped.items():
            if name != "_":
                choice.rest.setdefault(why, []).append(name)
    return DriveRig(face_rig(character, chans, choice.drive), chans, choice, character)


def character_weights(drive: DriveRig, weights: np.ndarray, names: list[str]) -> np.ndarray:
    """``(T, C)`` weights of every channel of the character from curves named by ``names`` (ARKit names or
    the character's own shape names: each matched by any spelling, as :meth:`Rig.map_weights` does)."""
    return drive.full_weights(drive.rig.map_weights(list(names), np.asarray(weights, dtype=np.float64),
                                                    source=drive.character.name, warn=False))


# ------------------------------------------------------------------------------------- preview
@dataclass(eq=False)
class CharacterLook:
    """The character as a preview shows it (:func:`character_look`).

    Attributes
    ----------
    rig : Rig
        Every mesh about the face, head frame (+Y up, +Z out of the face), metres; the face meshes move with
        the shapes (the driving channels in ``drive.rig``'s order, or those asked for).
    surface : Surface
        Each triangle's material (base colour, texture, alpha mode, sides), texture coordinates per corner,
        vertex colours: what :class:`~faceretarget.render.MeshRenderer` draws as a glTF viewer would.
    colors : (V, 3) float
        sRGB per vertex (the textures sampled at the vertices): a flat stand-in for the surface.
    pivot : (3,) float
        The head joint (or the face region's centre), head frame: the centre of the head's rotations.
    frame : (N, 3) float
        The points the preview's camera frames (the face with a margin about it); the meshes reach further,
        so that the edge where they were cut stays out of the picture.
    eyes : list of (role, indices, centre)
        The eyeballs: a mesh that follows an eye joint entirely, its vertices in :attr:`rig` and the joint's
        position (head frame), for :meth:`eye_turns`.
    """

    rig: Rig
    surface: object
    colors: np.ndarray
    pivot: np.ndarray
    frame: np.ndarray
    eyes: list = field(default_factory=list)

    def eye_turns(self, gaze: dict | None) -> list:
        """The eyeballs turning with ``gaze`` (``{"leftEye": Rotation, "rightEye": Rotation}``, head frame,
        relative to the head: what ``animate`` writes on the eye joints) as
        :class:`~faceretarget.pipelines.TakeSampler`'s ``turns``."""
        gaze = gaze or {}
        return [(idx, centre, gaze[role]) for role, idx, centre in self.eyes if role in gaze]


def character_look(drive: DriveRig, *, margin: float = 0.7, reach: float = 1.6,
                   channels: list[int] | None = None) -> CharacterLook:
    """The character as it looks around its face, for preview videos: every mesh cropped to a sphere about
    the face (``reach`` times the framed one: the face region's extent times ``1 + margin``), face meshes
    moving with the driving channels (or with ``channels``, indices into ``drive.channels``), the others still;
    materials and textures as the file gives them (:class:`CharacterLook`)."""
    from ..capture import face_region
    from ..character import Material, character_frame
    from ..mesh import Mesh
    from ..render import Surface

    ch = drive.character
    F = character_frame(ch)
    reg = face_region(ch)
    c = (reg.min(axis=0) + reg.max(axis=0)) / 2.0
    radius = 0.5 * float(np.ptp(reg, axis=0).max()) * (1.0 + margin)
    verts, counts, idx, cols, parts, framed = [], [], [], [], [], []
    mats, tmat, uvs, vcols, eyes = [], [], [], [], []
    eye_joint = {j.name: role for role in ("leftEye", "rightEye") if (j := ch.joint(role)) is not None}
    n = 0
    for mi, m in enumerate(ch.meshes):
        tri = m.mesh.triangles()
        if not len(tri):
            continue
        dist = np.linalg.norm(m.mesh.vertices - c, axis=1)
        keep_t = (dist < reach * radius)[tri].all(axis=1)
        if not keep_t.any():
            continue
        used = np.unique(tri[keep_t])
        remap = np.full(m.mesh.n_vertices, -1, np.int64)
        remap[used] = np.arange(len(used)) + n
        verts.append(m.mesh.vertices[used])
        framed.append(m.mesh.vertices[used][dist[used] < radius])
        counts.append(np.full(int(keep_t.sum()), 3))
        idx.append(remap[tri[keep_t]].reshape(-1))
        cols.append(_vertex_colors(m, used, tri, keep_t))
        own = m.materials or [Material("default")]
        tm = m.triangle_material if m.triangle_material is not None and m.materials else np.zeros(len(tri), np.int64)
        tmat.append(np.asarray(tm, np.int64)[keep_t] + len(mats))
        mats.extend(own)
        if m.mesh.uvs is not None:
            uvs.append(m.mesh.uvs[m.mesh.triangle_uv_indices()[keep_t]])
        else:
            uvs.append(np.zeros((int(keep_t.sum()), 3, 2)))
        vcols.append(m.vertex_colors[used] if m.vertex_colors is not None else np.ones((len(used), 4)))
        if m.joint in eye_joint:
            role = eye_joint[m.joint]
            eyes.append((role, np.arange(len(used)) + n, ch.joint(role).position @ F.T))
        parts.append((mi, used, n))
        n += len(used)
    if not parts:
        raise InvalidDataError(f"{ch.name}: nothing to show around the face")
    carried = list(drive.choice.drive) if channels is None else [int(c) for c in channels]
    names = list(drive.rig.names) if channels is None else [drive.channels[c].name for c in carried]
    D = np.zeros((len(carried), n, 3))
    for r, c_i in enumerate(carried):
        for mi, k, w in drive.channels[c_i].weighted():
            for pmi, used, off in parts:
                if pmi == mi:
                    D[r, off:off + len(used)] += w * ch.meshes[mi].deltas[k][used]
    V = np.concatenate(verts) @ F.T
    rig = Rig(Mesh(V, np.concatenate(counts), np.concatenate(idx), name=ch.name), names, D @ F.T,
              unit="m", name=ch.name, keep_names=True)
    any_colors = any(ch.meshes[mi].vertex_colors is not None for mi, _, _ in parts)
    surface = Surface(mats, np.concatenate(tmat), np.concatenate(uvs),
                      np.concatenate(vcols) if any_colors else None)
    head = ch.joint("head")
    pivot = (head.position if head is not None and np.linalg.norm(head.position - c) < 2 * radius else c) @ F.T
    frame = np.concatenate(framed) @ F.T
    return CharacterLook(rig, surface, np.clip(np.concatenate(cols), 0.0, 1.0), pivot, frame if len(frame) else V,
                         eyes)


def look_rig(drive: DriveRig, *, margin: float = 0.7,
             channels: list[int] | None = None) -> tuple[Rig, np.ndarray, np.ndarray]:
    """The character as it looks around its face, as a rig, vertex colours and a pivot: every mesh cropped
    to a sphere about the face (the face region's extent times ``1 + margin``), face meshes moving with the
    driving channels (or with ``channels``, indices into ``drive.channels``), the others still; colours from
    the textures (sampled at each vertex's UVs) or materials.  :func:`character_look` gives the textures,
    alpha modes and sides themselves, as the preview draws them.

    Returns
    -------
    rig : Rig
        Head frame (+Y up, +Z out of the face), metres; the driving channels' shapes in
        ``drive.rig``'s order (or those of ``channels``, named as the channels).
    colors : (V, 3) float
        sRGB 0..1 per vertex.
    pivot : (3,) float
        The head joint (or the face region's centre), head frame: the centre of the preview's head
        rotations.
    """
    look = character_look(drive, margin=margin, reach=1.0, channels=channels)
    return look.rig, look.colors, look.pivot


def _vertex_colors(m, used: np.ndarray, tri: np.ndarray, keep_t: np.ndarray) -> np.ndarray:
    """sRGB colour of each kept vertex: its material's texture at its UV, or the material's colour."""
    mats = m.materials or []
    tm = m.triangle_material
    out = np.full((m.mesh.n_vertices, 3), 0.8)
    tuv = m.mesh.triangle_uv_indices() if m.mesh.uvs is not None else None
    mat_of = tm if tm is not None and len(mats) else np.zeros(len(tri), np.int64)
    for k in np.unique(mat_of[keep_t]):
        sel = np.flatnonzero(keep_t & (mat_of == k))
        mat = mats[int(k)] if len(mats) else None
        base = np.array([0.8, 0.8, 0.8]) if mat is None else _to_srgb(np.asarray(mat.color, float)[:3])
        vs = tri[sel].reshape(-1)
        img = mat.image if mat is not None and tuv is not None else None
        if img is None:
            out[vs] = base
            continue
        uv = m.mesh.uvs[tuv[sel].reshape(-1)]
        h, w = img.shape[:2]
        px = img[np.mod((uv[:, 1] * h).astype(np.int64), h), np.mod((uv[:, 0] * w).astype(np.int64), w), :3]
        out[vs] = px / 255.0 * base
    return out[used]


def _to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


# ------------------------------------------------------------------------------------- inspect
@dataclass(eq=False)
class CharacterReport:
    """What ``character inspect`` found (:func:`inspect_character`)."""

    character: Character
    drive: DriveRig | None
    regions: dict
    lines: list
    picture: Path | None = None


def inspect_character(path, *, out: str | os.PathLike | None = None, shapes: str = "auto",
                      landmarks: str | os.PathLike | None = None, mesh: str | None = None,
                      log: Callable[..., None] = _quiet) -> CharacterReport:
    """Read a character, find its landmarks and report what will drive it; with ``out`` write a
    picture of the render with the 68 points (the face found, the check a user makes)."""
    try:
        ch = load_character(path, landmarks=landmarks, mesh=mesh, log=log)
    except FaceNotFoundError as e:
        if out is None or not getattr(e, "images", None):
            raise
        from ..render import render_grid, save_png

        labels = [f"from {np.round(v['front'], 2).tolist()}" for v in e.views]
        save_png(out, render_grid(e.images, labels))
        raise FaceNotFoundError(f"{e}; the {len(e.images)} renders tried are in {out}", views=e.views) from e
    lines = [ch.summary()]
    lines += [f"note: {n}" for n in ch.notes]
    if ch.landmarks is not None:
        lines.append(f"landmarks: 68 on '{ch.meshes[ch.landmarks.mesh].name}' ({ch.landmarks.source}); "
                     f"read {ch.timings['read']:.2f} s, landmarks {ch.timings['landmarks']:.2f} s")
    dr = drive_rig(ch, shapes) if ch.landmarks is not None else None
    regions: dict[str, list[str]] = {}
    if dr is not None:
        D = ch._landmark_deltas(dr.channels)
        for c, chn in enumerate(dr.channels):
            mag = {r: float(np.linalg.norm(D[c, list(ix)], axis=1).max()) for r, ix in REGIONS.items()}
            r = max(mag, key=mag.get)
            regions.setdefault(r if mag[r] > 0 else "no landmark", []).append(chn.name)
        for r, names in regions.items():
            lines.append(f"  {r}: {len(names)} shape(s): {', '.join(names[:8])}{' ...' if len(names) > 8 else ''}")
        lines.append(dr.summary)
    pic = None
    if out is not None:
        pic = _check_picture(ch, out)
        lines.append(f"wrote {pic}")
    for ln in lines:
        log(ln)
    return CharacterReport(ch, dr, regions, lines, pic)


def _check_picture(ch: Character, out) -> Path:
    from PIL import Image, ImageDraw

    from ..render import look_at, render_scene

    out = Path(out)
    res = getattr(ch, "search", None)
    if res is not None and res.image is not None:
        # the points where they were put on the surface, not where the landmarker saw them: a lid point it saw
        # in the eye's opening or a jaw point moved onto a mask's edge shows where it went
        img = res.image
        pts = res.camera.project(ch.landmark_positions())[:, :2] if res.camera is not None else res.points
    else:
        from ..capture import face_region
        from ..character import character_frame

        R = character_frame(ch)
        reg = face_region(ch)
        c = (reg.min(0) + reg.max(0)) / 2
        cam = look_at(c, R[2], R[1], 1.6 * float(np.ptp(reg, axis=0).max()), (512, 512))
        img = render_scene(ch.meshes, cam).image
        pts = cam.project(ch.landmark_positions())[:, :2] if ch.landmarks is not None else np.zeros((0, 2))
    im = Image.fromarray(img)
    d = ImageDraw.Draw(im)
    for k, (x, y) in enumerate(pts):
        col = (40, 220, 60) if k >= 17 else (240, 160, 30)
        d.ellipse([x - 2.5, y - 2.5, x + 2.5, y + 2.5], fill=col, outline=(0, 0, 0))
    with atomic_path(out) as tmp:
        im.save(tmp, format="PNG")
    return out

