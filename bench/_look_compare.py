"""The preview against a glTF viewer (issue 34): one frame of a character file with its animation written
back, drawn by faceretarget's preview renderer and by three.js (``tests/browser/render_three.mjs``:
GLTFLoader, WebGL on SwiftShader in headless Chromium) with the same orthographic camera and the same
lights, compared by the mean colour difference (CIE 1976 Delta E, in L*a*b*, D65) over the face and,
separately, over the eyes, the lips and the hair.

three.js draws every material as a ``MeshLambertMaterial`` keeping its colour, texture, vertex colours,
alpha mode and sides, lit as the preview is: an ambient light and the preview's key and fill lights
(intensities times pi: three.js's Lambert divides by pi), and the preview's highlight added in its shader.
What differs is then the renderers': normals (three.js takes the file's, the preview computes them from
the moving vertices), texture filtering, the sides of a double-sided surface's silhouette.  The regions come from the character's 68 landmarks at that frame (face: inside the jaw
line and the brows; eyes: inside the lids; lips: between the outer and inner lip lines) and, for the hair,
from the meshes named hair or wig seen at rest.

Used by ``bench/preview_look.py`` (the numbers and pictures of the report) and
``tests/test_preview_look.py`` (the bound).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "tests" / "browser" / "render_three.mjs"
NODE_MODULES = REPO / ".tools" / "node_modules"
#: Depth of the three.js camera in front of the framed centre, metres (near 0, far twice that).
DEPTH = 5.0
HAIR = re.compile(r"hair|wig", re.IGNORECASE)


def tools() -> tuple[dict | None, str]:
    """The environment render_three.mjs needs (node, three.js, puppeteer-core, Chromium), or None and why
    not (``make tools browser``; ``THREE_DIR``, ``PUPPETEER_CORE_DIR``, ``CHROMIUM`` say where)."""
    three = Path(os.environ.get("THREE_DIR", NODE_MODULES / "three"))
    pup = Path(os.environ.get("PUPPETEER_CORE_DIR", NODE_MODULES / "puppeteer-core"))
    chromium = Path(os.environ.get("CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium")
    if shutil.which("node") is None:
        return None, "node not found (install nodejs)"
    if not (three / "package.json").is_file():
        return None, f"three.js not installed at {three}: run `make tools browser`"
    if not (pup / "package.json").is_file():
        return None, f"puppeteer-core not installed at {pup}: run `make tools browser`"
    if not chromium.is_file():
        return None, f"Chromium not found at {chromium}: run `make tools browser` (or set CHROMIUM)"
    return dict(os.environ, THREE_DIR=str(three), PUPPETEER_CORE_DIR=str(pup), CHROMIUM=str(chromium)), ""


def world_camera(camera, F: np.ndarray):
    """The preview's camera (head frame) as a camera of the file's world frame (``v_head = F v_world``)."""
    from faceretarget.render import Camera

    return Camera(camera.rotation @ F, F.T @ camera.center, camera.scale, camera.size)


def three_spec(camera, F: np.ndarray, time: float, *, light=None, ambient: float = 0.22, specular: float = 0.12,
               background=None) -> dict:
    """render_three.mjs's spec for the preview's camera (head frame), the file's frame ``F`` (world to head)
    and the preview's lights."""
    from faceretarget.render import DEFAULT_BACKGROUND, DEFAULT_LIGHT

    wc = world_camera(camera, F)
    W, H = camera.size
    L = np.asarray(DEFAULT_LIGHT if light is None else light, np.float64)
    L = L / np.linalg.norm(L)
    fill = np.array([0.6, -0.1, 0.8])
    fill = fill / np.linalg.norm(fill)
    to_world = wc.rotation.T                     # view -> world
    half = L + np.array([0.0, 0.0, 1.0])
    half = half / np.linalg.norm(half)
    return {"width": int(W), "height": int(H), "time": float(time), "clip": None,
            "background": list(map(float, DEFAULT_BACKGROUND if background is None else background)),
            "camera": {"right": wc.rotation[0].tolist(), "up": wc.rotation[1].tolist(), "back": wc.rotation[2].tolist(),
                       "center": wc.center.tolist(), "half_width": W / 2.0 / camera.scale,
                       "half_height": H / 2.0 / camera.scale, "depth": DEPTH},
            "ambient": float(np.pi * ambient),
            "lights": [{"direction": (to_world @ L).tolist(), "intensity": float(np.pi * 0.85)},
                       {"direction": (to_world @ fill).tolist(), "intensity": float(np.pi * 0.18)}],
            "lambert": True, "highlight": {"halfway": half.tolist(), "strength": float(specular), "exponent": 40.0}}


