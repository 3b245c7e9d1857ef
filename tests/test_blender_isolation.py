"""Issue 31: a user who installed a Blender extension (ours bundles Pillow, SciPy, OpenCV built for Blender's
NumPy 1.26) must not get its wheels when the library imports ``bpy``: Blender puts the user's extension
site-packages *before* the environment's on ``sys.path``.  The library's Blender routes run here in a child
process whose HOME holds such a configuration, with packages that shadow the environment's (a ``PIL`` without
``ImageDraw``, a ``spafe`` without ``features``); tests/test_blender_extension.py runs the same child with the
real extension installed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from faceretarget.optional import has_module

CHILD = Path(__file__).with_name("_bpy_isolation_child.py")
SITE = Path(".config/blender/4.5/extensions/.local/lib/python3.11/site-packages")

pytestmark = pytest.mark.skipif(not has_module("bpy"), reason="Blender's Python module is not installed: make blender")


def child_job(home: Path, out: Path, cache: Path, fbx: Path | None = None) -> dict:
    """The child's command and environment: ``home`` as HOME, nothing of the suite's own Blender settings."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("BLENDER_", "XDG_", "PYTHON"))}
    env.update(HOME=str(home), FACERETARGET_CACHE=str(cache), PYTHONNOUSERSITE="1")
    out.mkdir(parents=True, exist_ok=True)
    return {"cmd": [sys.executable, str(CHILD), str(out)] + ([str(fbx)] if fbx else []), "env": env}


def child_report(returncode: int, stdout: str, stderr: str) -> dict:
    assert returncode == 0, stderr[-3000:]
    return json.loads(stdout.strip().splitlines()[-1])


def run_child(home: Path, out: Path, cache: Path, fbx: Path | None = None) -> dict:
    """The child script's report (module docstring)."""
    job = child_job(home, out, cache, fbx)
    res = subprocess.run(job["cmd"], env=job["env"], capture_output=True, text=True, timeout=600)
    return child_report(res.returncode, res.stdout, res.stderr)


def check_isolated(rep: dict) -> None:
    """What a user with extensions installed must see: the routes work, nothing of theirs is imported."""
    assert rep["written"] == ["take.blend", "take.fbx"]
    assert rep["read"]["take.blend"]["shapes"] >= 50          # the demo character's ARKit shapes came back
    failed = {k: v for k, v in rep["imports"].items() if v.startswith("FAILED") and k not in ("av", "mediapipe")}
    assert not failed, failed
    assert rep["paths_in_config"] == [] and rep["modules_from_config"] == [], rep
    assert not any("extensions" in p for p in rep["added_paths"]), rep["added_paths"]
    assert all(v.startswith(str(rep["blender_user_env"]["BLENDER_USER_RESOURCES"]).rsplit("/", 1)[0])
               for v in rep["blender_user_env"].values())


def test_user_extension_wheels_do_not_shadow_the_environment(tmp_path):
    home = tmp_path / "home"
    site = home / SITE
    (site / "PIL").mkdir(parents=True)
    (site / "PIL" / "__init__.py").write_text("SHADOW = True\n")        # a Pillow without ImageDraw
    (site / "spafe").mkdir()
    (site / "spafe" / "__init__.py").write_text("SHADOW = True\n")      # a spafe without features
    addons = home / ".config/blender/4.5/scripts/addons"
    addons.mkdir(parents=True)
    (addons / "PIL.py").write_text("raise ImportError('a user add-on was imported')\n")
    config = home / ".config" / "blender"
    before = sorted(p.relative_to(home).as_posix() for p in config.rglob("*"))
    rep = run_child(home, tmp_path / "out", tmp_path / "cache")
    check_isolated(rep)
    for name in ("PIL.ImageDraw", "spafe.features.rplp"):               # the environment's own packages
        assert str(site) not in rep["imports"][name] and "site-packages" in rep["imports"][name]
    # the user's Blender configuration is left as it was (Blender's user folders are the cache's; importing bpy
    # with the user's own once deleted the wheels of their installed extension)
    assert sorted(p.relative_to(home).as_posix() for p in config.rglob("*")) == before
    assert (tmp_path / "cache" / "blender-user").is_dir()


def test_import_bpy_restores_the_environment_when_bpy_is_missing(monkeypatch):
    """Without bpy the BLENDER_USER_* variables the user had are left as they were."""
    from faceretarget.errors import MissingDependencyError
    from faceretarget.io import _blender

    monkeypatch.delitem(sys.modules, "bpy", raising=False)     # as before a first import (put back afterwards)
    monkeypatch.setenv("BLENDER_USER_CONFIG", "/somewhere/of/theirs")
    monkeypatch.delenv("BLENDER_USER_SCRIPTS", raising=False)
    monkeypatch.setattr(_blender, "optional_import",
                        lambda *a, **k: (_ for _ in ()).throw(MissingDependencyError("no bpy here")))
    with pytest.raises(MissingDependencyError):
        _blender.import_bpy()
    assert os.environ["BLENDER_USER_CONFIG"] == "/somewhere/of/theirs" and "BLENDER_USER_SCRIPTS" not in os.environ
