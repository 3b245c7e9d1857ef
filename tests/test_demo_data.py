"""The built-in procedural demo characters and take."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from faceretarget.datasets import (
    demo_vertex_colors,
    make_demo_character,
    make_demo_take,
)
from faceretarget.datasets._demo import _build
from faceretarget.errors import InvalidDataError
from faceretarget.names import ARKIT_NAMES

CHARACTERS = ("ada", "bo")
FLIP = np.array([-1.0, 1.0, 1.0])


@pytest.fixture(scope="module", params=CHARACTERS)
def rig(request):
    return make_demo_character(request.param)


def _mirror_map(v: np.ndarray) -> tuple[np.ndarray, float]:
    d, j = cKDTree(v).query(v * FLIP)
    return j, float(d.max())


def _pairs():
    out = []
    for n in ARKIT_NAMES:
        if n.endswith("Left"):
            out.append((n, n[: -len("Left")] + "Right"))
    return out


def test_basic_structure(rig):
    assert rig.n_shapes == 52
    assert rig.names == list(ARKIT_NAMES)
    assert rig.unit == "cm"
    assert rig.deltas.shape == (52, rig.n_vertices, 3)
    assert np.isfinite(rig.deltas).all()
    assert set(rig.neutral.face_counts.tolist()) == {4}
    # a face-sized thing in centimetres: 14-20 cm wide, 18-24 cm tall
    ext = rig.neutral.vertices.max(0) - rig.neutral.vertices.min(0)
    assert 14.0 < ext[0] < 20.0
    assert 18.0 < ext[1] < 24.0
    # every vertex is used by a face
    assert np.unique(rig.neutral.face_indices).size == rig.n_vertices
    # four pieces: skin, two eyeballs, tongue
    e = rig.neutral.edges()
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(rig.n_vertices,) * 2)
    assert connected_components(adj, directed=False)[0] == 4


def test_characters_differ_in_size_and_order():
    a, b = (make_demo_character(n) for n in CHARACTERS)
    assert 1500 <= a.n_vertices <= 3000
    assert 1000 <= b.n_vertices <= 3000
    assert a.n_vertices != b.n_vertices
    wa = np.ptp(a.neutral.vertices[:, 0])
    wb = np.ptp(b.neutral.vertices[:, 0])
    assert wb > wa + 0.5  # bo's face is wider
    # bo's chin/jaw is broader: width between landmarks 5 and 11
    ja = np.ptp(a.neutral.vertices[a.landmarks[[5, 11]], 0])
    jb = np.ptp(b.neutral.vertices[b.landmarks[[5, 11]], 0])
    assert jb > ja + 1.0
    # bo's nose sticks out further from the cheeks
    na = a.neutral.vertices[a.landmarks[30], 2] - a.neutral.vertices[a.landmarks[31], 2]
    nb = b.neutral.vertices[b.landmarks[30], 2] - b.neutral.vertices[b.landmarks[31], 2]
    assert nb > na
    # vertex 0 is somewhere else entirely on the two faces
    assert np.linalg.norm(a.neutral.vertices[0] - b.neutral.vertices[0]) > 3.0


def test_deterministic_and_fast():
    a1 = make_demo_character("ada")
    a2 = make_demo_character("ada")
    assert np.array_equal(a1.neutral.vertices, a2.neutral.vertices)
    assert np.array_equal(a1.deltas, a2.deltas)
    assert a1.deltas is not a2.deltas  # fresh arrays each call
    a1.deltas[0] += 1.0
    assert not np.array_equal(a1.deltas, make_demo_character("ada").deltas)
    _build.cache_clear()
    t = time.perf_counter()
    for n in CHARACTERS:
        make_demo_character(n)
    assert time.perf_counter() - t < 0.5


def test_unknown_character():
    with pytest.raises(InvalidDataError, match="unknown demo character"):
        make_demo_character("carl")
    assert make_demo_character("ADA").n_vertices == make_demo_character("ada").n_vertices


def test_front_facing(rig):
    n = rig.neutral.vertex_normals()
    nose = rig.landmarks[30]
    assert n[nose, 2] > 0.5
    # most skin normals look forward
    assert np.median(n[rig.landmarks, 2]) > 0.5


def test_landmarks(rig):
    lm = rig.landmarks
    V = rig.neutral.vertices
    assert lm.shape == (68,)
    assert np.unique(lm).size == 68
    assert lm.min() >= 0 and lm.max() < rig.n_vertices
    P = V[lm]
    x, y = P[:, 0], P[:, 1]
    # image-left points (subject's right) are at -x
    assert (x[0:8] < 0).all() and (x[9:17] > 0).all() and abs(x[8]) < 0.3
    assert (x[17:22] < 0).all() and (x[22:27] > 0).all()
    assert (x[36:42] < 0).all() and (x[42:48] > 0).all()
    # order along the jaw (down to the chin and up again, left to right) and the brows
    assert (np.diff(x[0:17]) >= 0).all() and x[16] - x[0] > 10.0
    assert (np.diff(y[0:9]) <= 0).all() and (np.diff(y[8:17]) >= 0).all()
    assert (np.diff(x[17:27]) > 0).all()
    # chin lowest on the jaw line; brows over eyes over nose tip over mouth over chin
    assert np.argmin(y[0:17]) in (7, 8, 9)
    assert y[17:27].min() > y[36:48].max()
    assert y[36:48].min() > y[30] > y[48:68].max()
    assert y[48:68].min() > y[8]
    # nose tip is the most forward landmark
    assert np.argmax(P[:, 2]) == 30
    # eye corners: outer 36 / inner 39 and inner 42 / outer 45; lids above and below
    assert x[36] < x[39] < 0 < x[42] < x[45]
    assert y[37] > y[41] and y[38] > y[40] and y[43] > y[47] and y[44] > y[46]
    # mouth: corners outermost, upper lip above lower lip, inner lips between outer lips
    assert x[48] < x[60] < x[64] < x[54]
    assert y[51] > y[62] > y[66] > y[57]
    # landmark points are left/right mirror images of each other
    mirror = {0: 16, 17: 26, 36: 45, 39: 42, 31: 35, 48: 54, 60: 64, 37: 44, 41: 46}
    for i, j in mirror.items():
        assert np.allclose(P[i] * FLIP, P[j], atol=1e-6), (i, j)


def test_every_shape_moves_a_plausible_amount(rig):
    mags = np.linalg.norm(rig.deltas, axis=2)
    top = mags.max(axis=1)
    for name, m in zip(rig.names, top, strict=True):
        assert 0.1 <= m <= 3.0, f"{name}: max displacement {m:.3f} cm"
    # shapes are localised: except for the jaw family, most vertices stay (nearly) put
    for name, frac in zip(rig.names, (mags > 0.01).mean(axis=1), strict=True):
        if not name.startswith(("jaw", "mouthClose", "tongueOut")):
            assert frac < 0.35, f"{name} moves {frac:.0%} of the face"


def test_left_right_mirror(rig):
    V = rig.neutral.vertices
    mirror, err = _mirror_map(V)
    assert err < 1e-9  # the neutral is exactly symmetric
    D = {n: rig.deltas[i] for i, n in enumerate(rig.names)}
    pairs = _pairs()
    assert len(pairs) == 20  # 18 sided shape pairs + jawLeft/Right + mouthLeft/Right
    for left, right in pairs:
        assert np.abs(D[left] - D[right][mirror] * FLIP).max() < 1e-6, left
        assert np.abs(D[left]).max() > 0.1
    sided = {n for p in pairs for n in p}
    for name in ARKIT_NAMES:
        if name not in sided:  # whole shapes are symmetric themselves
            assert np.abs(D[name] - D[name][mirror] * FLIP).max() < 1e-6, name


def test_left_is_the_characters_left(rig):
    V = rig.neutral.vertices
    for name in ("eyeBlinkLeft", "mouthSmileLeft", "browOuterUpLeft", "noseSneerLeft", "cheekSquintLeft"):
        m = np.linalg.norm(rig.deltas[rig.index(name)], axis=1)
        moved = m > 0.2 * m.max()
        assert (V[moved, 0] > 0).all(), name
    chin = rig.landmarks[8]
    assert rig.deltas[rig.index("jawLeft")][chin, 0] > 0.5
    assert rig.deltas[rig.index("jawRight")][chin, 0] < -0.5
    assert rig.deltas[rig.index("mouthLeft")][rig.landmarks[62], 0] > 0.5


def test_anatomy_of_key_shapes(rig):
    V = rig.neutral.vertices
    lm = rig.landmarks

    def after(name, w=1.0):
        return V + w * rig.deltas[rig.index(name)]

    # jawOpen: the chin swings down and back, the upper lip stays, the lips part by 1.5-3 cm
    J = after("jawOpen")
    d_chin = J[lm[8]] - V[lm[8]]
    assert d_chin[1] < -1.2 and d_chin[2] < 0
    assert np.linalg.norm(J[lm[62]] - V[lm[62]]) < 0.05
    gap0 = V[lm[62], 1] - V[lm[66], 1]
    gap1 = J[lm[62], 1] - J[lm[66], 1]
    assert 1.2 < gap1 - gap0 < 3.0
    # mouthClose on top of jawOpen brings the lips back together
    w = np.zeros(52)
    w[rig.index("jawOpen")] = w[rig.index("mouthClose")] = 1.0
    C = rig.evaluate(w)
    assert C[lm[62], 1] - C[lm[66], 1] < 0.3 * gap1
    # eyeBlinkLeft closes the left eye (43/44 upper lid onto 47/46 lower lid), not the right
    B = after("eyeBlinkLeft")
    open0 = V[lm[44], 1] - V[lm[46], 1]
    assert open0 > 0.5
    assert abs(B[lm[44], 1] - B[lm[46], 1]) < 0.1 * open0
    assert np.allclose(B[lm[36:42]], V[lm[36:42]])
    # mouthSmileLeft lifts the left corner (54) up and out, not the right one (48)
    S = after("mouthSmileLeft")
    d54 = S[lm[54]] - V[lm[54]]
    assert d54[1] > 0.4 and d54[0] > 0.2
    assert np.linalg.norm(S[lm[48]] - V[lm[48]]) < 0.05
    # browInnerUp raises the inner brows
    Bi = after("browInnerUp")
    assert (Bi[lm[[21, 22]], 1] - V[lm[[21, 22]], 1] > 0.3).all()
    # eyeLookUpLeft turns the eyeball: the mesh's left-eye vertices rotate (move) but keep their size
    E = after("eyeLookUpLeft")
    moved = np.linalg.norm(E - V, axis=1) > 0.2
    assert moved.sum() > 20 and (V[moved, 0] > 0).all()


def test_bo_smiles_broader_than_ada():
    a, b = (make_demo_character(n) for n in CHARACTERS)

    def area(r):
        m = np.linalg.norm(r.deltas[r.index("mouthSmileLeft")], axis=1)
        return (m > 0.1).sum() / r.n_vertices * np.ptp(r.neutral.vertices[:, 0]) * np.ptp(r.neutral.vertices[:, 1])

    assert area(b) > 1.3 * area(a)


def test_vertex_colors():
    for n in CHARACTERS:
        c = demo_vertex_colors(n)
        assert c.shape == (make_demo_character(n).n_vertices, 3)
        assert c.min() >= 0.0 and c.max() <= 1.0
        assert len(np.unique(np.round(c, 2), axis=0)) > 5  # skin, lips, eyes, irises, tongue


def test_take_shape_and_range():
    take = make_demo_take()
    assert take.kind == "weights"
    assert take.names == list(ARKIT_NAMES)
    assert take.weights.shape == (180, 52)
    assert take.fps == 30.0 and take.times[0] == 0.0
    assert abs(take.duration - 179 / 30) < 1e-9
    W = take.weights
    assert W.min() >= 0.0 and W.max() <= 1.0
    col = {n: W[:, i] for i, n in enumerate(ARKIT_NAMES)}
    # talking: the jaw opens and closes many times
    jaw = col["jawOpen"]
    assert jaw.max() > 0.3
    peaks = np.flatnonzero((jaw[1:-1] > jaw[:-2]) & (jaw[1:-1] >= jaw[2:]) & (jaw[1:-1] > 0.15))
    assert len(peaks) >= 10
    assert np.abs(np.diff(jaw)).max() < 0.25  # smooth at 30 fps
    # blinks (both eyes together), a smile and a brow raise
    blink = col["eyeBlinkLeft"]
    closed = blink > 0.9
    assert 2 <= np.count_nonzero(np.diff(closed.astype(int)) == 1) <= 5
    assert np.array_equal(blink, col["eyeBlinkRight"])
    assert col["mouthSmileLeft"].max() > 0.5 and col["browInnerUp"].max() > 0.5
    assert (W.max(axis=0) > 0).sum() >= 30


def test_take_deterministic_and_sized():
    a, b = make_demo_take(), make_demo_take()
    assert np.array_equal(a.weights, b.weights)
    assert not np.array_equal(a.weights, make_demo_take(seed=8).weights)
    short = make_demo_take(seconds=2.0, fps=24)
    assert short.weights.shape == (48, 52) and short.fps == 24.0
    with pytest.raises(InvalidDataError):
        make_demo_take(seconds=0)


def test_take_drives_both_characters():
    take = make_demo_take(seconds=2.0)
    for n in CHARACTERS:
        r = make_demo_character(n)
        V = r.evaluate(r.map_weights(take.names, take.weights))
        assert V.shape == (60, r.n_vertices, 3) and np.isfinite(V).all()
