"""The library side of the Blender extension (issue 26), without Blender: the plain glTF copy Blender's importer
needs, the take routes, the landmark records, the capture's progress callback and the worker's protocol."""

from __future__ import annotations

import io
import json
import os
import pickle
import threading
import time

import numpy as np
import pytest

from faceretarget.errors import InvalidDataError, MissingShapeError
from faceretarget.pipelines.worker import character_parts, read_character_parts


@pytest.fixture(scope="module")
def valid_glb(data_dir):
    p = data_dir / "characters" / "valid" / "Black_M_2_Busi.glb"
    if not p.is_file():
        pytest.skip(f"{p} missing")
    return p


def test_plain_glb_decodes_meshopt_and_keeps_the_character(valid_glb, tmp_path):
    from faceretarget.io import GltfDocument, read_gltf_character, write_plain_glb

    out = write_plain_glb(valid_glb, tmp_path / "plain.glb")
    doc = GltfDocument(out)
    assert "EXT_meshopt_compression" not in doc.json.get("extensionsUsed", [])
    assert not any("EXT_meshopt_compression" in v.get("extensions", {}) for v in doc.json["bufferViews"])
    assert len(doc.json["buffers"]) == 1
    a, b = read_gltf_character(valid_glb), read_gltf_character(out)
    assert [m.name for m in a.meshes] == [m.name for m in b.meshes]
    for ma, mb in zip(a.meshes, b.meshes, strict=True):
        assert np.array_equal(ma.mesh.vertices, mb.mesh.vertices)
        assert np.array_equal(ma.mesh.face_indices, mb.mesh.face_indices)
        assert ma.shape_names == mb.shape_names and np.array_equal(ma.deltas, mb.deltas)
    assert [j.name for j in a.joints] == [j.name for j in b.joints]
    img_a = next(m for m in a.meshes if m.materials and m.materials[0].has_image).materials[0].image
    img_b = next(m for m in b.meshes if m.materials and m.materials[0].has_image).materials[0].image
    assert np.array_equal(img_a, img_b)                    # the WebP textures, byte for byte
    with pytest.raises(Exception, match="input file|another name"):
        write_plain_glb(out, out)


def test_landmark_points_reads_68_labelled_points():
    from faceretarget.performance import Performance
    from faceretarget.pipelines import landmark_points

    rng = np.random.default_rng(0)
    P = rng.normal(size=(3, 68, 3))
    order = rng.permutation(68)
    perf = Performance(np.arange(3) / 30, 30.0, points=P[:, order], labels=[f"lm{i}" for i in order])
    assert np.array_equal(landmark_points(perf), P)
    assert np.array_equal(landmark_points(Performance(np.arange(3) / 30, 30.0, points=P)), P)
    other = Performance(np.arange(3) / 30, 30.0, points=P, labels=[f"M{i:03d}" for i in range(68)])
    assert landmark_points(other) is None


@pytest.fixture(scope="module")
def arkit_character(arkit_rig):
    from faceretarget.io import character_from_rig

    return character_from_rig(arkit_rig)


def test_apply_take_clone_route_is_the_clone_command(arkit_character, data_dir):
    from faceretarget.characters import character_weights, drive_rig
    from faceretarget.cloning import keymodel_pair
    from faceretarget.datasets import make_demo_character
    from faceretarget.io import read_performance
    from faceretarget.pipelines import apply_take, arkit_curves, clone_take

    take = read_performance(data_dir / "livelinkface" / "MySlate_3_Jason_Millers_iPhone.csv").slice(0, 60)
    res = apply_take(take, arkit_character)
    assert res.route == "clone" and res.weights.shape == (60, 51)
    drive = drive_rig(arkit_character, "arkit", need_landmarks=False)
    src = make_demo_character("ada")
    sk, tk, _ = keymodel_pair(src, drive.rig, "arkit")
    W, names = arkit_curves(clone_take(take, sk, tk, source_rig=src))
    assert np.array_equal(res.weights, character_weights(drive, W, names))
    # the jaw follows the take's jawOpen (the clone's own accuracy is P1's business, docs/cloning.md)
    j = [c.name for c in drive.channels].index("jawOpen")
    k = take.names.index("jawOpen") if "jawOpen" in take.names else [n.lower() for n in take.names].index("jawopen")
    assert np.corrcoef(res.weights[:, j], take.weights[:, k])[0, 1] > 0.9


