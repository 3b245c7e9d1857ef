"""Previews that look like the user's character (issue 34): materials as a glTF viewer draws them.

* A glTF file of cards made here (an opaque single-sided wall, a card masked by its texture's alpha, a
  blended card, a quad facing away, a quad with vertex colours) is read with its alpha modes, cutoffs,
  sides and ``COLOR_0``; the NumPy and OpenGL renderers agree on it, what is behind a masked card's
  transparent texels shows, a blended card mixes, the quad facing away is culled; and three.js draws the
  same picture (``tests/browser/render_three.mjs``, when node, three.js and Chromium are here).
* The VALID avatar (shared data): its eyes show the iris of its eye texture (not a grey smudge: the
  texture was sampled at the eye mesh's 201 vertices), its hair drawn masked by a transparent texture shows
  what is behind it, and one frame of the preview is within the bound of three.js drawing the written file
  (mean CIE 1976 Delta E over the face, eyes, lips and hair: ``bench/_look_compare.py``).

The three.js checks skip naming what is missing, or fail instead under ``FACERETARGET_REQUIRE_BROWSER=1``
(as ``tests/test_browser.py`` decides); the OpenGL ones skip without an EGL driver.
"""

from __future__ import annotations

import io
import json
import os
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

from faceretarget.character import Material, character_frame
from faceretarget.io import read_character
from faceretarget.render import MeshRenderer, Surface, gl_available, scene_surface

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import _look_compare as lc  # noqa: E402

#: The bounds of the three.js comparison (mean Delta E), about twice what the preview measures on the VALID
#: avatar's frame below (face 0.49, eyes 1.6, lips 0.77, hair 0.64: most of it texture filtering, one mip level
#: where three.js blends two); the vertex-colour look of before (no gaze) measured 1.74, 21.7, 1.75 and 4.0.
BOUND = {"face": 1.0, "eyes": 3.0, "lips": 1.5, "hair": 1.3}
CARD_BOUND = 0.5  # the cards' picture (measured 0.14, the 99th percentile 0.56)


@pytest.fixture(scope="module")
def gl():
    ok, why = gl_available()
    if not ok:
        pytest.skip(f"no OpenGL preview renderer: {why}")
    return why


@pytest.fixture(scope="module")
def three_env():
    env, why = lc.tools()
    if env is None:
        if os.environ.get("FACERETARGET_REQUIRE_BROWSER", "") not in ("", "0"):
            pytest.fail(why)
        pytest.skip(why)
    return env


# ------------------------------------------------------------------------------------ the cards
STRIPES = 8  # the masked card's texture: columns of 8 texels, opaque and transparent in turn


def _png(rgba: np.ndarray) -> bytes:
    from PIL import Image

    b = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(b, format="PNG")
    return b.getvalue()


