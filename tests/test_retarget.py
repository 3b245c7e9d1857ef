"""BlendshapeRetargeter, regions, the consistency check and the retargeting command line (issue 3)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from faceretarget.cli import main
from faceretarget.errors import InvalidDataError, MissingShapeError
from faceretarget.io import read_keyshapes, read_livelinkface, read_npz_performance, write_livelinkface
from faceretarget.mesh import Mesh
from faceretarget.performance import Performance
from faceretarget.retarget import (
    BlendshapeRetargeter,
    Regions,
    check_consistency,
    default_regions,
    load_regions,
)
from faceretarget.rig import Rig


def _grid_rig(n_keys=6, seed=0, name="src"):
    """A 10 x 10 point face (y up) with localised random keyshapes."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(-1, 1, 10), np.linspace(-1, 1, 10))
    V = np.c_[x.ravel(), y.ravel(), np.zeros(100)]
    D = np.zeros((n_keys, 100, 3))
    for k in range(n_keys):
        c = V[rng.integers(100)]
        bump = np.exp(-((V - c) ** 2).sum(axis=1) / 0.3)
        D[k] = bump[:, None] * rng.normal(size=3) * 0.2
    return Rig(Mesh(V), [f"k{k}" for k in range(n_keys)], D, "cm", None, None, name)


def _take(rig, W):
    return W @ rig.deltas.reshape(rig.n_shapes, -1)


def test_signed_and_nnls_recover_exact_weights():
    src, tgt = _grid_rig(seed=1), _grid_rig(seed=2, name="tgt")
    rng = np.random.default_rng(3)
    W = rng.uniform(0, 1, (50, src.n_shapes))
    frames = (_take(src, W).reshape(50, 100, 3) + src.neutral.vertices)
    for solver in ("signed", "nnls"):
        rt = BlendshapeRetargeter(solver, features="all", denoise=False).fit(src, tgt)
        Wh = rt.transform(frames).weights
        assert np.abs(Wh - W).max() < 1e-8
        out = rt.blend(Wh)
        truth = _take(tgt, W).reshape(50, 100, 3) + tgt.neutral.vertices
        assert np.abs(out - truth).max() < 1e-8
    # signed reaches weights of either sign, nnls clips them at 0
    Wn = W - 0.5
    framesn = _take(src, Wn).reshape(50, 100, 3) + src.neutral.vertices
    signed = BlendshapeRetargeter(features="all", denoise=False).fit(src, tgt).transform(framesn).weights
    assert np.abs(signed - Wn).max() < 1e-8
    nn = BlendshapeRetargeter("nnls", features="all", denoise=False).fit(src, tgt).transform(framesn).weights
    assert nn.min() >= 0 and np.abs(nn - Wn).max() > 0.1


def test_missing_markers_are_solved_on_the_markers_present():
    src, tgt = _grid_rig(seed=4), _grid_rig(seed=5, name="tgt")
    rng = np.random.default_rng(6)
    W = rng.uniform(-0.5, 1, (80, src.n_shapes))
    frames = _take(src, W).reshape(80, 100, 3) + src.neutral.vertices
    holes = frames.copy()
    holes[rng.random((80, 100)) < 0.1] = np.nan
    for solver, Wt in (("signed", W), ("nnls", np.maximum(W, 0))):
        f = frames if solver == "signed" else _take(src, Wt).reshape(80, 100, 3) + src.neutral.vertices
        h = f.copy()
        h[np.isnan(holes)] = np.nan
        rt = BlendshapeRetargeter(solver, features="all", denoise=False).fit(src, tgt)
        assert np.abs(rt.transform(h).weights - Wt).max() < 1e-6


def test_denoising_reduces_error_with_noise():
    src, tgt = _grid_rig(seed=7), _grid_rig(seed=8, name="tgt")
    t = np.arange(600) / 60.0
    W = 0.5 + 0.4 * np.sin(2 * np.pi * np.outer(t, np.linspace(0.2, 1.0, src.n_shapes)))
    clean = _take(src, W).reshape(len(t), 100, 3) + src.neutral.vertices
    noisy = clean + np.random.default_rng(9).normal(0, 0.01, clean.shape)
    raw = BlendshapeRetargeter(features="all", denoise=False).fit(src, tgt).transform(noisy, t).weights
    rt = BlendshapeRetargeter(features="all").fit(src, tgt)
    res = rt.transform(noisy, t)
    e_raw, e_den = np.abs(raw - W).mean(), np.abs(res.weights - W).mean()
    assert e_den < 0.5 * e_raw
    assert 0.005 < res.noise_sigma < 0.02                       # the take's own noise, estimated