def test_apply_take_refuses_what_a_route_cannot_do(arkit_character, data_dir):
    from faceretarget.io import read_performance
    from faceretarget.performance import Performance
    from faceretarget.pipelines import apply_take

    take = read_performance(data_dir / "livelinkface" / "MySlate_3_Jason_Millers_iPhone.csv").slice(0, 5)
    with pytest.raises(InvalidDataError, match="route must be one of"):
        apply_take(take, arkit_character, route="magic")
    with pytest.raises(InvalidDataError, match="retarget route takes points"):
        apply_take(take, arkit_character, route="retarget")
    markers = Performance(np.arange(4) / 30, 30.0, points=np.zeros((4, 41, 3)), labels=[f"M{i}" for i in range(41)])
    with pytest.raises(InvalidDataError, match="41 points are not the 68 face landmarks.*source keys"):
        apply_take(markers, arkit_character)
    with pytest.raises(InvalidDataError, match="clone route takes a weight take"):
        apply_take(markers, arkit_character, route="clone")


def test_clone_route_on_a_character_without_arkit_shapes_names_it(arkit_rig):
    from faceretarget.io import character_from_rig
    from faceretarget.pipelines import apply_take
    from faceretarget.rig import Rig

    names = [f"shape{i}" for i in range(arkit_rig.n_shapes)]
    plain = character_from_rig(Rig(arkit_rig.neutral, names, arkit_rig.deltas, unit=arkit_rig.unit,
                                   landmarks=arkit_rig.landmarks, name="plain"))
    from faceretarget.performance import Performance

    take = Performance.from_weights(np.zeros((3, 2)), ["jawOpen", "eyeBlinkLeft"], times=np.arange(3) / 30)
    with pytest.raises(MissingShapeError, match="plain: fewer than 10 ARKit-named shapes"):
        apply_take(take, plain, route="clone")


def test_landmark_record_round_trip_and_refusal(arkit_character):
    from faceretarget.characters import apply_landmark_record, landmark_record, mesh_sha256

    rec = landmark_record(arkit_character)
    assert rec["sha256"] == mesh_sha256(arkit_character.meshes[0].mesh) and len(rec["triangles"]) == 68
    again = pickle.loads(pickle.dumps(arkit_character))
    again.landmarks = None
    assert apply_landmark_record(again, json.loads(json.dumps(rec)))
    assert np.allclose(again.landmark_positions(), arkit_character.landmark_positions())
    moved = pickle.loads(pickle.dumps(arkit_character))
    moved.landmarks = None
    moved.meshes[0].mesh.vertices[0] += 0.001              # another face: the record is not used
    assert not apply_landmark_record(moved, rec) and moved.landmarks is None


def test_character_parts_round_trip_and_refuse_a_torn_file(arkit_character):
    """The character file the extension writes for the worker: a header, the pickle (arrays out of band, so that
    pickling copies none of them on Blender's main thread) and each array's bytes; read back equal, and a file
    cut short refused by name."""
    parts = character_parts(arkit_character)
    big = max(memoryview(p).nbytes for p in parts[2:])
    assert memoryview(parts[1]).nbytes < big            # the pickle holds no array's bytes
    data = b"".join(bytes(p) for p in parts)
    back = read_character_parts(data)
    for a, b in zip(arkit_character.meshes, back.meshes, strict=True):
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices) and np.array_equal(a.deltas, b.deltas)
        assert a.shape_names == b.shape_names
    assert np.allclose(back.landmark_positions(), arkit_character.landmark_positions())
    with pytest.raises(InvalidDataError, match="written incompletely"):
        read_character_parts(data[:-10])


def test_capture_progress_calls_back_every_frame(data_dir):
    pytest.importorskip("mediapipe", reason="the capture extra")
    from faceretarget.capture import track_video

    calls = []
    cap = track_video(data_dir / "video" / "WDA_AOC_000.mp4", max_frames=6, audio=False,
                      progress=lambda done, total: calls.append((done, total)))
    assert cap.n_frames == 6 and calls == [(i, 6) for i in range(1, 7)]


