"""Emotion/viseme tables and key-model composition (Pyun et al. 2003, Sec. 2 and Appendix)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from faceretarget.cloning import (
    EMOTIONS,
    VISEMES,
    combined_weight_vectors,
    emotion_vectors,
    table_shapes,
    viseme_vectors,
    weight_vector,
)
from faceretarget.cloning._composition import (
    blend_weight,
    build_key_models,
    compose_displacements,
    compose_key_models,
    propagate_importance,
    raw_importance,
    vertex_importance,
)
from faceretarget.errors import InvalidDataError, MissingShapeError, TopologyError
from faceretarget.mesh import Mesh
from faceretarget.names import ARKIT_NAMES, is_arkit
from faceretarget.rig import Rig

EMOTION_ORDER = ["neutral", "happy", "sad", "surprised", "afraid", "angry"]
VISEME_ORDER = ["PP", "FF", "TH", "DD", "kk", "CH", "SS", "RR", "aa", "E", "I", "O", "U"]


# ---------------------------------------------------------------------------------------------- tables
def test_tables_have_pyuns_six_emotions_and_thirteen_visemes():
    assert list(EMOTIONS) == EMOTION_ORDER
    assert list(VISEMES) == VISEME_ORDER
    assert EMOTIONS["neutral"] == {}


@pytest.mark.parametrize("table", [EMOTIONS, VISEMES], ids=["emotions", "visemes"])
def test_table_weights_are_arkit_in_unit_range_and_symmetric(table):
    for label, entry in table.items():
        for shape, w in entry.items():
            assert is_arkit(shape), f"{label}: {shape}"
            assert 0.0 < w <= 1.0, f"{label}: {shape}={w}"
            for a, b in (("Left", "Right"), ("Right", "Left")):
                if shape.endswith(a):
                    twin = shape[: -len(a)] + b
                    assert entry.get(twin) == w, f"{label}: {shape}={w} but {twin}={entry.get(twin)}"


def test_emotions_carry_their_facs_prototype_shapes():
    assert EMOTIONS["happy"]["mouthSmileLeft"] == 0.8 and EMOTIONS["happy"]["cheekSquintLeft"] == 0.6  # AU12, AU6
    assert {"browInnerUp", "mouthFrownLeft", "mouthShrugLower"} <= set(EMOTIONS["sad"])  # AU1, 15, 17
    assert {"browInnerUp", "browOuterUpLeft", "eyeWideLeft", "jawOpen"} <= set(EMOTIONS["surprised"])
    assert {"browDownLeft", "eyeWideLeft", "mouthStretchLeft", "jawOpen"} <= set(EMOTIONS["afraid"])
    assert {"browDownLeft", "eyeSquintLeft", "mouthPressLeft"} <= set(EMOTIONS["angry"])  # AU4, 7, 24
    # fear opens the eyes wider than (slight, 5B) surprise
    assert EMOTIONS["afraid"]["eyeWideLeft"] > EMOTIONS["surprised"]["eyeWideLeft"]


def test_visemes_use_only_mouth_jaw_cheek_shapes_and_are_distinct():
    for label, entry in VISEMES.items():
        assert entry, label
        assert all(s.startswith(("mouth", "jaw", "cheek")) for s in entry), label
    _, W = viseme_vectors(ARKIT_NAMES)
    d = np.linalg.norm(W[:, None] - W[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() > 0.1
    assert VISEMES["aa"]["jawOpen"] == max(v.get("jawOpen", 0) for v in VISEMES.values())
    assert VISEMES["U"]["mouthPucker"] == max(v.get("mouthPucker", 0) for v in VISEMES.values())


def test_weight_vector_maps_spellings_halves_and_names_unknown_shapes():
    w = weight_vector({"jawOpen": 0.5, "eyeBlink_L": 1.0}, ["eyeBlinkLeft", "jawOpen", "mouthClose"])
    np.testing.assert_array_equal(w, [1.0, 0.5, 0.0])
    w = weight_vector({"browInnerUp": 0.7}, ["browInnerUp_L", "browInnerUp_R", "jawOpen"])
    np.testing.assert_array_equal(w, [0.7, 0.7, 0.0])
    with pytest.raises(KeyError) as exc:
        weight_vector({"jawOpen": 0.5, "mouthClose": 0.1, "cheekPuff": 1.0}, ["jawOpen"])
    assert isinstance(exc.value, MissingShapeError)
    assert "mouthClose" in str(exc.value) and "cheekPuff" in str(exc.value)


def test_emotion_and_viseme_vectors():
    labels, E = emotion_vectors(ARKIT_NAMES)
    assert labels == EMOTION_ORDER and E.shape == (6, 52)
    np.testing.assert_array_equal(E[0], 0.0)
    assert E[1, ARKIT_NAMES.index("mouthSmileRight")] == 0.8
    labels, V = viseme_vectors(ARKIT_NAMES)
    assert labels == VISEME_ORDER and V.shape == (13, 52)
    assert V[8, ARKIT_NAMES.index("jawOpen")] == 0.6  # aa


def test_combined84_shape_labels_and_clipping():
    labels, W = combined_weight_vectors(ARKIT_NAMES)
    assert W.shape == (84, 52) and len(labels) == 84
    assert labels[0] == "neutral+PP" and labels[13 + 8] == "happy+aa" and labels[77] == "angry+U"
    assert labels[78:] == EMOTION_ORDER
    assert W.min() >= 0.0 and W.max() <= 1.0
    _, E = emotion_vectors(ARKIT_NAMES)
    _, V = viseme_vectors(ARKIT_NAMES)
    np.testing.assert_array_equal(W[78:], E)
    np.testing.assert_array_equal(W[:13], V)  # neutral + viseme = the pure viseme
    # happy (smile 0.8) + I (smile 0.3) = 1.1, clipped to 1; jawOpen 0 + 0.15 stays 0.15
    row = W[labels.index("happy+I")]
    assert row[ARKIT_NAMES.index("mouthSmileLeft")] == 1.0
    assert row[ARKIT_NAMES.index("jawOpen")] == pytest.approx(0.15)
    # surprised (jaw 0.3) + aa (jaw 0.6) = 0.9 is not clipped
    assert W[labels.index("surprised+aa"), ARKIT_NAMES.index("jawOpen")] == pytest.approx(0.9)
    assert len({tuple(r) for r in W}) == 84  # no duplicate key-models


def test_table_shapes_are_the_used_arkit_shapes():
    shapes = table_shapes()
    assert "browInnerUp" in shapes and "mouthClose" in shapes and "tongueOut" not in shapes
    assert all(is_arkit(s) for s in shapes)


# ---------------------------------------------------------------------------------------------- importance
def test_raw_importance_is_max_displacement_normalised():
    d = np.zeros((2, 4, 3))
    d[0, :, 0] = [0.0, 1.0, 2.0, 0.5]
    d[1, :, 1] = [4.0, 0.0, 1.0, 0.0]
    np.testing.assert_allclose(raw_importance(d), [1.0, 0.25, 0.5, 0.125])
    np.testing.assert_array_equal(raw_importance(np.zeros((3, 5, 3))), 0.0)


def _line(n: int) -> np.ndarray:
    x = np.zeros((n, 3))
    x[:, 0] = np.arange(n)
    return x


def test_propagation_on_a_line_matches_hand_computed_values():
    raw = np.array([0.4, 0, 0, 0, 0, 1.0, 0, 0, 0.6, 0, 0])
    p = propagate_importance(raw, _line(11), 3.0, threshold=0.5)
    # seeds: vertex 5 (1.0) and vertex 8 (0.6); vertex 0 (0.4) is below S1 and does not spread.
    # p_i = max(raw_i, 1.0 (1 - |i - 5| / 3), 0.6 (1 - |i - 8| / 3))
    expect = [0.4, 0, 0, 1 / 3, 2 / 3, 1.0, 2 / 3, 0.4, 0.6, 0.4, 0.2]
    np.testing.assert_allclose(p, expect, atol=1e-12)
    np.testing.assert_array_equal(propagate_importance(raw, _line(11), 0.0), raw)  # radius 0: no spreading


def test_propagation_geodesic_follows_edges():
    # a 3 x 3 grid of unit quads; seed at the corner (0, 0).  Edge paths have no diagonals, so the
    # centre (1, 1) is 2 away along edges but sqrt(2) away in a straight line.
    g = np.array([(i, j, 0.0) for j in range(3) for i in range(3)])
    quads = [[j * 3 + i, j * 3 + i + 1, (j + 1) * 3 + i + 1, (j + 1) * 3 + i] for j in range(2) for i in range(2)]
    mesh = Mesh.from_triangles(g, np.array(quads))
    raw = np.zeros(9)
    raw[0] = 1.0
    geo = propagate_importance(raw, g, 3.0, mesh=mesh, distance="geodesic")
    euc = propagate_importance(raw, g, 3.0, mesh=mesh, distance="euclidean")
    assert geo[4] == pytest.approx(1 - 2 / 3)
    assert euc[4] == pytest.approx(1 - np.sqrt(2) / 3)
    assert geo[1] == pytest.approx(2 / 3) and euc[1] == pytest.approx(2 / 3)
    assert geo[8] == 0.0 and euc[8] == pytest.approx(1 - np.sqrt(8) / 3)
    with pytest.raises(InvalidDataError, match="geodesic"):
        propagate_importance(raw, g, 3.0, distance="geodesic")


def test_vertex_importance_radius_is_a_fraction_of_the_bbox_diagonal():
    x = _line(11)  # diagonal 10
    d = np.zeros((1, 11, 3))
    d[0, 5, 2] = 2.0
    p, p1 = vertex_importance(d, x, radius=0.3, threshold=0.5)  # L = 3
    np.testing.assert_allclose(p1[5], 1.0)
    np.testing.assert_allclose(p[3:8], [1 / 3, 2 / 3, 1.0, 2 / 3, 1 / 3], atol=1e-12)
    assert p[2] == 0.0 and p[8] == 0.0


def test_blend_weight_ramp():
    p = np.array([1.0, 0.3, 0.25, 0.35, 0.2, 0.4, 1.0])
    e = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0])
    np.testing.assert_allclose(blend_weight(p, e), [1.0, 0.5, 0.0, 1.0, 0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_array_equal(blend_weight(p, e, width=0.0), [1, 0, 0, 1, 0, 1, 0])
    # smoothstep: a quarter of the way up the ramp (m = 0.275) beta = 3/16 - 2/64 = 0.15625
    assert blend_weight(np.array([0.275]), np.array([1.0]))[0] == pytest.approx(0.15625)


# ---------------------------------------------------------------------------------------------- composition
def _unit_rows(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_perpendicular_rule_keeps_lip_sync_where_both_importances_are_one():
    rng = np.random.default_rng(0)
    V = 50
    x = rng.normal(size=(V, 3))
    # every vertex moves by the same length in every key-model, so p1 = e1 = 1 everywhere
    dp = 0.7 * _unit_rows(rng, V)[None]
    de = 1.3 * _unit_rows(rng, V)[None]
    out, imp = compose_key_models(x, de, dp, return_importance=True)
    assert out.shape == (1, V, 3)
    np.testing.assert_allclose(imp.viseme, 1.0, rtol=1e-12)
    np.testing.assert_allclose(imp.emotion, 1.0, rtol=1e-12)
    np.testing.assert_array_equal(imp.beta, 1.0)
    u = dp[0] / np.linalg.norm(dp[0], axis=1, keepdims=True)
    along = np.sum(out[0] * u, axis=1)
    np.testing.assert_allclose(along, 0.7, rtol=0, atol=1e-13)  # |d_p|: lip sync preserved exactly
    perp = out[0] - along[:, None] * u
    de_perp = de[0] - np.sum(de[0] * u, axis=1, keepdims=True) * u
    np.testing.assert_allclose(perp, de_perp, rtol=0, atol=1e-13)
    # plain superposition would have moved along d_p by |d_p| + d_e . u
    assert np.abs(np.sum(de[0] * u, axis=1)).max() > 0.5


def test_composite_is_superposition_where_emotion_is_unimportant():
    rng = np.random.default_rng(1)
    V = 40
    x = _line(V)
    dp = 0.5 * _unit_rows(rng, V)[None]
    de = _unit_rows(rng, V)[None].copy()
    low = np.arange(20, 30)
    de[0, low] *= 0.1  # e = 0.1 < S2 - w/2 = 0.25: emotion unimportant there
    de[0, 30:] *= 0.3  # e = 0.3 = S2: half-way up the ramp
    out, imp = compose_key_models(x, de, dp, viseme_radius=0.0, emotion_radius=0.0, return_importance=True)
    np.testing.assert_allclose(imp.emotion[low], 0.1)
    np.testing.assert_array_equal(imp.beta[low], 0.0)
    np.testing.assert_array_equal(out[0, low], dp[0, low] + de[0, low])
    np.testing.assert_allclose(imp.beta[30:], 0.5)
    u = dp[0, 30:] / 0.5
    half = dp[0, 30:] + de[0, 30:] - 0.5 * np.sum(de[0, 30:] * u, axis=1, keepdims=True) * u
    np.testing.assert_allclose(out[0, 30:], half, atol=1e-13)


def test_compose_order_neutral_emotion_and_tiny_viseme_motion():
    rng = np.random.default_rng(2)
    V = 30
    x = rng.normal(size=(V, 3))
    de = np.stack([np.zeros((V, 3)), _unit_rows(rng, V)])  # neutral, one emotion
    dp = np.stack([_unit_rows(rng, V), 2.0 * _unit_rows(rng, V), 0.5 * _unit_rows(rng, V)])
    out = compose_key_models(x, de, dp)
    assert out.shape == (6, V, 3)
    np.testing.assert_array_equal(out[:3], dp)  # neutral + viseme = the viseme
    # a viseme that leaves a vertex (nearly) still: its direction is noise, so plain superposition
    dp2 = dp.copy()
    dp2[:, 0] = [1e-9, 0.0, 0.0]
    out2 = compose_key_models(x, de, dp2)
    np.testing.assert_allclose(out2[3:, 0], de[1, 0] + dp2[:, 0], atol=1e-15)
    with pytest.raises(TopologyError):
        compose_key_models(x, de[:, :-1], dp)


def test_compose_displacements_broadcasts_with_beta():
    de = np.array([[[1.0, 1.0, 0.0]]])
    dp = np.array([[[2.0, 0.0, 0.0]]])
    np.testing.assert_allclose(compose_displacements(de, dp, np.array([1.0])), [[[2.0, 1.0, 0.0]]])
    np.testing.assert_allclose(compose_displacements(de, dp, np.array([0.0])), [[[3.0, 1.0, 0.0]]])
    np.testing.assert_allclose(compose_displacements(de, dp, np.array([0.25])), [[[2.75, 1.0, 0.0]]])


def _toy_rig(names):
    rng = np.random.default_rng(3)
    x = rng.normal(size=(20, 3))
    return Rig(Mesh(x), list(names), 0.1 * rng.normal(size=(len(names), 20, 3)), name="toy")


def test_build_key_models_on_a_rig_lacking_shapes_warns_once():
    names = [n for n in ARKIT_NAMES if n not in ("mouthClose", "mouthFunnel", "browInnerUp")]
    names = names + ["browInnerUp_L", "browInnerUp_R"]
    rig = _toy_rig(names)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        labels, verts = build_key_models(rig)
    msgs = [str(w.message) for w in caught]
    assert len(msgs) == 1, msgs
    assert "mouthClose" in msgs[0] and "mouthFunnel" in msgs[0] and "browInnerUp" not in msgs[0]
    assert verts.shape == (84, 20, 3)
    assert labels == combined_weight_vectors(ARKIT_NAMES)[0]
    # pure emotions are the rig's own evaluation; sad's browInnerUp drives both halves
    E = rig.map_weights(ARKIT_NAMES, emotion_vectors(ARKIT_NAMES)[1], warn=False)
    np.testing.assert_allclose(verts[78:], rig.evaluate(E), atol=1e-12)
    assert E[2, rig.index("browInnerUp_L")] == 0.7
    full = _toy_rig(ARKIT_NAMES)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        build_key_models(full)  # nothing missing: no warning


# ---------------------------------------------------------------------------------------------- real ICT rig
def _read_obj(path):
    verts, counts, idx = [], [], []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                verts.append(line.split()[1:4])
            elif line.startswith("f "):
                corners = [int(t.split("/")[0]) - 1 for t in line.split()[1:]]
                counts.append(len(corners))
                idx.extend(corners)
    return np.array(verts, dtype=np.float64), counts, idx


def _load_ict(folder):
    try:
        from faceretarget.io import read_rig
    except ImportError:
        read_rig = None
    if read_rig is not None:
        rig = read_rig(folder)
    else:  # private fallback until faceretarget.io lands
        v, counts, idx = _read_obj(folder / "generic_neutral_mesh.obj")
        neutral = Mesh(v, counts, idx, name="ict-face")
        names, deltas = [], []
        for p in sorted(folder.glob("*.obj")):
            if p.name == "generic_neutral_mesh.obj" or p.name.startswith("identity"):
                continue
            names.append(p.stem)
            deltas.append(_read_obj(p)[0] - v)
        rig = Rig(neutral, names, np.array(deltas), name="ict-face")
    landmarks = rig.landmarks
    if landmarks is None:
        landmarks = np.loadtxt(folder / "landmarks68.txt", dtype=np.int64)
    return rig, landmarks


@pytest.fixture(scope="module")
def ict(data_dir):
    rig, landmarks = _load_ict(data_dir / "ict-face")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # ICT has every shape the tables use
        labels, verts, imp = build_key_models(rig, return_importance=True)
    return rig, landmarks, labels, verts, imp


def test_ict_builds_84_key_models(ict):
    rig, _, labels, verts, _ = ict
    assert verts.shape == (84, 9409, 3)
    assert labels == combined_weight_vectors(ARKIT_NAMES)[0]
    assert np.isfinite(verts).all()
    # neutral + viseme and the pure emotions are the rig's own expressions
    V = rig.map_weights(ARKIT_NAMES, viseme_vectors(ARKIT_NAMES)[1], warn=False)
    E = rig.map_weights(ARKIT_NAMES, emotion_vectors(ARKIT_NAMES)[1], warn=False)
    np.testing.assert_allclose(verts[:13], rig.evaluate(V), atol=1e-9)
    np.testing.assert_allclose(verts[78:], rig.evaluate(E), atol=1e-9)
    # all 84 are distinct faces (at least 1 cm apart over the whole mesh)
    flat = verts.reshape(84, -1)
    gram = flat @ flat.T
    sq = np.diag(gram)[:, None] + np.diag(gram)[None] - 2 * gram
    np.fill_diagonal(sq, np.inf)
    assert np.sqrt(sq.min()) > 1.0


def test_ict_mouth_matters_more_to_speech_than_the_forehead(ict):
    rig, lm, _, _, imp = ict
    x = rig.neutral.vertices
    mouth = lm[48:68]
    brow_top = x[lm[17:27], 1].max()
    forehead = np.flatnonzero(x[:, 1] > brow_top + 1.0)  # 1 cm above the brows
    assert forehead.size > 100
    assert imp.viseme[mouth].min() > 0.3
    assert imp.viseme[forehead].max() < 0.05
    assert imp.viseme[mouth].min() > imp.viseme[forehead].max()
    # emotion matters on the forehead (brows raise and lower), speech does not: no blending there
    assert imp.emotion[forehead].max() > 0.3
    assert imp.beta[forehead].max() == 0.0


def test_ict_happy_pp_keeps_lip_closure_along_the_viseme(ict):
    rig, lm, labels, verts, imp = ict
    x = rig.neutral.vertices
    dp = verts[labels.index("neutral+PP")] - x
    de = verts[labels.index("happy")] - x
    comp = verts[labels.index("happy+PP")] - x
    lips = lm[48:68]
    assert (imp.beta[lips] == 1.0).all()
    length = np.linalg.norm(dp[lips], axis=1)
    assert length.min() > 0.01  # the viseme moves every lip landmark (cm)
    u = dp[lips] / length[:, None]
    np.testing.assert_allclose(np.sum(comp[lips] * u, axis=1), length, atol=1e-9)
    de_perp = de[lips] - np.sum(de[lips] * u, axis=1, keepdims=True) * u
    np.testing.assert_allclose(comp[lips] - dp[lips], de_perp, atol=1e-9)
    # plain superposition would not: the smile moves the lips along PP's direction by up to mm
    assert np.abs(np.sum(de[lips] * u, axis=1)).max() > 0.1
    # far from the mouth (brows, eyes) the composite is the plain sum of the two
    upper = np.flatnonzero(imp.beta == 0.0)
    np.testing.assert_allclose(comp[upper], dp[upper] + de[upper], atol=1e-12)