def test_filter_level_reports_extremes_removed():
    src = _grid_rig(seed=10)
    t = np.arange(300) / 60.0
    W = np.zeros((300, src.n_shapes))
    W[::30, 0] = 1.0                                            # one-frame spikes: all extremes
    frames = _take(src, W).reshape(300, 100, 3) + src.neutral.vertices
    rt = BlendshapeRetargeter(features="all", denoise=False, filter_level=1.0).fit(src, src)
    assert rt.transform(frames, t).extremes_removed > 0.3
    rt0 = BlendshapeRetargeter(features="all", denoise=False).fit(src, src)
    assert rt0.transform(frames, t).extremes_removed == 0.0


def test_regions_partition_of_unity_and_seam_is_smooth():
    src = _grid_rig(seed=11)
    reg = default_regions(src.neutral.vertices)
    rt = BlendshapeRetargeter(features="all", regions=reg, denoise=False).fit(src, src)
    M = rt.regions_.masks_
    assert M.shape == (2, 100)
    assert np.allclose(M.sum(axis=0), 1.0)
    y = src.neutral.vertices[:, 1]
    assert np.allclose(M[0, y >= 0.9], 1.0) and np.allclose(M[1, y <= -0.9], 1.0)
    # along a column of the grid the membership changes by at most one grid step's share
    col = np.argsort(y[::10])
    assert np.abs(np.diff(M[0, ::10][col])).max() < 0.6
    # equal weights in every region give the unsplit blend exactly
    w = np.random.default_rng(0).uniform(0, 1, (5, src.n_shapes))
    whole = BlendshapeRetargeter(features="all", denoise=False).fit(src, src).blend(w)
    assert np.abs(rt.blend(np.hstack([w, w])) - whole).max() < 1e-12
    assert np.allclose(rt.key_weights(np.hstack([w, w])), w)
    assert rt.weight_names_[0] == "k0@upper" and rt.target_keys_.n_shapes == 2 * src.n_shapes


def test_region_solve_keeps_a_mouth_key_out_of_the_brows():
    # two keys: one moves the top half, one the bottom; a take using only the bottom key must not
    # move the top of the target even when the target's bottom key leaks upwards
    V = _grid_rig().neutral.vertices
    top, bottom = (V[:, 1] > 0).astype(float), (V[:, 1] < 0).astype(float)
    D = np.zeros((2, 100, 3))
    D[0, :, 1], D[1, :, 1] = top, bottom
    src = Rig(Mesh(V), ["brow", "jaw"], D, "cm", None, None, "s")
    Dt = D.copy()
    Dt[1, :, 2] = 0.3                                           # target jaw key also pushes everything forward
    tgt = Rig(Mesh(V), ["brow", "jaw"], Dt, "cm", None, None, "t")
    frames = (np.array([[0.0, 1.0]]) @ D.reshape(2, -1)).reshape(1, 100, 3) + V
    reg = Regions({"upper": np.flatnonzero(V[:, 1] > 0).tolist(), "lower": np.flatnonzero(V[:, 1] <= 0).tolist()},
                  {"upper": np.flatnonzero(V[:, 1] > 0).tolist(), "lower": np.flatnonzero(V[:, 1] <= 0).tolist()},
                  width=0.3)
    rt = BlendshapeRetargeter(features="all", regions=reg, denoise=False).fit(src, tgt)
    out = rt.blend(rt.transform(frames).weights)[0]
    far_top = V[:, 1] > 0.5
    assert np.abs(out[far_top] - V[far_top]).max() < 1e-9       # the brow region stays still
    assert np.allclose(out[V[:, 1] < -0.5, 2], 0.3)


def test_regions_file(tmp_path):
    p = tmp_path / "regions.json"
    (tmp_path / "low.txt").write_text("\n".join(map(str, range(50))))
    p.write_text('{"width": 0.5, "regions": {"upper": {"source": [50, 51], "target": [60, 70]}, '
                 '"lower": {"source": [0, 1], "target": "low.txt"}}}')
    reg = load_regions(p)
    assert reg.names == ["upper", "lower"] and reg.target["lower"].size == 50 and reg.width == 0.5
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(Exception, match="bad.json"):
        load_regions(bad)
    with pytest.raises(InvalidDataError, match="belong to no region"):
        Regions({"a": [0]}).resolve(3)


def test_missing_target_key_is_named():
    src, tgt = _grid_rig(seed=1), _grid_rig(seed=2, name="tgt")
    with pytest.raises(MissingShapeError, match="k5"):
        BlendshapeRetargeter().fit(src, tgt.subset(["k0", "k1", "k2", "k3", "k4"]))