def _serve(requests: list[dict]) -> list[dict]:
    """Run the worker on in-memory pipes: the answers it writes."""
    from faceretarget.pipelines import serve_jobs

    inp = io.StringIO("".join(json.dumps(r) + "\n" for r in requests))
    out = io.StringIO()
    serve_jobs(inp, out)
    return [json.loads(line) for line in out.getvalue().splitlines()]


def test_worker_runs_a_take_job_and_reports_errors_in_one_line(arkit_character, data_dir, tmp_path, monkeypatch):
    from faceretarget.pipelines import apply_take

    monkeypatch.setenv("FACERETARGET_CACHE", str(tmp_path / "cache"))
    ch = tmp_path / "character.pkl"
    ch.write_bytes(b"".join(bytes(p) for p in character_parts(arkit_character)))
    take = data_dir / "livelinkface" / "MySlate_3_Jason_Millers_iPhone.csv"
    params = {"character": str(ch), "landmarks": None, "take": str(take), "route": "landmarks"}
    msgs = _serve([{"id": 1, "kind": "take", "dir": str(tmp_path), "params": params},
                   {"id": 2, "kind": "take", "dir": str(tmp_path), "params": {**params, "take": str(tmp_path / "no.csv")}},
                   {"id": 3, "kind": "nonsense", "dir": str(tmp_path), "params": {}},
                   {"quit": True}])
    assert msgs[0]["id"] == 0 and "ready" in msgs[0]
    done = next(m["done"] for m in msgs if m.get("id") == 1 and "done" in m)
    assert done["route"] == "landmarks" and done["frames"] == 328
    with np.load(done["result"]) as z:
        W = z["weights"]
    assert np.array_equal(W, apply_take(take, arkit_character, route="landmarks").weights)
    assert [b for _, b in done["channels"]][:2] == [[[arkit_character.meshes[0].ref, n]] for n in
                                                    arkit_character.meshes[0].shape_names[:2]]
    progress = [m["progress"] for m in msgs if m.get("id") == 1 and "progress" in m]
    assert progress == sorted(progress) and progress[-1] == 1.0
    err = next(m for m in msgs if m.get("id") == 2 and "error" in m)
    assert err["type"] == "InputFileError" and "no.csv" in err["error"] and "\n" not in err["error"]
    bad = next(m for m in msgs if m.get("id") == 3 and "error" in m)
    assert "unknown job 'nonsense'" in bad["error"]


def test_worker_stop_ends_a_running_live_job(arkit_character, data_dir, tmp_path):
    pytest.importorskip("mediapipe", reason="the capture extra")
    from faceretarget.pipelines import serve_jobs

    ch = tmp_path / "character.pkl"
    ch.write_bytes(b"".join(bytes(p) for p in character_parts(arkit_character)))
    r_fd, w_fd = os.pipe()
    reader = os.fdopen(r_fd, "r")
    writer = os.fdopen(w_fd, "w", buffering=1)
    out = io.StringIO()
    t = threading.Thread(target=serve_jobs, args=(reader, out), daemon=True)
    t.start()
    writer.write(json.dumps({"id": 5, "kind": "live", "dir": str(tmp_path),
                             "params": {"character": str(ch), "source": str(data_dir / "video" / "WDA_AOC_000.mp4")}})
                 + "\n")
    t0 = time.perf_counter()
    while '"frame"' not in out.getvalue() and time.perf_counter() - t0 < 60:
        time.sleep(0.05)
    writer.write(json.dumps({"stop": 5}) + "\n")
    writer.write(json.dumps({"quit": True}) + "\n")
    t.join(20)
    assert not t.is_alive()
    msgs = [json.loads(line) for line in out.getvalue().splitlines()]
    frames = [m["frame"] for m in msgs if "frame" in m]
    done = next(m["done"] for m in msgs if "done" in m)
    assert frames and done["processed"] < 200               # stopped before the video's end
    assert len(frames[-1]["w"]) == len(next(m["live"] for m in msgs if "live" in m)["drive"])
