"""The .glb played by three.js in headless Chromium gives back the written weights and head pose.

``tests/browser/run_three.mjs`` loads the file with three.js's ``GLTFLoader`` in Chromium (through
puppeteer-core), builds an ``AnimationMixer`` for the first clip and reads the face mesh's
``morphTargetInfluences`` and the ``head`` node's quaternion/position at the times asked for.  Needs
node, ``.tools/node_modules/{three,puppeteer-core}`` (``make tools``) and Chromium (``make browser``,
or ``$CHROMIUM``); skips naming what is missing, or fails instead under
``FACERETARGET_REQUIRE_BROWSER=1``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from faceretarget.headpose import HeadPose
from faceretarget.io import (
    read_bvh_head,
    read_glb_head,
    read_glb_weights,
    read_performance,
    write_glb,
    write_glb_head,
)
from faceretarget.names import normalize_name

sys.path.insert(0, str(Path(__file__).parent))
from _browser import CHROMIUM, PUPPETEER_DIR, REPO, THREE_DIR, browser_missing  # noqa: E402

SCRIPT = REPO / "tests" / "browser" / "run_three.mjs"
FRAMES = slice(450, 750)  # 10 s of S07-001 (at 30 fps) whose weights reach 0.94
WEIGHT_TOL = 1e-6  # float32 storage
ANGLE_TOL = 1e-5  # radians


@pytest.fixture(scope="module")
def node() -> str:
    reason = browser_missing("the three.js browser check", three=True)
    if reason:
        if os.environ.get("FACERETARGET_REQUIRE_BROWSER", "") not in ("", "0"):
            pytest.fail(reason)
        pytest.skip(reason)
    return shutil.which("node")


def run_harness(node: str, glb: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, CHROMIUM=str(CHROMIUM), THREE_DIR=str(THREE_DIR), PUPPETEER_CORE_DIR=str(PUPPETEER_DIR))
    return subprocess.run([node, str(SCRIPT), str(glb), "--timeout", "60", *args], capture_output=True,
                          text=True, timeout=90, env=env)


def play(node: str, glb: Path, times: np.ndarray) -> dict:
    """Run the harness on ``glb`` at ``times`` (seconds from the clip's start); its JSON report."""
    tfile = glb.with_suffix(".times.json")
    tfile.write_text(json.dumps([float(t) for t in times]))
    r = run_harness(node, glb, "--times-file", str(tfile))
    assert r.returncode == 0, f"run_three.mjs failed ({r.returncode}) on {glb}: {r.stderr}"
    # GLTFLoader reports what it ignores (e.g. "Invalid extras.targetNames length") on the console
    assert "browser warn" not in r.stderr and "browser error" not in r.stderr, r.stderr
    out = json.loads(r.stdout)
    print(f"three.js r{out['three']} in {out['browser']}: {len(times)} times of {glb.name}")
    return out


def sample_times(t32: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every keyframe time and every midpoint: (times, left frame, fraction towards the next)."""
    t = t32.astype(np.float64)
    mid = 0.5 * (t[:-1] + t[1:])
    times = np.concatenate([t, mid])
    left = np.concatenate([np.arange(t.size), np.arange(t.size - 1)])
    # the last key sits at the end of its interval: left = T - 2, fraction 1 (what three.js does)
    left[t.size - 1] = t.size - 2
    frac = (times - t[left]) / (t[left + 1] - t[left])
    return times, left, frac


def expected_weights(w32: np.ndarray, left: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """LINEAR interpolation of the float32 keys, in float64."""
    w = w32.astype(np.float64)
    return w[left] * (1 - frac[:, None]) + w[left + 1] * frac[:, None]


def expected_quats(q: np.ndarray, t: np.ndarray, times: np.ndarray) -> Rotation:
    return Slerp(t, Rotation.from_quat(q))(times)


def angle_error(q: np.ndarray, ref: Rotation) -> np.ndarray:
    """Angle (radians) of the rotation between ``q`` (x, y, z, w rows) and ``ref``; sign-free."""
    return (Rotation.from_quat(q) * ref.inv()).magnitude()


@pytest.fixture(scope="module")
def take(data_dir):
    return read_performance(data_dir / "livelinkface" / "S07-001.csv")


@pytest.fixture(scope="module")
def head(data_dir) -> HeadPose:
    """300 frames (30 fps) of real head motion with translation: S07-001's head angles are all zero."""
    h = read_bvh_head(data_dir / "headmotion" / "zeggs_067_Speech_2_x_1_0.bvh").head[:300]
    assert h.valid.all() and h.translation is not None and h.rotation.magnitude().max() > 0.5
    return h


def _write_take(tmp_path: Path, rig, take, weights: np.ndarray, head: HeadPose, name: str) -> Path:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*tongueOut")  # the ARKit test rig has no tongueOut
        return write_glb(tmp_path / name, rig, weights, take.times[FRAMES], names=take.names, head=head)


def _check_weights(out: dict, take, weights: np.ndarray, glb: Path) -> float:
    """three.js's influences against the take's weights, by name; the worst error."""
    names, t32, _ = read_glb_weights(glb)
    times, left, frac = sample_times(t32)
    np.testing.assert_array_equal(out["times"], times)
    assert out["face"] == "face" and out["clip"]["name"] == "take"
    assert out["clip"]["duration"] == pytest.approx(float(t32[-1]), abs=0)
    assert sorted(out["names"]) == sorted(names) and len(out["names"]) == 51
    col = {normalize_name(n): j for j, n in enumerate(take.names)}
    cols = [col[normalize_name(n)] for n in out["names"]]
    w32 = weights[:, cols].astype(np.float32)  # what the file stores, in three.js's order
    got = np.asarray(out["influences"])
    assert got.shape == (times.size, 51)
    want = expected_weights(w32, left, frac)
    err = np.abs(got - want)
    T = t32.size
    err64 = np.abs(got[:T] - weights[:, cols]).max()  # against the float64 weights given to the writer
    step = np.abs(want[T:] - w32[left[T:]]).max()  # how far a midpoint is from its left key
    print(f"influences: max error {err[:T].max():.3g} at keyframes ({err64:.3g} against the float64 "
          f"weights), {err[T:].max():.3g} at midpoints (up to {step:.3f} from the keys); range "
          f"{got.min():.3f} .. {got.max():.3f}")
    assert err.max() < WEIGHT_TOL and err64 < WEIGHT_TOL
    assert step > 100 * WEIGHT_TOL  # the midpoints do test the interpolation
    return float(err.max())


def _check_head(out: dict, head: HeadPose, t32: np.ndarray, pivot=(0.0, 0.0, 0.0)) -> float:
    """three.js's head quaternions (slerp between keys) and positions against ``head``; worst angle."""
    pivot = np.asarray(pivot, dtype=np.float64)
    times, left, frac = sample_times(t32)
    q = np.asarray(out["head"]["quaternion"])
    T = t32.size
    err_keys = angle_error(q[:T], head.rotation)
    err_all = angle_error(q, expected_quats(head.as_quat(), t32.astype(np.float64), times))
    step = angle_error(q[T:], head.rotation[np.arange(T - 1)]).max()  # midpoint to its left key
    print(f"head: max angle error {err_keys.max():.3g} rad at keyframes, {err_all[T:].max():.3g} rad "
          f"at midpoints (up to {step:.3g} rad from the keys; rotations up to "
          f"{head.rotation.magnitude().max():.3f} rad)")
    assert err_keys.max() < ANGLE_TOL and err_all.max() < ANGLE_TOL
    assert step > 100 * ANGLE_TOL
    pos = np.asarray(out["head"]["position"])
    if head.translation is None:
        np.testing.assert_allclose(pos, np.broadcast_to(pivot, pos.shape), atol=1e-7)
    else:
        np.testing.assert_allclose(pos[:T], head.translation + pivot, atol=1e-6)  # metres
        want = expected_weights((head.translation + pivot).astype(np.float32), left, frac)
        perr = np.abs(pos - want).max()
        print(f"head position: max error {perr:.3g} m (keys and midpoints)")
        assert perr < 1e-6
    return float(err_all.max())


def test_three_plays_the_written_weights_and_head(node, arkit_rig, take, head, tmp_path):
    w = take.weights[FRAMES]
    glb = _write_take(tmp_path, arkit_rig, take, w, head, "s07.glb")
    out = play(node, glb, sample_times(read_glb_weights(glb)[1])[0])
    assert set(out["clip"]["tracks"]) == {"face.morphTargetInfluences", "head.quaternion", "head.position"}
    _check_weights(out, take, w, glb)
    t32 = read_glb_weights(glb)[1]
    _check_head(out, head, t32)


def test_three_keeps_weights_outside_0_1(node, arkit_rig, take, head, tmp_path):
    w = take.weights[FRAMES] * 1.8 - 0.3
    assert w.min() < -0.25 and w.max() > 1.0
    glb = _write_take(tmp_path, arkit_rig, take, w, head, "wide.glb")
    out = play(node, glb, sample_times(read_glb_weights(glb)[1])[0])
    _check_weights(out, take, w, glb)
    got = np.asarray(out["influences"])
    assert got.min() < -0.25 and got.max() > 1.0  # three.js does not clamp morph influences


def test_three_plays_a_head_only_glb(node, tmp_path):
    T = 120
    times = 2.0 + np.arange(T) / 30.0
    u = np.linspace(0.0, 1.0, T)
    # large turns (yaw up to 150 degrees both ways), nods and tilts, a moving head, a neck pivot
    angles = np.stack([150 * np.sin(2 * np.pi * u), 35 * np.sin(6 * np.pi * u), 20 * np.cos(4 * np.pi * u)], 1)
    translation = np.stack([0.05 * u, 0.02 * np.sin(2 * np.pi * u), -0.03 * u], 1)
    head = HeadPose.from_euler("YXZ", angles, translation, degrees=True, source="synthetic")
    q = head.as_quat()
    q[1::2] *= -1  # same rotations with alternating quaternion signs (the writer aligns them)
    head = HeadPose(q, translation, source="synthetic")
    pivot = np.array([0.0, 1.5, 0.02])
    glb = write_glb_head(tmp_path / "head.glb", times, head, pivot=pivot)
    t32, _ = read_glb_head(glb)
    out = play(node, glb, sample_times(t32)[0])
    assert out["face"] is None and out["influences"] == []
    assert set(out["clip"]["tracks"]) == {"head.quaternion", "head.position"}
    _check_head(out, head, t32, pivot)


def test_harness_reports_a_broken_file(node, tmp_path):
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"glTF not really")
    r = run_harness(node, bad, "--times", "0")
    assert r.returncode == 3 and r.stdout == ""
    assert str(bad) in r.stderr
