"""Command line: ``faceretarget character inspect FILE [--out check.png] [--sheet shapes.png]``.

What the character reader and the landmark search make of a character file (:func:`faceretarget.pipelines.
inspect_character`): the route and meshes, the face meshes and joints found, the shapes grouped by the face
region they move, which of them will drive the face, and a picture of the render with the 68 landmarks.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..errors import FaceNotFoundError, OutputError
from ._support import check_inputs, warnings_to_log

__all__ = ["register", "cmd_inspect"]


def cmd_inspect(args, log) -> int:
    from ..io import check_character_route
    from ..pipelines import inspect_character

    check_inputs(("FILE", args.file), ("--landmarks", args.landmarks), folders=("FILE",))
    if args.out is not None:
        out = Path(args.out)
        if out.suffix.lower() != ".png":
            raise OutputError(f"{out}: the check picture is a .png")
        if out.resolve() == Path(args.file).resolve():
            raise OutputError(f"{out}: is the character file")
        from ..files import check_output_path

        check_output_path(out)
    sheet = getattr(args, "sheet", None)
    if sheet is not None:
        if Path(sheet).suffix.lower() not in (".png", ".jpg", ".jpeg"):
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
            from ..pipelines import load_character, shape_sheet

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
    return c
