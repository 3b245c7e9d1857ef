"""Command line: ``faceretarget character inspect FILE [--out check.png] [--sheet shapes.png]`` and
``faceretarget character shapes CHAR --out OUT``.

What the character reader and the landmark search make of a character file (:func:`faceretarget.pipelines.
inspect_character`): the route and meshes, the face meshes and joints found, the shapes grouped by the face
region they move, which of them will drive the face, and a picture of the render with the 68 landmarks.

``character shapes`` generates the ARKit expression shapes of a character that has only a neutral face
(:func:`faceretarget.characters.generate_shapes`) and writes them: an OUT without a suffix (or an existing
folder) is an OBJ rig folder of the head mesh (``neutral.obj``, one OBJ per shape, ``landmarks68.txt``);
any other OUT is the character's own format with the new morph targets (``faceretarget.io.write_character_shapes``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..errors import FaceNotFoundError, InvalidDataError, OutputError
from ..formats import PNG
from ._support import check_inputs, warnings_to_log

__all__ = ["register", "cmd_inspect", "cmd_shapes", "write_shapes_obj"]


def cmd_inspect(args, log) -> int:
    from ..characters import inspect_character
    from ..io import check_character_route

    check_inputs(("FILE", args.file), ("--landmarks", args.landmarks), folders=("FILE",))
    if args.out is not None:
        out = Path(args.out)
        if out.suffix.lower() != PNG:
            raise OutputError(f"{out}: the check picture is a .png")
        if out.resolve() == Path(args.file).resolve():
            raise OutputError(f"{out}: is the character file")
        from ..files import check_output_path

        check_output_path(out)
    sheet = getattr(args, "sheet", None)
    if sheet is not None:
        if Path(sheet).suffix.lower() not in (PNG, ".jpg", ".jpeg"):
            raise OutputError(f"{sheet}: the contact sheet is a .png or .jpg")
        from ..files import check_output_path

        check_output_path(sheet)
    check_character_route(args.file)
    with warnings_to_log(log):
        try:
            rep = inspect_character(args.file, out=args.out, shapes=args.shapes, landmarks=args.landmarks,
                                    mesh=args.mesh, log=log)
        except FaceNotFoundError:
            if sheet is None:
                raise
            from ..characters import load_character
            from ..pipelines import shape_sheet

            log("no landmarks: the contact sheet frames the face mesh's moving vertices instead")
            shape_sheet(load_character(args.file, mesh=args.mesh, find=False), sheet, shapes=args.shapes, log=log)
            raise
        if sheet is not None:
            from ..pipelines import shape_sheet

            shape_sheet(rep.character, sheet, shapes=args.shapes, log=log)
    if args.json:
        ch = rep.character
        print(json.dumps({
            "file": str(args.file), "format": ch.format, "route": ch.route,
            "meshes": [{"name": m.name, "vertices": m.mesh.n_vertices, "shapes": m.n_shapes} for m in ch.meshes],
            "face_meshes": [ch.meshes[i].name for i in ch.face_meshes()],
            "joints": {r: ch.joints[i].name for r, i in ch.roles.items()},
            "landmarks": None if ch.landmarks is None else ch.landmarks.source,
            "regions": rep.regions,
            "drive": None if rep.drive is None else [rep.drive.channels[i].name for i in rep.drive.choice.drive],
            "notes": ch.notes}))
    return 0


def write_shapes_obj(out, gen) -> Path:
    """Write generated shapes as an OBJ rig folder of the head mesh: ``neutral.obj`` (metres), one
    ``<shape>.obj`` per generated shape (and per ARKit shape the character kept), ``landmarks68.txt`` (the
    vertex nearest each landmark)."""
    import numpy as np

    from ..io import write_rig
    from ..names import ARKIT_NAMES, normalize_name
    from ..rig import Rig

    ch = gen.character
    mi = ch.landmarks.mesh
    m = ch.meshes[mi]
    shapes = dict(gen.added.get(m.name, {}))
    for k, n in enumerate(m.shape_names):                 # the character's own ARKit shapes it kept
        a = normalize_name(n)
        if a in ARKIT_NAMES and a not in shapes:
            shapes[a] = m.deltas[k]
    if not shapes:
        raise OutputError(f"{out}: no shape was generated on '{m.name}'")
    names = [a for a in ARKIT_NAMES if a in shapes]
    lm = ch.landmarks
    idx = lm.triangles[np.arange(len(lm)), lm.bary.argmax(axis=1)]
    rig = Rig(m.mesh, names, np.stack([shapes[a] for a in names]).astype(np.float64), unit="m", landmarks=idx,
              source_names=names, name=ch.name, keep_names=True)
    return write_rig(rig, out)


def cmd_shapes(args, log) -> int:
    from ..characters import generate_shapes
    from ..errors import InputFileError
    from ..files import check_output_path

    check_inputs(("CHAR", args.file), ("--landmarks", args.landmarks), folders=("CHAR",))
    out = Path(args.out)
    if out.resolve() == Path(args.file).resolve():
        raise OutputError(f"{out}: is the character itself; write the shapes to a new file or folder")
    obj = out.suffix == "" or out.is_dir()
    writer = None
    if not obj:
        try:
            from ..io import write_character_shapes as writer
        except ImportError:
            import sys

            print(f"faceretarget: error: character shapes: {out}: writing shapes into a {out.suffix} character is "
                  "not available in this version (faceretarget.io.write_character_shapes); give a folder (no "
                  "suffix) for OBJ output", file=sys.stderr)
            return 2
    check_output_path(out)
    if args.template not in ("ict-face", "arkit-face") and not Path(args.template).exists():
        raise InputFileError(f"--template {args.template}: not ict-face, arkit-face nor an existing rig folder or "
                             "character file")
    with warnings_to_log(log):
        gen = generate_shapes(args.file, template=args.template, shapes=args.shapes, replace=args.replace,
                              mesh=args.mesh, landmarks=args.landmarks, progress=log)
        if not gen.added:
            raise InvalidDataError(f"{args.file}: has all {len(gen.skipped)} of the shapes asked ({args.shapes}) "
                                   "and keeps its own: nothing to generate, nothing written (--replace generates "
                                   "them over its own)")
        for n in gen.notes:
            log(f"note: {n}")
        if obj:
            write_shapes_obj(out, gen)
        else:
            writer(out, gen.character, gen.added, replace=args.replace, log=log)
    log(f"wrote {len(gen.shape_names)} generated shape(s) to {out} in {gen.timings['total']:.1f} s")
    return 0


def register(subparsers) -> argparse.ArgumentParser:
    """Add ``character`` (``inspect``) to ``subparsers``."""
    c = subparsers.add_parser("character", help="a character file as faceretarget sees it",
                              description="Read a character file (.glb, .gltf, .vrm, .fbx, .blend, .usd*, or a rig "
                              "folder), find its landmarks, and show what will drive its face.")
    sub = c.add_subparsers(dest="character_command", required=True)
    i = sub.add_parser("inspect", help="meshes, joints, shapes by face region, the landmarks on a render",
                       description="Show the face meshes, head and eye joints, the shapes grouped by the face region "
                       "they move and which will drive, and (--out) a picture of the render with the 68 landmarks.")
    i.add_argument("file", metavar="FILE", help="the character file or rig folder")
    i.add_argument("--out", help="check picture (.png): the render the landmarks were found on, with the 68 points")
    i.add_argument("--shapes", default="auto", help="which shapes drive: auto, arkit, visemes, all or names")
    i.add_argument("--landmarks", help="a landmark file to use instead of the automatic search")
    i.add_argument("--mesh", help="the face mesh when the file holds several heads")
    i.add_argument("--sheet", metavar="OUT", help="contact sheet (.png or .jpg): the neutral and every shape "
                   "chosen by --shapes (auto means all) rendered at weight 1, front view of the face")
    i.add_argument("--json", action="store_true", help="also print what was found as one JSON line")
    i.set_defaults(func=cmd_inspect)
    g = sub.add_parser("shapes", help="generate the ARKit expression shapes of a character with a neutral face",
                       description="Generate a character's expression shapes (the ARKit set) from a template's by "
                       "non-rigid registration and deformation transfer, and write them: OUT without a suffix is an "
                       "OBJ rig folder of the head mesh; OUT.glb/.vrm/.gltf/.blend/.fbx/.usd* the character with the "
                       "new morph targets.")
    g.add_argument("file", metavar="CHAR", help="the character file or rig folder")
    g.add_argument("--template", default="ict-face",
                   help="ict-face (packaged, default), arkit-face, or a rig folder / character file with ARKit shapes")
    g.add_argument("--shapes", default="arkit", help="arkit (every ARKit shape the template has) or ARKit names, "
                   "comma-separated")
    g.add_argument("--replace", action="store_true", help="also generate the shapes the character already has")
    g.add_argument("--landmarks", help="a landmark file to use instead of the automatic search")
    g.add_argument("--mesh", help="the head mesh when the file holds several")
    g.add_argument("--out", required=True, help="OBJ folder, or a character file of the input's format")
    g.set_defaults(func=cmd_shapes)
    return c