def _stripes() -> np.ndarray:
    tex = np.zeros((64, 64, 4), np.uint8)
    tex[..., 0] = np.linspace(40, 250, 64).astype(np.uint8)[None, :]
    tex[..., 1] = 200
    tex[..., 2] = 60
    tex[..., 3] = np.where((np.arange(64) // STRIPES) % 2 == 0, 255, 0)[None, :]
    return tex


def card_glb(path: Path) -> Path:
    """A glTF binary of five quads facing +Z (one facing -Z) with the materials of the module docstring."""
    quads = [  # (x0, y0, x1, y1, z, material, facing away, vertex colours)
        (-1.0, -1.0, 1.0, 1.0, 0.0, 0, False, False),
        (-0.8, -0.6, 0.2, 0.8, 0.3, 1, False, False),
        (-0.2, -0.8, 0.8, 0.4, 0.5, 2, False, False),
        (0.3, 0.45, 0.9, 0.95, 0.7, 3, True, False),
        (-0.95, 0.5, -0.35, 0.95, 0.7, 4, False, True),
    ]
    materials = [
        {"name": "wall", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.1, 0.1, 1.0]}},
        {"name": "card", "doubleSided": True, "alphaMode": "MASK", "alphaCutoff": 0.4,
         "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}},
        {"name": "glass", "doubleSided": True, "alphaMode": "BLEND",
         "pbrMetallicRoughness": {"baseColorFactor": [0.1, 0.2, 0.9, 0.5]}},
        {"name": "away", "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.9, 0.9, 1.0]}},
        {"name": "painted", "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0]}},
    ]
    blob = bytearray()
    views, accessors = [], []

    def add(arr: np.ndarray, ctype: int, type_: str, target: int | None, minmax: bool = False) -> int:
        while len(blob) % 4:
            blob.append(0)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": arr.nbytes} |
                     ({"target": target} if target else {}))
        blob.extend(arr.tobytes())
        acc = {"bufferView": len(views) - 1, "componentType": ctype, "count": len(arr), "type": type_}
        if minmax:
            acc |= {"min": arr.min(axis=0).tolist(), "max": arr.max(axis=0).tolist()}
        accessors.append(acc)
        return len(accessors) - 1

    meshes, nodes = [], []
    for x0, y0, x1, y1, z, mat, away, painted in quads:
        pos = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float32)
        idx = np.array([0, 2, 1, 0, 3, 2] if away else [0, 1, 2, 0, 2, 3], np.uint16)
        attrs = {"POSITION": add(pos, 5126, "VEC3", 34962, True),
                 "TEXCOORD_0": add(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32), 5126, "VEC2", 34962)}
        if painted:
            attrs["COLOR_0"] = add(np.array([[0.1, 0.8, 0.1, 1], [0.1, 0.8, 0.1, 1], [0.1, 0.1, 0.9, 1],
                                             [0.1, 0.1, 0.9, 1]], np.float32), 5126, "VEC4", 34962)
        prim = {"attributes": attrs, "indices": add(idx, 5123, "SCALAR", 34963), "material": mat}
        meshes.append({"name": materials[mat]["name"], "primitives": [prim]})
        nodes.append({"name": materials[mat]["name"], "mesh": len(meshes) - 1})
    png = _png(_stripes())
    while len(blob) % 4:
        blob.append(0)
    views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(png)})
    blob.extend(png)
    while len(blob) % 4:
        blob.append(0)
    js = {"asset": {"version": "2.0", "generator": "faceretarget tests"}, "scene": 0,
          "scenes": [{"nodes": list(range(len(nodes)))}], "nodes": nodes, "meshes": meshes,
          "materials": materials, "accessors": accessors, "bufferViews": views,
          "buffers": [{"byteLength": len(blob)}],
          "images": [{"bufferView": len(views) - 1, "mimeType": "image/png"}],
          "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}],
          "textures": [{"source": 0, "sampler": 0}]}
    j = json.dumps(js).encode()
    j += b" " * (-len(j) % 4)
    body = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
    return path


@pytest.fixture(scope="module")
def cards(tmp_path_factory):
    glb = card_glb(tmp_path_factory.mktemp("cards") / "cards.glb")
    ch = read_character(glb)
    mesh, surface = scene_surface(ch.meshes)
    return glb, ch, mesh, surface


def _card_render(mesh, surface, backend: str, camera=None):
    with MeshRenderer(mesh, (256, 256), backend=backend, surface=surface, head_room=0.0, mm_per_unit=1000.0,
                      camera=camera) as r:
        return r.render(mesh.vertices), r.camera


def test_gltf_materials_are_read_with_alpha_sides_and_vertex_colours(cards):
    _, ch, _, _ = cards
    mats = {m.name: m.materials[0] for m in ch.meshes}
    assert mats["wall"].alpha_mode == "OPAQUE" and not mats["wall"].double_sided
    assert mats["card"].alpha_mode == "MASK" and mats["card"].alpha_cutoff == pytest.approx(0.4)
    assert mats["card"].double_sided and mats["card"].image[..., 3].min() == 0
    assert mats["glass"].alpha_mode == "BLEND" and mats["glass"].color[3] == pytest.approx(0.5)
    painted = next(m for m in ch.meshes if m.name == "painted")
    assert painted.vertex_colors.shape == (4, 4)
    np.testing.assert_allclose(painted.vertex_colors[:, :3], [[0.1, 0.8, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.9],
                                                              [0.1, 0.1, 0.9]], atol=1e-6)
    assert all(m.vertex_colors is None for m in ch.meshes if m.name != "painted")


def _pixel(cam, x: float, y: float, z: float) -> tuple[int, int]:
    px = cam.project(np.array([[x, y, z]]))[0]
    return int(px[1]), int(px[0])