def test_consistency_flags_a_bad_key(data_dir, ict_rig):
    from faceretarget.cloning import keymodel_rig, keyset_weights
    from faceretarget.io import read_rig

    ark = read_rig(data_dir / "arkit-face")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rom = read_livelinkface(data_dir / "livelinkface" / "alex_rom_3.csv")
    labels, U, names = keyset_weights("rom-20", ict_rig, rom=rom, selection="pca-extrema")  # has near twins
    sk, tk = keymodel_rig(ict_rig, labels, U, names), keymodel_rig(ark, labels, U, names)
    rep = check_consistency(sk, tk)
    assert not rep.flagged.any()                                # a perfectly consistent artist
    assert rep.checkable.sum() >= 10
    # one key sculpted 2.5x too strong: it disagrees with its near twin
    j = int(np.argmin(rep.source_residual))
    d = tk.deltas.copy()
    d[j] *= 2.5
    bad = Rig(tk.neutral, tk.names, d, tk.unit, tk.landmarks, None, "bad")
    rep2 = check_consistency(sk, bad)
    assert tk.names[j] in rep2.flagged_names
    assert "DISAGREES" in rep2.table() and tk.names[j] in rep2.table()


def test_arkit_keys_retarget_exactly(data_dir, ict_rig):
    from faceretarget.cloning import keymodel_pair
    from faceretarget.io import read_rig
    from faceretarget.metrics import rel_motion_pct

    ark = read_rig(data_dir / "arkit-face")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take = read_livelinkface(data_dir / "livelinkface" / "S07-001.csv").slice(0, 300)
    sk, tk, _ = keymodel_pair(ict_rig, ark, "arkit")
    src = ict_rig.evaluate(ict_rig.map_weights(take.names, take.weights, warn=False))
    gt = ark.evaluate(ark.map_weights(take.names, take.weights, warn=False))
    rt = BlendshapeRetargeter(features="all", denoise=False).fit(sk, tk)
    assert rel_motion_pct(rt.blend(rt.transform(src).weights), gt, ark.neutral.vertices) < 1e-6


