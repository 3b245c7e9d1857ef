"""P11 (issue 32): the fidelity metrics on cases with known answers, and a short round trip of a real ARKit take
rendered on a character and captured back (bench/fidelity.py's pieces)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import REPO
from faceretarget.metrics import _fidelity as F

sys.path.insert(0, str(REPO / "bench"))


def _toy():
    """Six shapes on 40 vertices: jawOpen and mouthSmileLeft move 0-9, eyeBlinkLeft 10-19, browInnerUp 20-29,
    cheekPuff 30-39, and mouthClose a little of everything (it must not steal a region)."""
    names = ["jawOpen", "mouthSmileLeft", "eyeBlinkLeft", "browInnerUp", "cheekPuff", "mouthClose"]
    D = np.zeros((6, 40, 3))
    D[0, :10, 1] = -1.0
    D[1, :10, 0] = 0.5
    D[1, :10, 1] = 0.5
    D[2, 10:20, 1] = -0.8
    D[3, 20:30, 1] = 0.6
    D[4, 30:40, 2] = 0.4
    D[5, :, 2] = 0.01
    return names, D


def test_regions_come_from_the_shapes_own_displacement():
    names, D = _toy()
    reg = F.face_regions(D, names)
    assert reg["mouth"].tolist() == list(range(10)) and reg["lids"].tolist() == list(range(10, 20))
    assert reg["brows"].tolist() == list(range(20, 30)) and reg["cheeks"].tolist() == list(range(30, 40))


def test_region_error_is_a_share_of_the_true_motion():
    names, D = _toy()
    reg = F.face_regions(D, names)
    rng = np.random.default_rng(0)
    Wt = rng.uniform(0, 1, (50, 6))
    assert all(v == pytest.approx(0.0, abs=1e-9) for v in F.region_errors(Wt, Wt, D, reg).values())
    assert all(v == pytest.approx(100.0) for v in F.region_errors(Wt, 0 * Wt, D, reg).values())
    assert all(v == pytest.approx(100.0) for v in F.region_errors(Wt, 2 * Wt, D, reg).values())
    half = Wt.copy()
    half[:, 2] *= 0.5                                       # the blink at half its size: 50 % off in the lids
    e = F.region_errors(Wt, half, D, reg)
    assert e["lids"] == pytest.approx(50.0, abs=1.0) and e["mouth"] < 1.0
    # a prediction on shapes of its own (bench/own_shapes.py): the blink as two half-size shapes at weight 1
    own = np.concatenate([np.delete(D, 2, axis=0), 0.5 * D[2:3], 0.5 * D[2:3]])
    Wo = np.concatenate([np.delete(Wt, 2, axis=1), Wt[:, 2:3], Wt[:, 2:3]], axis=1)
    assert all(v == pytest.approx(0.0, abs=1e-9) for v in F.region_errors(Wt, Wo, D, reg, pred_deltas=own).values())
    assert F.region_errors(Wt, Wo[:, :-1], D, reg, pred_deltas=own[:-1])["lids"] == pytest.approx(50.0, abs=1.0)
    with pytest.raises(ValueError, match="for 7"):
        F.region_errors(Wt, Wt, D, reg, pred_deltas=own)


def test_blink_f1_smile_direction_and_head_error():
    names, D = _toy()
    Wt = np.zeros((10, 6))
    Wt[2:5, 2] = 0.9                                        # a blink of 3 frames (left eye only in this rig)
    Wp = np.zeros((10, 6))
    Wp[3:6, 2] = 0.7                                        # found one frame late
    b = F.blink_f1(Wt, Wp, names)
    assert b["f1"] == pytest.approx(2 * 2 / (2 * 2 + 1 + 1)) and b["closed_frames"] == 3
    corners = np.stack([D[:, 0], D[:, 9]], axis=1)          # (K, 2, 3): two vertices of the mouth
    smile = np.zeros((4, 6))
    smile[:, 1] = 0.6
    grimace = np.zeros((4, 6))
    grimace[:, 0] = 0.6                                     # the jaw drops instead: corners go down
    up = [0.0, 1.0, 0.0]
    assert F.smile_direction(smile, smile, names, corners, up)["share"] == 1.0
    assert F.smile_direction(smile, grimace, names, corners, up)["share"] == 0.0
    assert np.isnan(F.smile_direction(grimace, smile, names, corners, up)["share"])   # no true smile frame
    yaw = np.radians(np.r_[np.zeros(5), np.full(5, 10.0)])
    qt = Rotation.from_euler("y", yaw[:, None]).as_quat()
    offset = Rotation.from_euler("x", 20, degrees=True)      # another rest pose: does not count
    qp = (offset * Rotation.from_quat(qt)).as_quat()
    assert np.nanmax(F.head_rotation_error(qt, qp)) < 1e-6
    still = np.tile([0.0, 0.0, 0.0, 1.0], (10, 1))
    assert np.median(F.head_rotation_error(qt, still)) == pytest.approx(5.0, abs=0.01)


def test_round_trip_of_a_real_take_on_a_character(data_dir, tmp_path):
    """Two seconds of a real Live Link Face take on arkit-face, rendered, captured back: the main job follows the
    jaw and scores against the truth with every P11 figure, beside the peer on the same frames."""
    pytest.importorskip("mediapipe")
    import fidelity as bench
    from faceretarget.io import read_livelinkface
    from faceretarget.pipelines import animate, capture_take

    target = bench.Target(data_dir / "arkit-face")
    assert {"mouth", "lids", "brows", "cheeks"} <= {k for k, v in target.regions.items() if len(v) > 50}
    perf = read_livelinkface(data_dir / "livelinkface" / "MySlate_3_Jason_Millers_iPhone.csv")
    s0, s1 = bench.active_window(perf.weights, perf.times, 2.0)
    t = np.arange(s0, s1, 1 / bench.FPS)
    W = np.clip(bench.resample(perf.weights, perf.times, t), 0, 1)
    head = bench.head_truth(data_dir / "headmotion" / "zeggs_067_Speech_2_x_1_0.bvh", len(t))
    video = tmp_path / "take.mp4"
    assert bench.render_video(target, target.weights(W, perf.names), head, "webcam", video, size=384) == len(t)
    cap = capture_take(video, neutral_percentile=5.0)
    assert cap.detected.mean() > 0.95
    res = animate(cap, target.character)
    from faceretarget.capture import track_video

    raw = track_video(video)                               # the raw peer: the tracker's scores copied straight
    r = bench.run_one(target, target, cap, res, W, perf.names, head, raw=raw)
    assert r["frames"] == len(t)
    for who in ("ours", "peer", "peer_raw"):
        assert set(r[who]["regions"]) == {"mouth", "lids", "brows", "cheeks"}
        assert np.isfinite(r[who]["head_deg"])
    print({k: (round(r["ours"]["regions"][k], 1), round(r["peer"]["regions"][k], 1)) for k in r["ours"]["regions"]},
          r["ours"]["head_deg"], r["peer"]["head_deg"])
    assert r["ours"]["shapes"]["jawOpen"]["corr"] > 0.8
    assert r["ours"]["regions"]["mouth"] < 80.0             # measured 59 % on this take's 5 s (the peer 55 %)
    assert r["ours"]["head_deg"] < 5.0                      # the real head motion is followed
    # the raw peer: the same scores without the take's neutral removed or smoothing (measured within 1.2 points
    # of the capture's on these 2 s; over P11's 40 runs, ours / raw: mouth 0.91x, lids 0.93x)
    print("raw peer", {k: round(v, 1) for k, v in r["peer_raw"]["regions"].items()})
    assert r["ratio_raw"]["regions"]["mouth"] == pytest.approx(r["ours"]["regions"]["mouth"]
                                                               / r["peer_raw"]["regions"]["mouth"])
    # the live mode on the same video, after its 1 s calibration, beside MediaPipe's raw scores on those frames
    lv = bench.run_live(target, target, video, raw, W, perf.names, head)
    print("live", {k: (round(lv["ours"]["regions"][k], 1), round(lv["peer"]["regions"][k], 1))
                   for k in lv["ours"]["regions"]}, lv["frames"], lv["ours"]["shapes"]["jawOpen"]["corr"])
    assert len(t) - 1.2 * bench.FPS <= lv["frames"] <= len(t) - 0.8 * bench.FPS
    assert lv["ours"]["shapes"]["jawOpen"]["corr"] > 0.6       # measured 0.75 on its 29 frames
    assert lv["ours"]["regions"]["mouth"] < 80.0                # measured 51 % (raw scores 49 %)
