"""The NumPy preview renderer."""

from __future__ import annotations

import time

import numpy as np
import pytest
from PIL import Image

from faceretarget import Mesh
from faceretarget.errors import InvalidDataError
from faceretarget.render import (
    DEFAULT_BACKGROUND,
    fit_camera,
    render_frames,
    render_grid,
    render_mesh,
    render_shapes,
    save_png,
)

BG = np.round(np.asarray(DEFAULT_BACKGROUND) * 255).astype(np.uint8)


def _uv_sphere(r=1.0, n_lat=64, n_lon=128) -> Mesh:
    th = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1).reshape(-1, 3) * r
    v = np.vstack([v, [[0, r, 0], [0, -r, 0]]])
    top, bot = len(v) - 2, len(v) - 1
    idx = np.arange((n_lat - 1) * n_lon).reshape(n_lat - 1, n_lon)
    nxt = np.roll(idx, -1, axis=1)
    quads = np.stack([idx[:-1], nxt[:-1], nxt[1:], idx[1:]], -1).reshape(-1, 4)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]],
                           np.stack([np.full(n_lon, top), nxt[0], idx[0]], 1),
                           np.stack([np.full(n_lon, bot), idx[-1], nxt[-1]], 1)])
    return Mesh.from_triangles(v, tris)


def _cube() -> Mesh:
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    return Mesh(v, np.full(6, 4), np.array(quads).reshape(-1))


def _covered(img: np.ndarray) -> np.ndarray:
    return (img != BG).any(axis=2)


def test_sphere_silhouette_area():
    W = H = 256
    margin = 0.1
    img = render_mesh(_uv_sphere(), size=(W, H), margin=margin)
    assert img.shape == (H, W, 3) and img.dtype == np.uint8
    r_px = W * (1 - 2 * margin) / 2
    frac = _covered(img).mean()
    expect = np.pi * r_px ** 2 / (W * H)
    assert abs(frac - expect) / expect < 0.02
    # centred: the silhouette's centroid is the image centre
    yy, xx = np.nonzero(_covered(img))
    assert abs(xx.mean() + 0.5 - W / 2) < 1.0 and abs(yy.mean() + 0.5 - H / 2) < 1.0


def test_cube_fills_its_square():
    W, H = 200, 100  # non-square image: the cube is fitted to the height
    img = render_mesh(_cube(), size=(W, H), view="front", margin=0.1)
    cov = _covered(img)
    side = H * 0.8
    assert abs(cov.sum() - side ** 2) / side ** 2 < 0.03
    cols = np.flatnonzero(cov.any(axis=0))
    assert abs((cols[0] + cols[-1] + 1) / 2 - W / 2) <= 1.0


def test_zbuffer_nearer_triangle_wins():
    # two overlapping triangles, red at z = 1 (nearer the front camera), blue at z = 0
    v = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0], [-1, 1, 1], [1, 1, 1], [0, -1, 1]], float)
    col = np.array([[0, 0, 1]] * 3 + [[1, 0, 0]] * 3, float)
    for faces in ([[0, 1, 2], [3, 5, 4]], [[3, 5, 4], [0, 1, 2]]):  # face order must not matter
        img = render_mesh(v, np.array(faces), size=(64, 64), color=col, ambient=1.0, specular=0.0,
                          margin=0.0)
        c = img[32, 32].astype(int)
        assert c[0] > 200 and c[2] < 60, c
    # from behind the blue one is nearer
    img = render_mesh(v, np.array([[0, 1, 2], [3, 5, 4]]), size=(64, 64), view="back", color=col,
                      ambient=1.0, specular=0.0, margin=0.0)
    c = img[32, 32].astype(int)
    assert c[2] > 200 and c[0] < 60, c


def test_deterministic():
    m = _uv_sphere(n_lat=24, n_lon=48)
    a = render_mesh(m, size=(96, 80), view="three_quarter")
    b = render_mesh(m, size=(96, 80), view="three_quarter")
    assert np.array_equal(a, b)


def test_lit_from_upper_left():
    img = render_mesh(_uv_sphere(), size=(128, 128)).astype(float).sum(axis=2)
    assert img[40, 40] > img[88, 88] + 100


