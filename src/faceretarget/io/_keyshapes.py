"""Hand chosen keyshape frames to an artist and read the target keyshapes they model back.

:func:`write_keyshapes` writes the selected frames of a source take (see
:mod:`faceretarget.numerics`) into a folder:

* ``frame_00123.obj`` per frame: the marker / feature points as an OBJ point set (``v`` lines only,
  marker labels in comments) or, for a mesh take, the whole mesh;
* ``contact_sheet.png``: every exported frame seen from the front, labelled with its frame id (a
  scatter of the markers, or a shaded render of the mesh);
* ``keyshapes.txt``: one line per frame, ``file<TAB>frame<TAB>time_s<TAB>label``;
* ``key_weights.csv`` (frames of a weight take): each frame's weights (``file,<ARKit names>``, one
  row per ``frame_00123.obj``; the layout of :mod:`faceretarget.io._rig`), so keys read back know
  what they are as ARKit weights (:attr:`Rig.basis <faceretarget.rig.Rig.basis>`) and a clone or
  retarget onto them can be written as a Live Link Face CSV.  Copy it beside the target shapes
  with ``keyshapes.txt``.

The artist models the target character's counterpart of each frame and saves it under the same
name (``frame_00123.obj``) in a folder, with the target's neutral as ``neutral.obj``;
:func:`read_keyshapes` reads them back by frame id (or label) into a
:class:`~faceretarget.rig.Rig` whose key shapes are in the order asked for.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import InputFileError, InvalidDataError, MissingShapeError, OutputError, TopologyError
from ..files import atomic_dir
from ..formats import OBJ
from ..mesh import Mesh
from ..performance import Performance
from ..rig import Rig
from ..units import guess_unit
from ._obj import read_obj, read_obj_vertices, write_obj
from ._rig import KEY_WEIGHTS, read_key_weights, write_key_weights

__all__ = ["write_keyshapes", "read_keyshapes", "read_marker_labels", "is_keyshape_folder", "read_keys",
           "keyshape_filename", "MANIFEST", "MARKERS", "CONTACT_SHEET"]

MANIFEST = "keyshapes.txt"
MARKERS = "markers.txt"
CONTACT_SHEET = "contact_sheet.png"


def keyshape_filename(frame: int) -> str:
    """``frame_00123.obj``: the file name of the keyshape of frame ``frame``."""
    return f"frame_{int(frame):05d}.obj"


def _frames(frames, T: int) -> list[int]:
    out = []
    for f in np.asarray(frames).reshape(-1).tolist():
        if isinstance(f, bool) or int(f) != f:
            raise InvalidDataError(f"keyshape frames must be integer frame indices, got {f!r}")
        f = int(f)
        if not 0 <= f < T:
            raise InvalidDataError(f"keyshape frame {f} is outside the take's frames 0..{T - 1}")
        out.append(f)
    if not out:
        raise InvalidDataError("no keyshape frames to export")
    dup = sorted({f for f in out if out.count(f) > 1})
    if dup:
        raise InvalidDataError(f"keyshape frame(s) {', '.join(map(str, dup))} listed more than once")
    return out


def _scatter_sheet(points: np.ndarray, frames: list[int], labels: list[str], cell: int,
                   neutral: np.ndarray | None = None, unit: str | None = None) -> np.ndarray:
    """Front-view pictures of marker keyshapes ``(n, P, 3)`` as an artist reads them, tiled: the neutral's
    markers joined into a light face mesh (a Delaunay triangulation of their front view), and each key's
    displacement from the neutral as arrows magnified by one shared factor (so that the largest motion of any
    key spans 15 % of a tile; written on the sheet), coloured by length; each tile names its frame and its
    largest marker motion.  Without a neutral, the mean of the keys is the reference."""
    from PIL import Image, ImageDraw
    from scipy.spatial import Delaunay

    from ..render import fit_camera, render_grid

    ref3 = np.asarray(neutral, np.float64) if neutral is not None else points.mean(axis=0)
    cam = fit_camera(np.concatenate([points, ref3[None]]), (cell, cell), "front", margin=0.12)
    ref = cam.project(ref3)[:, :2]
    disp = points - ref3[None]                                   # (n, P, 3) in the take's unit
    proj = np.stack([cam.project(p)[:, :2] for p in points])                          # (n, P, 2) pixels
    moved = np.linalg.norm(proj - ref[None], axis=2)                                  # pixels, unmagnified
    biggest = float(moved.max()) if moved.size else 0.0
    gain = max(1.0, 0.15 * cell / biggest) if biggest > 0 else 1.0
    try:
        edges = {tuple(sorted((a, b))) for t in Delaunay(ref).simplices for a, b in ((t[0], t[1]), (t[1], t[2]),
                                                                                   (t[2], t[0]))}
        span = np.median([np.linalg.norm(ref[a] - ref[b]) for a, b in edges]) * 2.5
        edges = [e for e in edges if np.linalg.norm(ref[e[0]] - ref[e[1]]) <= span]   # no hull-spanning edges
    except Exception:  # noqa: BLE001 - fewer than 3 markers or all on a line: no face mesh, markers only
        edges = []
    r = max(2, cell // 100)
    from ..units import mm_per_unit

    try:
        to_mm = mm_per_unit(unit)
    except Exception:  # noqa: BLE001 - a take without a length unit: lengths as they are
        to_mm = None
    imgs, text = [], []
    for k, q in enumerate(proj):
        im = Image.new("RGB", (cell, cell), (250, 250, 250))
        d = ImageDraw.Draw(im)
        for a, b in edges:
            d.line([tuple(ref[a]), tuple(ref[b])], fill=(215, 215, 220), width=1)
        length = moved[k] / biggest if biggest > 0 else moved[k]
        for (x0, y0), (x1, y1), f in zip(ref, ref + gain * (q - ref), length, strict=True):
            d.ellipse([x0 - r, y0 - r, x0 + r, y0 + r], fill=(150, 150, 160))
            if f > 0.05:
                col = (int(40 + 200 * f), int(90 * (1 - f)), int(200 * (1 - f)))
                d.line([(x0, y0), (x1, y1)], fill=col, width=2)
                d.ellipse([x1 - r, y1 - r, x1 + r, y1 + r], fill=col)
        imgs.append(np.asarray(im))
        most = float(np.linalg.norm(disp[k], axis=1).max())
        size = f"{most * to_mm:.1f} mm" if to_mm is not None else f"{most:.3g} {unit or 'units'}"
        lab = labels[k]
        text.append(f"frame {frames[k]}" + (f" {lab}" if lab != f"frame {frames[k]}" else "") + f", up to {size}")
    sheet = render_grid(imgs, text, background=(255, 255, 255), text_color=(20, 20, 20))
    im = Image.fromarray(sheet)
    ImageDraw.Draw(im).text((4, sheet.shape[0] - 12), f"arrows: motion from the neutral x{gain:.0f}",
                            fill=(90, 90, 90))
    return np.asarray(im)


def _mesh_sheet(vertices: np.ndarray, mesh: Mesh, frames: list[int], labels: list[str], cell: int,
                step=lambda n=1: None) -> np.ndarray:
    from ..render import render_frames, render_grid

    imgs = []
    for img in render_frames(vertices, mesh, (cell, cell), "front"):
        imgs.append(img)
        step()
    text = [f"frame {f}" + (f" {lab}" if lab != f"frame {f}" else "") for f, lab in zip(frames, labels, strict=True)]
    return render_grid(imgs, text)


def write_keyshapes(perf_or_vertices: Performance | np.ndarray, frames: Sequence[int],
                     out_dir: str | os.PathLike, *, mesh: Mesh | None = None,
                     labels: Sequence[str] | None = None, contact_sheet: bool = True,
                     cell: int = 240, neutral: np.ndarray | None = None,
                     basis: np.ndarray | None = None, basis_names: Sequence[str] | None = None,
                     progress: bool = False) -> Path:
    """Write the chosen frames of a take for an artist to model (see the module); ``progress``: a progress
    bar over the files and the contact sheet's renders (40 keys of a 9,409-vertex rig: seconds).

    Parameters
    ----------
    perf_or_vertices : Performance or (T, P, 3) / (T, P, 2) array
        A point (marker, landmark) or mesh take, or its array.  2-D points get ``z = 0``.
    frames : sequence of int
        Frame indices (0-based, into the take), e.g. from
        :func:`~faceretarget.numerics.select_keyshapes`.
    out_dir : path-like
        Output folder; written whole or not at all (files of the same name in an existing folder
        are replaced, others are kept).  Its parent must exist.
    mesh : Mesh, optional
        Topology of a mesh take (defaults to the performance's ``mesh``).  Without one each frame
        is written as a point set.
    labels : sequence of str, optional
        A label per frame (e.g. ``"jaw open"``), written to ``keyshapes.txt`` and the contact
        sheet; ``read_keyshapes`` can then look frames up by label.
    contact_sheet : bool
        Write ``contact_sheet.png``.
    cell : int
        Size in pixels of each contact sheet cell.
    neutral : (P, 3) float, optional
        The source's rest pose (same points / vertices as the frames), written as ``neutral.obj``
        so the folder is a complete set of source keyshapes for retargeting.
    basis : (n, M) float, optional
        What each exported frame is as weights of ``basis_names`` (a weight take's rows at
        ``frames``), written to ``key_weights.csv``.
    basis_names : sequence of str, optional
        The ``M`` base shape (ARKit) names of ``basis``.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    InvalidDataError
        A weights-only take, bad frame indices, a frame with a missing (NaN) point, labels of the
        wrong count.
    OutputError
        The folder cannot be written.
    """
    data, times, unit, marker_labels, mesh, source = _take_arrays(perf_or_vertices, mesh)
    T, P, _ = data.shape
    fr = _frames(frames, T)
    labs = _keyshape_labels(labels, fr)
    if mesh is not None and mesh.n_vertices != P:
        raise TopologyError(f"{source}: frames have {P} points but the mesh has {mesh.n_vertices} vertices")
    pts = _keyshape_points(data, fr, marker_labels, source)
    if (basis is None) != (basis_names is None):
        raise InvalidDataError(f"{source}: give basis and basis_names together")
    if basis is not None:
        basis = np.asarray(basis, dtype=np.float64)
        if basis.shape != (len(fr), len(basis_names)) or not np.isfinite(basis).all():
            raise InvalidDataError(f"{source}: basis must be ({len(fr)}, {len(basis_names)}) finite weights, "
                                   f"got {basis.shape}")
    out = Path(out_dir)
    if basis is None and (out / KEY_WEIGHTS).is_file():
        raise OutputError(f"{out}: already holds a {KEY_WEIGHTS} of an earlier export that does not describe "
                          "these frames; export to an empty folder")
    from tqdm.auto import tqdm

    steps = len(fr) * (2 if contact_sheet and mesh is not None else 1)
    with atomic_dir(out) as tmp, tqdm(total=steps, desc=f"writing {out.name}", unit="file", disable=not progress,
                                      leave=False) as bar:
        _write_frames(tmp, pts, fr, labs, times, unit, mesh, marker_labels, source, bar.update)
        if basis is not None:
            write_key_weights(tmp / KEY_WEIGHTS, [keyshape_filename(f) for f in fr], basis, list(basis_names))
        if neutral is not None:
            _write_source_neutral(tmp, neutral, P, mesh, unit, source)
        if contact_sheet:
            _write_contact_sheet(tmp, pts, fr, labs, mesh, cell, bar.update, neutral, unit)
    return out


def _take_arrays(perf_or_vertices: Performance | np.ndarray, mesh: Mesh | None
                 ) -> tuple[np.ndarray, np.ndarray | None, str | None, list[str], Mesh | None, str]:
    """``(data, times, unit, marker_labels, mesh, source)`` of a take or an array of frames."""
    times = None
    unit = None
    marker_labels: list[str] = []
    if isinstance(perf_or_vertices, Performance):
        perf = perf_or_vertices
        if perf.kind == "weights":
            raise InvalidDataError(f"{perf.source}: a weights take has no geometry to export; drive a rig "
                                   "first (rig.evaluate) or export its landmark points")
        data = perf.data()
        times = perf.times
        unit = perf.unit
        marker_labels = list(perf.labels) if perf.kind == "points" else []
        if mesh is None and perf.kind == "vertices":
            mesh = perf.mesh
        source = perf.source
    else:
        data = np.asarray(perf_or_vertices, dtype=np.float64)
        source = "take"
    if data.ndim != 3 or data.shape[2] not in (2, 3):
        raise InvalidDataError(f"{source}: expected frames of points (T, P, 3) or (T, P, 2), "
                               f"got {data.shape}")
    return data, times, unit, marker_labels, mesh, source


def _keyshape_labels(labels: Sequence[str] | None, fr: list[int]) -> list[str]:
    """One checked label per frame (``frame 123`` when none are given)."""
    if labels is None:
        return [f"frame {f}" for f in fr]
    labs = [str(s) for s in labels]
    if len(labs) != len(fr):
        raise InvalidDataError(f"{len(labs)} labels for {len(fr)} keyshape frames")
    for s in labs:
        if not s.strip() or any(c in s for c in "\t\n\r"):
            raise InvalidDataError(f"keyshape label {s!r} must be non-empty without tabs or line breaks")
    return labs


def _keyshape_points(data: np.ndarray, fr: list[int], marker_labels: list[str], source: str) -> np.ndarray:
    """The chosen frames as (n, P, 3) points (``z = 0`` for 2-D ones), with no missing point."""
    P = data.shape[1]
    pts = np.zeros((len(fr), P, 3))
    pts[:, :, : data.shape[2]] = data[fr]
    bad = ~np.isfinite(pts).all(axis=2)
    if bad.any():
        i, j = (int(x[0]) for x in np.nonzero(bad))
        who = f"'{marker_labels[j]}'" if marker_labels else str(j)
        raise InvalidDataError(f"{source}: frame {fr[i]} has a missing point {who}; choose another frame "
                               "or fill the gap first")
    return pts


def _write_frames(tmp: Path, pts: np.ndarray, fr: list[int], labs: list[str], times: np.ndarray | None,
                  unit: str | None, mesh: Mesh | None, marker_labels: list[str], source: str,
                  step=lambda n=1: None) -> None:
    """Write one OBJ per frame into ``tmp``, the manifest and (for markers) their labels."""
    lines = ["# file\tframe\ttime_s\tlabel"]
    for n, f in enumerate(fr):
        name = keyshape_filename(f)
        t = "" if times is None else f"{float(times[f]):.6f}"
        head = [f"faceretarget keyshape: frame {f} of {Path(source).name}" + (f", t = {t} s" if t else ""),
                f"label: {labs[n]}"] + ([f"unit: {unit}"] if unit else [])
        if mesh is None:
            head.append("point set (no faces): one vertex per point, in the take's order")
            head += [f"point {j}: {lab}" for j, lab in enumerate(marker_labels)]
            write_obj(tmp / name, Mesh(pts[n], name=name), header="\n".join(head))
        else:
            write_obj(tmp / name, mesh, pts[n], header="\n".join(head))
        lines.append(f"{name}\t{f}\t{t}\t{labs[n]}")
        step()
    (tmp / MANIFEST).write_text("\n".join(lines) + "\n", encoding="utf-8")
    if marker_labels:
        (tmp / MARKERS).write_text("\n".join(marker_labels) + "\n", encoding="utf-8")


def _write_source_neutral(tmp: Path, neutral: np.ndarray, P: int, mesh: Mesh | None, unit: str | None,
                          source: str) -> None:
    """Write the source's rest pose as ``tmp/neutral.obj`` (a point set without ``mesh``)."""
    nv = np.zeros((P, 3))
    n_arr = np.asarray(neutral, dtype=np.float64)
    if n_arr.shape[0] != P or n_arr.shape[1] not in (2, 3) or not np.isfinite(n_arr).all():
        raise InvalidDataError(f"{source}: the neutral must be {P} finite points, got {n_arr.shape}")
    nv[:, : n_arr.shape[1]] = n_arr
    head = [f"faceretarget source neutral of {Path(source).name}"] + ([f"unit: {unit}"] if unit else [])
    write_obj(tmp / "neutral.obj", Mesh(nv, name="neutral") if mesh is None else mesh,
              None if mesh is None else nv, header="\n".join(head))


def _write_contact_sheet(tmp: Path, pts: np.ndarray, fr: list[int], labs: list[str], mesh: Mesh | None,
                         cell: int, step=lambda n=1: None, neutral: np.ndarray | None = None,
                         unit: str | None = None) -> None:
    """Write ``tmp/contact_sheet.png``: the markers' motion pictures or the mesh renders (``step`` after each)."""
    from ..render import save_png

    sheet = (_scatter_sheet(pts, fr, labs, cell, neutral, unit) if mesh is None
             else _mesh_sheet(pts, mesh, fr, labs, cell, step))
    save_png(tmp / CONTACT_SHEET, sheet)


def _manifest(folder: Path) -> list[tuple[str, int, str]]:
    """``(file, frame, label)`` rows of a folder's ``keyshapes.txt`` (empty when there is none)."""
    path = folder / MANIFEST
    if not path.is_file():
        return []
    rows = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split("\t")
        try:
            rows.append((parts[0], int(parts[1]), parts[3] if len(parts) > 3 else f"frame {parts[1]}"))
        except (IndexError, ValueError):
            raise InputFileError(f"{path}:{n}: expected 'file<TAB>frame<TAB>time<TAB>label', got {line!r}") from None
    return rows


def _frame_of(item, folder: Path, rows: list[tuple[str, int, str]]) -> int:
    if isinstance(item, str):
        for _, f, lab in rows:
            if lab == item:
                return f
        s = item.strip()
        if s.endswith(OBJ):
            s = s[:-4]
        if s.startswith("frame_"):
            s = s[6:]
        if s.isdigit():
            return int(s)
        known = ", ".join(repr(lab) for _, _, lab in rows) or "none: there is no keyshapes.txt"
        raise MissingShapeError(f"{folder}: no keyshape labelled {item!r} (labels: {known})")
    if isinstance(item, bool) or int(item) != item:
        raise InvalidDataError(f"keyshape frames must be frame ids or labels, got {item!r}")
    return int(item)


def read_keyshapes(folder: str | os.PathLike, frames: Sequence[int | str] | None = None, *,
                          neutral: Mesh | str | os.PathLike | None = None, unit: str | None = None,
                          name: str | None = None) -> Rig:
    """Read the artist's target keyshapes (``frame_00123.obj`` ...) back, by frame id or label.

    Parameters
    ----------
    folder : path-like
        Folder holding the target keyshapes, one OBJ per frame named as :func:`write_keyshapes`
        named them, and by default the target's neutral ``neutral.obj``.
    frames : sequence of int or str, optional
        Which keyshapes, in which order: frame ids (``123``), file names or stems
        (``"frame_00123"``) or labels from ``keyshapes.txt``.  By default the frames listed in
        ``keyshapes.txt`` (copy it beside the target shapes), else every ``frame_*.obj``.
    neutral : Mesh or path-like, optional
        The target's neutral; default ``folder/neutral.obj``.
    unit : str, optional
        The target's unit (guessed from the neutral's size when omitted).
    name : str, optional
        The rig's name (default: the folder's name).

    Returns
    -------
    Rig
        The neutral and one key shape per frame, named by its label (``keyshapes.txt``) or
        ``frame_00123``; ``source_names`` holds the file stems; ``basis`` from ``key_weights.csv``
        when the folder has one with a row per frame.

    Raises
    ------
    MissingShapeError
        A frame's file (naming the frame id and the file expected) or the neutral is missing, or
        a label is unknown.
    TopologyError
        A keyshape's vertex count differs from the neutral's.
    InputFileError
        Unreadable files.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputFileError(f"{folder}: target keyshape folder not found")
    rows = _manifest(folder)
    ids = _keyshape_ids(folder, frames, rows)
    base = _target_neutral(folder, neutral)
    label_of = {f: lab for _, f, lab in rows}
    deltas = _keyshape_deltas(folder, ids, base)
    stems = [Path(keyshape_filename(f)).stem for f in ids]
    labels = [label_of.get(f, stems[n]) for n, f in enumerate(ids)]
    labels = [stems[n] if lab == f"frame {f}" else lab
              for n, (f, lab) in enumerate(zip(ids, labels, strict=True))]
    basis, basis_names = read_key_weights(folder, [keyshape_filename(f) for f in ids], str(folder))
    return Rig(base, labels, deltas, unit or guess_unit(base), None, stems, name or folder.name, basis,
               basis_names)


def _keyshape_ids(folder: Path, frames: Sequence[int | str] | str | None,
                  rows: list[tuple[str, int, str]]) -> list[int]:
    """The frame ids asked for (by default those of the manifest, else of every ``frame_*.obj``)."""
    if frames is None:
        if rows:
            ids = [f for _, f, _ in rows]
        else:
            ids = sorted(int(p.stem[6:]) for p in folder.glob("frame_*.obj") if p.stem[6:].isdigit())
            if not ids:
                raise MissingShapeError(f"{folder}: no target keyshapes (frame_00123.obj files) found")
    else:
        ids = [_frame_of(item, folder, rows)
               for item in (frames if not isinstance(frames, str) else [frames])]
    dup = sorted({f for f in ids if ids.count(f) > 1})
    if dup:
        raise InvalidDataError(f"keyshape frame(s) {', '.join(map(str, dup))} asked for more than once")
    return ids


def _target_neutral(folder: Path, neutral: Mesh | str | os.PathLike | None) -> Mesh:
    """The target's neutral: ``neutral`` itself, the OBJ it names, or ``folder/neutral.obj``."""
    if isinstance(neutral, Mesh):
        return neutral
    npath = folder / "neutral.obj" if neutral is None else Path(neutral)
    if not npath.is_file():
        raise MissingShapeError(f"{folder}: no target neutral '{npath.name}'; pass neutral= or save the "
                                "target's rest face as neutral.obj in the folder")
    return read_obj(npath)


def _keyshape_deltas(folder: Path, ids: list[int], base: Mesh) -> np.ndarray:
    """(K, V, 3) each frame's target keyshape minus the neutral (every file checked to exist first)."""
    missing = [f for f in ids if not (folder / keyshape_filename(f)).is_file()]
    if missing:
        which = ", ".join(f"frame {f} ({keyshape_filename(f)})" for f in missing)
        raise MissingShapeError(f"{folder}: missing target keyshape for {which}")
    deltas = np.empty((len(ids), base.n_vertices, 3))
    for n, f in enumerate(ids):
        path = folder / keyshape_filename(f)
        v = read_obj_vertices(path)
        if v.shape != base.vertices.shape:
            raise TopologyError(f"{path}: the keyshape of frame {f} has {len(v)} vertices, "
                                f"the target neutral has {base.n_vertices}")
        deltas[n] = v - base.vertices
    return deltas


def read_marker_labels(folder: str | os.PathLike) -> list[str]:
    """Marker labels of exported point keyshapes (``markers.txt``), empty when there are none."""
    p = Path(folder) / MARKERS
    if not p.is_file():
        return []
    return [ln.strip() for ln in p.read_text(encoding="utf-8").splitlines() if ln.strip()]


def is_keyshape_folder(folder: str | os.PathLike) -> bool:
    """Whether a folder holds exported keyshapes (``keyshapes.txt`` or ``frame_*.obj``) rather than a rig."""
    f = Path(folder)
    return (f / MANIFEST).is_file() or any(f.glob("frame_*.obj"))


def read_keys(folder: str | os.PathLike, *, neutral: str | os.PathLike | None = None,
              landmarks: str | os.PathLike | None = None, rig: Rig | None = None) -> tuple[Rig, list[str]]:
    """Keyshapes from an exported or artist's folder (``frame_*.obj`` beside ``neutral.obj``) or from
    an ARKit-style rig folder, and the marker labels of the source points (empty for rigs).

    Parameters
    ----------
    folder : path-like
    neutral : path-like, optional
        The folder's neutral OBJ when it is not named ``neutral*``.
    landmarks : path-like, optional
        A landmark index file for mesh keyshapes.
    rig : Rig, optional
        The rig the keyshapes were exported from: its landmarks are used when the topology matches.
    """
    from ._rig import read_rig

    if Path(folder).is_dir() and is_keyshape_folder(folder):
        keys = read_keyshapes(folder, neutral=neutral)
        if landmarks is not None:
            keys.landmarks = np.loadtxt(landmarks, dtype=np.int64, ndmin=1)
        elif rig is not None and rig.n_vertices == keys.n_vertices:
            keys.landmarks = rig.landmarks
        return keys, read_marker_labels(folder)
    return read_rig(folder, neutral=neutral, landmarks=landmarks), []