def test_cards_mask_blend_and_cull_as_a_gltf_viewer(cards):
    """The NumPy renderer: the wall shows through the masked card's transparent stripes (its own colour where
    the stripes are opaque), the blended card mixes half of itself with what is under it, the quad facing away
    is not drawn (the wall is), and the vertex colours paint their quad green at the bottom, blue at the top."""
    _, _, mesh, surface = cards
    img, cam = _card_render(mesh, surface, "numpy")
    wall = img[_pixel(cam, 0.9, -0.9, 0.0)].astype(int)
    assert wall[0] > 200 and wall[0] > wall[1] + 100                           # red, lit
    # the masked card, u from 0 (x = -0.8) to 1 (x = 0.2): texel columns of 8 opaque, 8 transparent
    row = _pixel(cam, 0.0, 0.45, 0.3)[0]              # above the glass, under the painted quad
    for k in range(8):
        x = -0.8 + (k * STRIPES + STRIPES / 2) / 64 * 1.0
        c = img[row, _pixel(cam, x, 0.45, 0.3)[1]].astype(int)
        if k % 2:
            np.testing.assert_array_equal(c, wall, err_msg=f"stripe {k}: the wall shows through")
        else:
            assert c[1] > 150 and abs(c[1] - wall[1]) > 100, f"stripe {k}: the card's own colour"
    opaque = img[_pixel(cam, 0.9, 0.0, 0.0)].astype(float)                     # the wall beside the glass
    glass = img[_pixel(cam, 0.6, -0.6, 0.5)].astype(float)                     # the glass over the wall
    assert glass[2] > opaque[2] + 40 and glass[0] < opaque[0] - 40              # bluer, less red: mixed
    assert glass[0] >= 0.5 * opaque[0] - 1.0                                     # half the wall's red stays
    np.testing.assert_array_equal(img[_pixel(cam, 0.6, 0.7, 0.7)], wall)        # the quad facing away: culled
    bottom, top = img[_pixel(cam, -0.65, 0.55, 0.7)].astype(int), img[_pixel(cam, -0.65, 0.9, 0.7)].astype(int)
    assert bottom[1] > bottom[2] + 60 and top[2] > top[1] + 60


def test_render_scene_draws_alpha_and_sides(cards):
    """What ``character inspect`` and the landmark search render (render_scene, its own lights): the wall shows
    through the masked card's transparent stripes, the glass mixes, the quad facing away is culled; only opaque
    surfaces count as what is at a pixel."""
    from faceretarget.render import look_at, render_scene

    _, ch, _, _ = cards
    cam = look_at([0.0, 0.0, 0.0], [0, 0, 1], [0, 1, 0], 2.2, (220, 220))
    sr = render_scene(ch.meshes, cam)
    names = [m.name for m in ch.meshes]
    img = sr.image.astype(int)
    wall = img[_pixel(cam, 0.9, -0.9, 0.0)]
    row = _pixel(cam, 0.0, 0.45, 0.3)[0]
    for k in range(8):
        y, x = row, _pixel(cam, -0.8 + (k * STRIPES + STRIPES / 2) / 64, 0.45, 0.3)[1]
        assert names[sr.mesh[y, x]] == ("wall" if k % 2 else "card"), k
        if k % 2:
            np.testing.assert_array_equal(img[y, x], wall)
    glass = img[_pixel(cam, 0.6, -0.6, 0.5)]
    assert names[sr.mesh[_pixel(cam, 0.6, -0.6, 0.5)]] == "wall" and glass[2] > wall[2] + 40
    assert names[sr.mesh[_pixel(cam, 0.6, 0.7, 0.7)]] == "wall"                  # the quad facing away


def test_cards_gl_matches_numpy(gl, cards):
    """Measured: mean |difference| 0.08 grey levels, none over 1."""
    _, _, mesh, surface = cards
    a, cam = _card_render(mesh, surface, "gl")
    b, _ = _card_render(mesh, surface, "numpy", cam)
    d = np.abs(a.astype(int) - b)
    assert d.mean() < 0.3 and (d > 2).mean() < 1e-3