def test_cli_keys_select_and_retarget_markers(data_dir, tmp_path):
    keys = tmp_path / "keys"
    rc = main(["-q", "keys", "select", "--performance", str(data_dir / "facial-mocap" / "Jaw.c3d"), "--k", "8",
               "--method", "pca-extrema", "--out", str(keys)])
    assert rc == 0
    assert len(list(keys.glob("frame_*.obj"))) == 8
    assert (keys / "neutral.obj").is_file() and (keys / "markers.txt").is_file() and (keys / "contact_sheet.png").is_file()
    # issue 34: each tile shows its key's motion from the neutral (it showed the same cloud of dots in every tile)
    from PIL import Image

    with Image.open(keys / "contact_sheet.png") as im:
        sheet = np.asarray(im.convert("RGB")).astype(np.int16)
    cell = sheet.shape[1] // 5
    tiles = [sheet[r * (sheet.shape[0] // 2) + 20:(r + 1) * (sheet.shape[0] // 2) - 12, c * cell:(c + 1) * cell]
             for r in range(2) for c in range(min(4, 8 - 5 * r) if r else 5)]
    diffs = [np.abs(a - b).mean() for i, a in enumerate(tiles) for b in tiles[i + 1:] if a.shape == b.shape]
    red = [int(((t[..., 0] > 150) & (t[..., 2] < 120)).sum()) for t in tiles]          # long arrows are red
    assert min(diffs) > 0.05 and max(red) > 20, (min(diffs), red)
    sk = read_keyshapes(keys)
    assert sk.n_shapes == 8
    out = tmp_path / "self.npz"
    rc = main(["-q", "retarget", "--performance", str(data_dir / "facial-mocap" / "Jaw.c3d"), "--source-keys", str(keys),
               "--target-keys", str(keys), "--out", str(out), "--smooth", "0.5"])
    assert rc == 0
    perf = read_npz_performance(out)
    assert perf.vertices.shape[1:] == sk.neutral.vertices.shape
    # a self retarget reproduces the keyshape frames closely (denoised, filtered: not exactly)
    ids = [int(n.split("_")[1]) for n in sk.source_names]
    err = np.abs(perf.vertices[ids] - (sk.deltas + sk.neutral.vertices)).mean()
    motion = np.abs(sk.deltas).mean()
    assert err < 0.35 * motion
    # a missing target keyshape is named, and nothing is written
    tk = tmp_path / "target"
    tk.mkdir()
    for f in list(keys.glob("*.obj"))[:4]:
        (tk / f.name).write_bytes(f.read_bytes())
    (tk / "neutral.obj").write_bytes((keys / "neutral.obj").read_bytes())
    bad = tmp_path / "bad.glb"
    rc = main(["-q", "retarget", "--performance", str(data_dir / "facial-mocap" / "Jaw.c3d"), "--source-keys",
               str(keys), "--target-keys", str(tk), "--out", str(bad)])
    assert rc == 2 and not bad.exists()


def test_cli_retarget_rigs_to_livelinkface_csv(data_dir, tmp_path, capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take = read_livelinkface(data_dir / "livelinkface" / "S07-001.csv").slice(0, 240)
    short = tmp_path / "short.csv"
    write_livelinkface(short, take)
    out = tmp_path / "out.csv"
    rc = main(["-q", "retarget", "--performance", str(short), "--source-keys", str(data_dir / "ict-face"),
               "--target-keys", str(data_dir / "arkit-face"), "--out", str(out), "--no-denoise"])
    assert rc == 0
    got = read_livelinkface(out)
    assert got.n_frames == 240
    # shapes that move the landmarks come back as the input weights
    for n in ("jawOpen", "mouthSmileLeft", "browInnerUp", "mouthPucker"):
        a = got.weights[:, got.names.index(n)]
        b = take.weights[:, take.names.index(n)]
        assert np.abs(a - b).max() < 0.02, n
    # keyshape folders with non-ARKit names and no ARKit definition (key_weights.csv, which `keys select`
    # writes for a weight take; removed here) cannot become a Live Link Face CSV
    rc = main(["-q", "keys", "select", "--performance", str(short), "--source-rig", str(data_dir / "ict-face"),
               "--k", "5", "--method", "pca-extrema", "--out", str(tmp_path / "k")])
    assert rc == 0
    (tmp_path / "k" / "key_weights.csv").unlink()
    bad = tmp_path / "bad.csv"
    rc = main(["-q", "retarget", "--performance", str(short), "--source-rig", str(data_dir / "ict-face"),
               "--source-keys", str(tmp_path / "k"), "--target-keys", str(tmp_path / "k"), "--out", str(bad)])
    assert rc == 2 and not bad.exists()
    assert "neither ARKit shapes nor defined by ARKit weight vectors" in capsys.readouterr().err


def test_weight_take_without_rig_is_refused():
    src = _grid_rig()
    perf = Performance.from_weights(np.zeros((3, 2)), ["a", "b"], fps=30)
    with pytest.raises(InvalidDataError, match="source rig"):
        BlendshapeRetargeter().fit(src, src).transform(perf)


def test_2d_landmark_tracks_retarget_through_flat_keyshapes(tmp_path):
    rng = np.random.default_rng(12)
    P, T = 30, 200
    rest = rng.uniform(-1, 1, (P, 2))
    modes = rng.normal(size=(4, P, 2)) * 0.1
    W = np.abs(np.sin(np.outer(np.arange(T) / 30.0, [0.7, 1.1, 1.9, 2.3])))
    pts = rest + np.einsum("tk,kpd->tpd", W, modes)
    perf = Performance.from_points(pts, [f"m{i}" for i in range(P)], fps=30)
    keys = tmp_path / "keys"
    from faceretarget.io import write_keyshapes
    from faceretarget.numerics import pivoted_qr

    X = (pts - pts[0]).reshape(T, -1)
    frames = sorted(pivoted_qr(X, 6).tolist())
    flat0 = np.c_[pts[0], np.zeros(P)]
    write_keyshapes(perf, frames, keys, neutral=flat0)
    sk = read_keyshapes(keys)
    rt = BlendshapeRetargeter(denoise=False, weight_range=None).fit(sk, sk)
    out = rt.blend(rt.transform(perf).weights)
    assert out.shape == (T, P, 3) and np.abs(out[..., 2]).max() == 0
    assert np.abs(out[..., :2] - pts).max() < 1e-8             # the take lies in the keys' span: exact
    W = BlendshapeRetargeter(denoise=False).fit(sk, sk).transform(perf).weights   # default example range
    assert W.min() >= -1.0 and W.max() <= 2.0


def test_cli_retarget_with_regions_writes_a_valid_glb(data_dir, tmp_path):
    from faceretarget.io import read_glb_weights
    from test_io_gltf import validate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take = read_livelinkface(data_dir / "livelinkface" / "apfel.csv").slice(0, 120)
    short = tmp_path / "short.csv"
    write_livelinkface(short, take)
    out = tmp_path / "regions.glb"
    rc = main(["-q", "retarget", "--performance", str(short), "--source-keys", str(data_dir / "ict-face"),
               "--target-keys", str(data_dir / "arkit-face"), "--regions", "upper-lower", "--out", str(out)])
    assert rc == 0
    names, times, W = read_glb_weights(out)
    assert W.shape == (120, len(names)) and len(names) % 2 == 0
    assert any(n.endswith("@upper") for n in names) and any(n.endswith("@lower") for n in names)
    assert validate(out)["issues"]["numErrors"] == 0