def render_three(glb: Path, spec: dict, out_png: Path, env: dict, timeout: float = 120.0) -> dict:
    """Run render_three.mjs; its JSON report (raises RuntimeError with its stderr when it fails)."""
    with tempfile.TemporaryDirectory() as d:
        sp = Path(d) / "spec.json"
        sp.write_text(json.dumps(spec))
        r = subprocess.run(["node", str(SCRIPT), str(glb), "--spec", str(sp), "--out", str(out_png),
                            "--timeout", str(int(timeout))], capture_output=True, text=True, timeout=timeout + 30,
                           env=env)
    if r.returncode != 0:
        raise RuntimeError(f"render_three.mjs failed ({r.returncode}) on {glb}: {r.stderr.strip()[-2000:]}")
    return json.loads(r.stdout)


def read_png(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def lab(img: np.ndarray) -> np.ndarray:
    """(H, W, 3) sRGB bytes -> CIE L*a*b* (D65)."""
    c = np.asarray(img, np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    M = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750],
                  [0.0193339, 0.1191920, 0.9503041]])
    xyz = lin @ M.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], axis=-1)


def delta_e(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) CIE 1976 colour difference of two sRGB images."""
    return np.linalg.norm(lab(a) - lab(b), axis=-1)


def chroma(img: np.ndarray) -> np.ndarray:
    """(..., ) C*ab of sRGB bytes (0 for a grey)."""
    L = lab(img)
    return np.hypot(L[..., 1], L[..., 2])


def _polygon(points: np.ndarray, size) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.new("L", tuple(int(s) for s in size), 0)
    ImageDraw.Draw(im).polygon([(float(x), float(y)) for x, y in points], fill=1)
    return np.asarray(im, bool)


def regions(drive, look, camera, weights_row: np.ndarray) -> dict[str, np.ndarray]:
    """(H, W) bool masks of the face, eyes, lips and hair for the preview's camera at one frame
    (``weights_row``: the driving shapes' weights, ``drive.rig``'s order)."""
    from faceretarget.character import character_frame
    from faceretarget.render import render_scene

    ch = drive.character
    F = character_frame(ch)
    wc = world_camera(camera, F)
    size = camera.size
    lm = ch.landmark_positions(drive.full_weights(np.asarray(weights_row, np.float64)[None]), drive.channels)[0]
    px = wc.project(lm)[:, :2]
    face = _polygon(np.concatenate([px[0:17], px[26:16:-1]]), size)
    eyes = _polygon(px[36:42], size) | _polygon(px[42:48], size)
    lips = _polygon(px[48:60], size) & ~_polygon(px[60:68], size)
    hair_ids = [i for i, m in enumerate(ch.meshes) if HAIR.search(m.name)]
    hair = np.zeros(size[::-1], bool)
    if hair_ids:
        seen = render_scene(ch.meshes, wc, textures=False).mesh
        hair = np.isin(seen, hair_ids)
    return {"face": face, "eyes": eyes, "lips": lips, "hair": hair}


def compare(ours: np.ndarray, theirs: np.ndarray, masks: dict[str, np.ndarray]) -> dict[str, float | None]:
    """Mean Delta E per region (None for an empty one) and each region's pixel count."""
    d = delta_e(ours, theirs)
    out: dict = {}
    for k, m in masks.items():
        out[k] = float(d[m].mean()) if m.any() else None
        out[f"{k}_px"] = int(m.sum())
    return out


def side_by_side(panels: list[tuple[str, np.ndarray]], masks: dict[str, np.ndarray] | None = None,
                 outlined: tuple[int, ...] = (-1,)) -> np.ndarray:
    """Labelled panels in a row, the region outlines drawn on the ``outlined`` ones (Delta E maps)."""
    from faceretarget.render import render_grid

    imgs = [p for _, p in panels]
    colours = {"face": (255, 255, 255), "eyes": (60, 200, 255), "lips": (255, 80, 160), "hair": (120, 255, 120)}
    for i in outlined if masks else ():
        img = imgs[i].copy()
        for k, m in masks.items():
            edge = m & ~(np.roll(m, 1, 0) & np.roll(m, -1, 0) & np.roll(m, 1, 1) & np.roll(m, -1, 1))
            img[edge] = colours.get(k, (255, 255, 0))
        imgs[i] = img
    return render_grid(imgs, [t for t, _ in panels], cols=len(imgs))


def delta_e_image(d: np.ndarray, top: float = 30.0) -> np.ndarray:
    """A Delta E map as an image: black 0, through red, to yellow at ``top`` and over."""
    u = np.clip(d / top, 0.0, 1.0)
    rgb = np.stack([np.clip(2 * u, 0, 1), np.clip(2 * u - 1, 0, 1), np.zeros_like(u)], axis=-1)
    return np.round(rgb * 255).astype(np.uint8)