def test_cards_match_three_js(three_env, cards, tmp_path):
    """three.js draws the file the way the preview does: mean Delta E over the picture under CARD_BOUND, the
    masked stripes, the blend and the culled quad included."""
    glb, ch, mesh, surface = cards
    ours, cam = _card_render(mesh, surface, "numpy")
    lc.render_three(glb, lc.three_spec(cam, character_frame(ch), 0.0), tmp_path / "three.png", three_env)
    theirs = lc.read_png(tmp_path / "three.png")
    d = lc.delta_e(ours, theirs)
    print(f"cards: mean Delta E {d.mean():.2f}, 99th percentile {np.percentile(d, 99):.2f}")
    assert d.mean() < CARD_BOUND and np.percentile(d, 99) < 3.0


def test_take_sampler_turns_rigid_parts_with_slerp():
    """A part turning about a centre (an eyeball with the gaze): 0 then 90 degrees about +Y over two frames;
    half way, 45 degrees; the rest of the rig follows its shapes only."""
    from scipy.spatial.transform import Rotation

    from faceretarget import Mesh
    from faceretarget.pipelines import TakeSampler
    from faceretarget.rig import Rig

    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [2.0, 0, 1], [3.0, 0, 1], [2.0, 1, 1]])
    rig = Rig(Mesh.from_triangles(V, [[0, 1, 2], [3, 4, 5]]), ["up"], np.tile([0.0, 1.0, 0.0], (1, 6, 1)), unit="m")
    turn = Rotation.from_euler("y", [[0.0], [90.0]], degrees=True)
    s = TakeSampler(rig, np.array([[0.0], [1.0]]), np.array([0.0, 1.0]), None,
                    [(np.array([3, 4, 5]), np.array([2.0, 0.0, 1.0]), turn)])
    np.testing.assert_allclose(s.vertices_at(0.0), V, atol=1e-6)
    end = s.vertices_at(1.0)
    np.testing.assert_allclose(end[:3], V[:3] + [0, 1, 0], atol=1e-6)
    np.testing.assert_allclose(end[4], [2.0, 1.0, 0.0], atol=1e-6)    # (1, 0, 0) from the centre turned to -Z
    mid = s.vertices_at(0.5)[4] - [2.0, 0.5, 1.0]
    np.testing.assert_allclose(mid, [np.sqrt(0.5), 0.0, -np.sqrt(0.5)], atol=1e-6)


# ------------------------------------------------------------------------------------ the VALID avatar
@pytest.fixture(scope="module")
def valid(chars):
    from faceretarget.characters import character_look, drive_rig, load_character

    ch = load_character(chars / "valid" / "AIAN_F_1_Busi.glb")
    drive = drive_rig(ch)
    return drive, character_look(drive)


def _expression(drive) -> np.ndarray:
    """A frame to compare: the jaw a little open and the lips apart (the VALID avatar's visemes)."""
    w = np.zeros(drive.rig.n_shapes)
    for name, value in (("h_expressions.AE_AA_h", 0.5), ("h_expressions.Ax_E_h", 0.3)):
        if name in drive.rig.names:
            w[drive.rig.names.index(name)] = value
    return w


def _render(look, w, backend="numpy", surface=True, camera=None, size=384):
    kw = dict(surface=look.surface, fit_to=look.frame) if surface else dict(color=look.colors)
    with MeshRenderer(look.rig.neutral, (size, size), backend=backend, pivot=look.pivot,
                      mm_per_unit=look.rig.mm_per_unit, camera=camera, **kw) as r:
        return r.render(look.rig.evaluate(w)), r.camera


IRIS = 0.27  # the iris's radius in the VALID eye texture, a fraction of the eye patch's half width


def _eye_patch(mesh) -> tuple[np.ndarray, float]:
    """The centre (u, v) and half width of an eye mesh's patch of the texture (the iris in its middle)."""
    lo, hi = mesh.mesh.uvs.min(axis=0), mesh.mesh.uvs.max(axis=0)
    return (lo + hi) / 2, float((hi - lo).min() / 2)


def _iris_texture(drive) -> np.ndarray:
    """Mean L*a*b* of the left eye's iris in its texture (the texels within IRIS of the patch's centre,
    the pupil's black middle left out)."""
    m = next(m for m in drive.character.meshes if m.name == "h_L_eye")
    img = m.materials[0].image[..., :3]
    c, r = _eye_patch(m)
    h, w = img.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w]
    d = np.hypot((xs + 0.5) / w - c[0], (ys + 0.5) / h - c[1]) / r
    return lc.lab(img[(d > 0.1) & (d < IRIS)][None])[0].mean(axis=0)