def test_flat_and_antialias():
    m = _uv_sphere(n_lat=16, n_lon=32)
    flat = render_mesh(m, size=(64, 64), shading="flat")
    smooth = render_mesh(m, size=(64, 64))
    assert not np.array_equal(flat, smooth)
    aa = render_mesh(m, size=(64, 64), antialias=2)
    assert aa.shape == (64, 64, 3)
    # antialiased edges have intermediate values
    assert abs(_covered(aa).mean() - _covered(smooth).mean()) < 0.02
    with pytest.raises(InvalidDataError):
        render_mesh(m, shading="toon")


def test_views_and_camera():
    # a point on the character's left (+x) appears right of centre from the front and nearer
    # the viewer (left of centre) when looking at the character's left side
    pts = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]])
    cam = fit_camera(pts, (100, 100), "front")
    p = cam.project(pts)
    assert p[0, 0] > 50 > p[1, 0] and p[3, 1] < 50  # +x right, +y up
    assert p[2, 2] > p[1, 2]  # +z is nearer in the front view
    side = fit_camera(pts, (100, 100), "left").project(pts)
    assert side[0, 2] > side[1, 2]  # from the left side, +x is nearer
    assert side[2, 0] < 50  # the face (+z) points to image left
    assert np.allclose(fit_camera(pts, (100, 100), 0.0).rotation, cam.rotation)
    with pytest.raises(InvalidDataError):
        fit_camera(pts, (100, 100), "top")


def test_render_frames_fixed_camera():
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    frames = np.stack([tri, tri + [3, 0, 0]])
    imgs = list(render_frames(frames, np.array([[0, 1, 2]]), size=(80, 40)))
    assert len(imgs) == 2
    x0 = np.flatnonzero(_covered(imgs[0]).any(axis=0)).mean()
    x1 = np.flatnonzero(_covered(imgs[1]).any(axis=0)).mean()
    assert x1 > x0 + 30  # the triangle moved right in a fixed frame


def test_bad_inputs():
    m = _cube()
    with pytest.raises(InvalidDataError):
        render_mesh(np.zeros((5, 3)), m)
    with pytest.raises(InvalidDataError):
        render_mesh(np.zeros((8, 3)))
    with pytest.raises(InvalidDataError):
        render_mesh(m, color=np.zeros((3, 3)))


def test_speed_on_a_face_sized_mesh():
    # 97 x 97 = 9,409 vertices, 18,432 triangles, like ICT-FaceKit's face
    n = 97
    u = np.linspace(-1, 1, n)
    X, Y = np.meshgrid(u, u)
    Z = 0.3 * np.exp(-3 * (X ** 2 + Y ** 2)) + 0.05 * np.sin(6 * X) * np.cos(5 * Y)
    v = np.stack([X, Y, Z], -1).reshape(-1, 3) * 10
    idx = np.arange(n * n).reshape(n, n)
    q = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    m = Mesh(v, np.full(len(q), 4), q.reshape(-1))
    assert m.n_vertices == 9409 and len(m.triangles()) == 18432
    render_mesh(m, size=(64, 64))  # warm up
    t = time.perf_counter()
    img = render_mesh(m, size=(512, 512))
    dt = time.perf_counter() - t
    assert dt < 1.0, f"{dt:.2f} s"
    assert _covered(img).mean() > 0.75


def test_grid_and_png(tmp_path):
    a = np.full((30, 40, 3), 200, np.uint8)
    b = np.full((20, 20, 3), 50, np.uint8)
    g = render_grid([a, b, a], cols=2, pad=2)
    assert g.shape == (2 * 30 + 3 * 2, 2 * 40 + 3 * 2, 3)
    gl = render_grid([a, b, a], labels=["one", "two", "three"], cols=3, pad=2)
    assert gl.shape[1] == 3 * 40 + 4 * 2 and gl.shape[0] > 30 + 4
    with pytest.raises(InvalidDataError):
        render_grid([a], labels=["x", "y"])
    out = save_png(tmp_path / "sheet.png", g)
    back = np.asarray(Image.open(out))
    assert np.array_equal(back, g)
    assert [p.name for p in tmp_path.iterdir()] == ["sheet.png"]  # no temporary left behind
    with pytest.raises(InvalidDataError):
        save_png(tmp_path / "bad.png", g.astype(float))


def test_render_shapes_sheet():
    from faceretarget.datasets import make_demo_character

    rig = make_demo_character("bo")
    sheet = render_shapes(rig, ["jawOpen", "eyeBlinkLeft"], size=(64, 64), cols=3)
    assert sheet.ndim == 3 and sheet.shape[1] == 3 * 64 + 4 * 4
