"""Child process of tests/test_blender_isolation.py and tests/test_blender_extension.py: run in an environment
whose HOME holds a user's Blender configuration with extensions installed (their wheels in
``~/.config/blender/4.5/extensions/.local/lib/python3.11/site-packages``), it drives the library's Blender
routes (a ``.blend`` and an ``.fbx`` written, both read back as characters through Blender) and then the
imports the test suite makes, and prints one JSON line: what it measured, for the test to check.

    python _bpy_isolation_child.py OUT_DIR [CHARACTER.fbx]
"""

from __future__ import annotations

import importlib
import json
import os
import sys
from pathlib import Path

#: Modules the suite imports after bpy has been imported in the same process (the ones issue 31 saw fail).
SUITE_IMPORTS = ["PIL.ImageDraw", "PIL.ImageFont", "spafe.features.rplp", "scipy.signal", "scipy.sparse.linalg",
                 "numpy.linalg", "pygltflib", "av", "mediapipe"]


def main(out: Path, fbx: Path | None) -> dict:
    import numpy as np

    before = list(sys.path)
    from faceretarget.datasets import make_demo_character
    from faceretarget.io import import_bpy, read_character, write_blend, write_fbx

    import_bpy()
    rig = make_demo_character("ada")
    t = np.arange(6) / 30.0
    w = np.zeros((6, rig.n_shapes))
    w[:, rig.names.index("jawOpen")] = np.linspace(0.0, 1.0, 6)
    rep: dict = {"written": [], "read": {}}
    for p, write in ((out / "take.blend", write_blend), (out / "take.fbx", write_fbx)):
        write(p, rig, w, t)
        rep["written"].append(p.name)
    for p in [out / "take.blend"] + ([fbx] if fbx else []):
        ch = read_character(p, prefer="blender")
        rep["read"][p.name] = {"meshes": len(ch.meshes), "shapes": sum(m.n_shapes for m in ch.meshes)}
    config = os.path.realpath(os.path.expanduser("~/.config/blender"))     # the user's Blender configuration
    site = Path(config, "4.5/extensions/.local/lib/python3.11/site-packages")
    rep["user_extension_site"] = sorted(p.name for p in site.iterdir()) if site.is_dir() else []
    rep["added_paths"] = [p for p in sys.path if p not in before]
    rep["paths_in_config"] = [p for p in sys.path if os.path.realpath(p).startswith(config + os.sep)]
    rep["imports"] = {}
    for name in SUITE_IMPORTS:
        try:
            m = importlib.import_module(name)
            rep["imports"][name] = os.path.realpath(getattr(m, "__file__", "") or "")
        except Exception as e:                     # noqa: BLE001 - the failure is what the test reports
            rep["imports"][name] = f"FAILED {type(e).__name__}: {e}"
    rep["modules_from_config"] = sorted(
        n for n, m in list(sys.modules.items())
        if getattr(m, "__file__", None) and os.path.realpath(m.__file__).startswith(config + os.sep))
    rep["blender_user_env"] = {k: v for k, v in os.environ.items() if k.startswith("BLENDER_USER")}
    return rep


if __name__ == "__main__":
    res = main(Path(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) > 2 else None)
    print(json.dumps(res))