def _iris_pixels(drive, cam) -> np.ndarray:
    """(H, W) bool: the pixels of the rendered picture that show an eye's iris (an eye mesh seen, its texture
    coordinate within IRIS of its patch's centre, the pupil's middle left out), from render_scene's look-up of
    what is at each pixel (the eyes and lids do not move in the frame compared)."""
    from faceretarget.render import render_scene

    ch = drive.character
    sr = render_scene(ch.meshes, lc.world_camera(cam, character_frame(ch)), textures=False)
    out = np.zeros(sr.mesh.shape, bool)
    for i, m in enumerate(ch.meshes):
        if m.name not in ("h_L_eye", "h_R_eye"):
            continue
        on = sr.mesh == i
        tuv = m.mesh.triangle_uv_indices()[sr.triangle[on]]
        uv = np.einsum("pk,pkd->pd", sr.bary[on], m.mesh.uvs[tuv])
        c, r = _eye_patch(m)
        d = np.hypot(*(uv - c).T) / r
        out[on] = (d > 0.1) & (d < IRIS)
    return out


def _hue(lab: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(lab[2], lab[1])))


def test_valid_eyes_show_their_iris(valid):
    """The iris pixels are dark and coloured as the texture's iris.  Measured: texture L* 13, chroma 11.8, hue
    22 degrees (a dark red-brown); the preview (lit) 27, 9.0, 24; the vertex-colour look of before 53, 7.4, 44
    (the iris blurred into the pink white of the eye: pale)."""
    drive, look = valid
    w = _expression(drive)
    img, cam = _render(look, w)
    iris = _iris_pixels(drive, cam)
    assert iris.sum() > 40
    tex = _iris_texture(drive)
    now = lc.lab(img)[iris].mean(axis=0)
    old = lc.lab(_render(look, w, surface=False, camera=cam)[0])[iris].mean(axis=0)
    for name, v in (("texture", tex), ("preview", now), ("vertex colours", old)):
        print(f"iris ({iris.sum()} px) {name}: L* {v[0]:.0f}, chroma {np.hypot(v[1], v[2]):.1f}, hue {_hue(v):.0f}")
    assert tex[0] < 30 and np.hypot(tex[1], tex[2]) > 8.0            # the texture's iris: dark and coloured
    assert now[0] < 35 and np.hypot(now[1], now[2]) > 0.5 * np.hypot(tex[1], tex[2])
    assert abs((_hue(now) - _hue(tex) + 180) % 360 - 180) < 20
    assert old[0] > 40                                                # before: pale


def test_valid_hair_masked_by_a_transparent_texture_shows_what_is_behind(valid):
    """The wig drawn MASK with a texture whose alpha is 0 everywhere: the picture is the one without the wig
    (NumPy, bit for bit); drawn BLEND at alpha 0.5 (layers of hair over each other, back to front): every
    hair pixel differs from both, and OpenGL (triangles sorted back to front) agrees with NumPy (fragments
    sorted per pixel) where one is available."""
    drive, look = valid
    w = _expression(drive)
    sf = look.surface
    wig = [k for k, m in enumerate(sf.materials) if m.name == "Hair"]
    assert wig, [m.name for m in sf.materials]
    hair = np.isin(sf.triangle_material, wig)

    def with_hair(mode: str, alpha_tex: int, factor_a: float) -> Surface:
        mats = list(sf.materials)
        for k in wig:
            m = mats[k]
            img = m.image.copy()
            img[..., 3] = alpha_tex
            mats[k] = Material(m.name, np.r_[np.asarray(m.color)[:3], factor_a], img, alpha_mode=mode,
                               double_sided=m.double_sided)
        return Surface(mats, sf.triangle_material, sf.uvs, sf.vertex_colors)

    full, cam = _render(look, w)
    masked, _ = _render(_Look(look, with_hair("MASK", 0, 1.0)), w, camera=cam)
    blended, _ = _render(_Look(look, with_hair("BLEND", 255, 0.5)), w, camera=cam)
    bare, _ = _render(_Look(look, Surface(sf.materials, sf.triangle_material, sf.uvs), drop=hair), w, camera=cam)
    shown = (full != bare).any(axis=2)                               # where the wig is in front
    assert shown.mean() > 0.1
    np.testing.assert_array_equal(masked, bare)
    assert np.abs(blended[shown].astype(int) - full[shown]).mean() > 5
    assert np.abs(blended[shown].astype(int) - bare[shown]).mean() > 5
    if gl_available()[0]:
        g, _ = _render(_Look(look, with_hair("BLEND", 255, 0.5)), w, backend="gl", camera=cam)
        d = np.abs(g.astype(int) - blended)
        print(f"blended hair, OpenGL against NumPy: mean {d.mean():.3f}, over 8 levels {(d > 8).mean():.2e}")
        assert d.mean() < 0.5 and (d > 8).mean() < 2e-3


class _Look:
    """``look`` with another surface, or without the triangles ``drop``."""

    def __init__(self, look, surface: Surface, drop: np.ndarray | None = None):
        from faceretarget import Mesh
        from faceretarget.rig import Rig

        self.pivot, self.frame, self.colors = look.pivot, look.frame, look.colors
        self.surface, self.rig = surface, look.rig
        if drop is not None:
            keep = ~drop
            t = look.rig.neutral.triangles()[keep]
            mesh = Mesh(look.rig.neutral.vertices, np.full(len(t), 3), t.reshape(-1), name="kept")
            self.rig = Rig(mesh, list(look.rig.names), look.rig.deltas, unit="m", keep_names=True)
            self.surface = Surface(surface.materials, surface.triangle_material[keep], surface.uvs[keep])


def test_valid_gl_matches_numpy(gl, valid):
    """Textures, mip levels and lights: measured mean |difference| 0.13 grey levels, 2e-5 of the pixels
    more than 8 off (where the mip level of a pixel is not the triangle's)."""
    drive, look = valid
    w = _expression(drive)
    a, cam = _render(look, w, backend="gl", size=512)
    b, _ = _render(look, w, backend="numpy", camera=cam, size=512)
    d = np.abs(a.astype(int) - b)
    assert d.mean() < 0.5 and (d > 8).mean() < 1e-3


def test_valid_preview_matches_three_js(three_env, valid, tmp_path):
    """One frame written into a copy of the VALID avatar's file (as ``animate --out`` does: the shapes' weights,
    the gaze on the eye joints, here 15 degrees to the character's left and 6 up) drawn by three.js and by the
    preview (its vertices as the preview video takes them, the eyeballs turned about their joints): mean Delta E
    per region under BOUND; the vertex-colour look of before (no gaze) is over it in every region."""
    from scipy.spatial.transform import Rotation

    from faceretarget.io import write_character_animation
    from faceretarget.pipelines import TakeSampler

    drive, look = valid
    w = _expression(drive)
    W = np.stack([w, w])
    times = np.array([0.0, 1.0 / 30.0])
    turn = Rotation.from_euler("YX", [[15.0, -6.0]] * 2, degrees=True)
    gaze = {"leftEye": turn, "rightEye": turn}
    glb = write_character_animation(tmp_path / "take.glb", drive.character, drive.channels, drive.full_weights(W),
                                    times, gaze=gaze)
    assert len(look.eye_turns(gaze)) == 2
    v = TakeSampler(look.rig, W, times, None, look.eye_turns(gaze)).vertices_at(0.0)
    with MeshRenderer(look.rig.neutral, (512, 512), backend="numpy", surface=look.surface, fit_to=look.frame,
                      pivot=look.pivot, mm_per_unit=look.rig.mm_per_unit) as r:
        ours, cam = r.render(v), r.camera
    old, _ = _render(look, w, surface=False, camera=cam, size=512)
    lc.render_three(glb, lc.three_spec(cam, character_frame(drive.character), 0.0), tmp_path / "three.png",
                    three_env)
    theirs = lc.read_png(tmp_path / "three.png")
    masks = lc.regions(drive, look, cam, w)
    now, before = lc.compare(ours, theirs, masks), lc.compare(old, theirs, masks)
    print("mean Delta E against three.js: " + ", ".join(f"{k} {now[k]:.2f} (before {before[k]:.2f})" for k in BOUND))
    for k, bound in BOUND.items():
        assert now[f"{k}_px"] > 300, k
        assert now[k] < bound, f"{k}: {now[k]:.2f} >= {bound}"
    assert all(before[k] > bound for k, bound in BOUND.items())
