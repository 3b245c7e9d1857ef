"""Issue 12 items 6 and 7: the head in the same file as the face (``--head``), and Live Link Face CSV
out for every key set defined by ARKit weights, with the input take's timecode and eye angles."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.cli import main
from faceretarget.cloning import keymodel_pair
from faceretarget.errors import InvalidDataError, OutputError
from faceretarget.headpose import HeadPose
from faceretarget.io import (
    read_glb_head,
    read_head_motion,
    read_keyshapes,
    read_livelinkface,
    read_rig,
    read_rig_npz,
    write_head_motion,
    write_keyshapes,
    write_livelinkface,
    write_rig,
    write_rig_npz,
)
from faceretarget.io._livelinkface import EYE_COLUMNS
from faceretarget.names import ARKIT_NAMES
from faceretarget.performance import Performance
from faceretarget.pipelines import clone_take, compose_keys, retarget_take, select_keys, write_result
from faceretarget.rig import Rig

FRAMES = 300
CSV_TOL = 0.51e-10          # the CSV's 10 decimals


def _first_cells(path: Path) -> list[str]:
    return [ln.split(",", 1)[0] for ln in path.read_text().splitlines()[1:]]


def _smooth_head(times: np.ndarray, source: str = "synthetic head") -> HeadPose:
    """A smooth yaw/pitch/roll motion of a few tenths of a radian."""
    t = np.asarray(times)
    ang = np.stack([0.3 * np.sin(1.3 * t), 0.2 * np.sin(0.7 * t + 0.4), 0.1 * np.cos(0.9 * t)], axis=1)
    return HeadPose.from_euler("YXZ", ang, source=source)


@pytest.fixture(scope="module")
def s07(data_dir, tmp_path_factory):
    """The first 300 frames of S07-001, as the file's own lines (timecode and eye columns untouched)."""
    d = tmp_path_factory.mktemp("headcsv")
    lines = (data_dir / "livelinkface" / "S07-001.csv").read_text().splitlines()
    path = d / "s07.csv"
    path.write_text("\n".join(lines[: FRAMES + 1]) + "\n")
    return path


@pytest.fixture(scope="module")
def rom(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_livelinkface(data_dir / "livelinkface" / "alex_rom_3.csv")


@pytest.fixture(scope="module")
def headed(s07, tmp_path_factory):
    """The S07 slice with a real head motion in its head columns (the shared takes hold zeros)."""
    take = read_livelinkface(s07)
    take = take.replace(head=_smooth_head(take.times, str(s07)))
    path = tmp_path_factory.mktemp("headed") / "headed.csv"
    write_livelinkface(path, take)
    return path


# ------------------------------------------------------------------------------------ data model
def test_rig_basis_validated_kept_by_subset_and_files(arkit_rig, tmp_path):
    _, tk, U = keymodel_pair(arkit_rig, arkit_rig, "visemes13")
    assert tk.basis is not None and tk.basis.shape == (tk.n_shapes, 52) and tk.basis_names == list(ARKIT_NAMES)
    np.testing.assert_array_equal(tk.basis, U)
    # key k is the rig at U[k]: the basis is exact for generated key-models
    again = arkit_rig.evaluate(arkit_rig.map_weights(tk.basis_names, tk.basis, warn=False)) - arkit_rig.neutral.vertices
    assert np.abs(again - tk.deltas).max() < 1e-12
    sub = tk.subset(tk.names[::-2])
    np.testing.assert_array_equal(sub.basis, tk.basis[::-2])
    W = np.random.default_rng(0).random((5, tk.n_shapes))
    np.testing.assert_allclose(tk.to_basis(W), W @ U)
    np.testing.assert_allclose(tk.to_basis(W[:, ::-1], tk.names[::-1]), W @ U)
    with pytest.raises(InvalidDataError, match="basis must be"):
        Rig(tk.neutral, tk.names, tk.deltas, tk.unit, basis=U[:, :5], basis_names=list(ARKIT_NAMES))
    with pytest.raises(InvalidDataError, match="together"):
        Rig(tk.neutral, tk.names, tk.deltas, tk.unit, basis=U)
    with pytest.raises(InvalidDataError, match="no basis"):
        arkit_rig.to_basis(np.zeros(arkit_rig.n_shapes))
    # .npz and OBJ folder round trips keep it
    back = read_rig_npz(write_rig_npz(tk, tmp_path / "keys.npz"))
    assert back.basis_names == tk.basis_names and np.array_equal(back.basis, tk.basis)
    write_rig(tk, tmp_path / "keys")
    assert (tmp_path / "keys" / "key_weights.csv").is_file()
    back = read_rig(tmp_path / "keys")
    order = [back.index(n) for n in tk.names]
    assert back.basis_names == tk.basis_names and np.array_equal(back.basis[order], tk.basis)
    # a rig without a basis refuses a folder whose key_weights.csv would describe it wrongly
    with pytest.raises(OutputError, match="key_weights.csv"):
        write_rig(Rig(tk.neutral, tk.names, tk.deltas, tk.unit), tmp_path / "keys")


def test_compose_and_select_keys_carry_basis(arkit_rig, rom, tmp_path):
    msgs: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        comp = compose_keys(arkit_rig, log=msgs.append)
    assert comp.n_shapes == 83 and comp.basis.shape == (83, 52)
    # the pure visemes and emotions are the rig at their weights exactly
    pure = list(range(13)) + list(range(78, 83))          # neutral + viseme, then the pure emotions
    assert comp.names[12] == "neutralU" and comp.names[78] == "happy"
    S = arkit_rig.evaluate(arkit_rig.map_weights(comp.basis_names, comp.basis[pure], warn=False))
    assert np.abs(S - arkit_rig.neutral.vertices - comp.deltas[pure]).max() < 1e-12
    assert any("plain sum" in m for m in msgs)
    write_rig(comp, tmp_path / "composed")
    back = read_rig(tmp_path / "composed")
    assert np.array_equal(back.basis[[back.index(n) for n in comp.names]], comp.basis)
    # keyshapes chosen from a weight take: the frames' weights go to key_weights.csv and come back
    take = rom.slice(0, 600)
    sel = select_keys(take, 8, "pivoted-qr", source_rig=arkit_rig)
    np.testing.assert_array_equal(sel.basis, take.weights[sel.frames])
    write_keyshapes(sel.geometry.points, sel.frames, tmp_path / "sel", mesh=sel.geometry.mesh,
                    neutral=sel.neutral, basis=sel.basis, basis_names=sel.basis_names, contact_sheet=False)
    keys = read_keyshapes(tmp_path / "sel")
    np.testing.assert_array_equal(keys.basis, take.weights[sel.frames])
    assert keys.basis_names == sel.basis_names
    order = [sel.frames[-1], sel.frames[0]]
    np.testing.assert_array_equal(read_keyshapes(tmp_path / "sel", order).basis, take.weights[order])


def test_performance_timecode_and_curves(s07):
    take = read_livelinkface(s07)
    _, info = read_livelinkface(s07, with_info=True)
    assert take.timecode == pytest.approx(info.start_seconds, abs=1e-9) and take.timecode_rate == 60
    assert take.curve_names == list(EYE_COLUMNS)
    np.testing.assert_array_equal(take.curves, info.eye_rotation)
    assert np.abs(take.curves).max() > 0.2
    part = take.slice(100, 200)
    assert part.timecode == take.timecode and np.array_equal(part.curves, take.curves[100:200])
    moved = take.with_weights(take.weights[:, :3], take.names[:3])
    assert moved.timecode == take.timecode and moved.curves is take.curves
    assert "curves" not in take.select("weights").channels
    with pytest.raises(InvalidDataError, match="together"):
        take.replace(timecode_rate=None)
    with pytest.raises(InvalidDataError, match="curves must be"):
        take.replace(curves=take.curves[:10])
    with pytest.raises(InvalidDataError, match="86400"):
        take.replace(timecode=90000.0)


def test_livelinkface_round_trip_keeps_timecode_and_eyes(s07, tmp_path):
    take = read_livelinkface(s07)
    out = write_livelinkface(tmp_path / "again.csv", take.slice(50))
    assert _first_cells(out) == _first_cells(s07)[50:]
    back = read_livelinkface(out)
    assert np.abs(back.curves - take.curves[50:]).max() <= CSV_TOL


# ------------------------------------------------------------------------------------ CSV out
@pytest.mark.parametrize("keys", ["rom-40", "arkit"])
def test_clone_to_csv_is_w_at_u_with_clock_and_eyes(s07, rom, ict_rig, arkit_rig, tmp_path, keys):
    take = read_livelinkface(s07)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sk, tk, U = keymodel_pair(ict_rig, arkit_rig, keys, rom=rom)
        job = clone_take(take, sk, tk, source_rig=ict_rig)
    msgs: list[str] = []
    out = write_result(tmp_path / "clone.csv", job, log=msgs.append)
    back = read_livelinkface(out)
    expect = job.result.weights @ U                         # (T, 52) over the ARKit names
    got = back.weights[:, [back.names.index(n) for n in ARKIT_NAMES]]
    # ARKit curves stay in [0, 1]: frames whose W @ U leaves it are solved again (one log line says so)
    inside = ((expect >= 0) & (expect <= 1)).all(axis=1)
    assert (got >= 0).all() and (got <= 1).all()
    assert (keys == "rom-40") == (not inside.all()) == any("kept in [0, 1]" in m for m in msgs), msgs
    err = np.abs(got[inside] - expect[inside]).max(initial=0.0)
    assert err <= CSV_TOL, err
    assert np.abs(expect).max() > 0.3                       # not a file of zeros
    assert _first_cells(out)[0] == _first_cells(s07)[0]     # 12:27:47:47.169
    assert _first_cells(out) == _first_cells(s07)
    assert np.abs(back.curves - take.curves).max() <= CSV_TOL
    assert (keys == "rom-40") == any("converted 40 key weights" in m for m in msgs)
    # exact where nothing was solved again: the target rig played by the CSV's curves is the cloned target
    # face (what the .glb shows); elsewhere still a blend of the keys (W2 @ U for some W2), near the clone
    faces = arkit_rig.evaluate(arkit_rig.map_weights(list(ARKIT_NAMES), got, warn=False))
    cloned = job.model.blend(job.result.weights)
    gap_mm = np.abs(faces - cloned)[inside].max(initial=0.0) * arkit_rig.mm_per_unit
    assert gap_mm < 1e-6, gap_mm
    W2 = np.linalg.lstsq(U.T, got.T, rcond=None)[0].T
    assert np.abs(W2 @ U - got).max() <= 2 * CSV_TOL
    motion = np.abs(cloned - arkit_rig.neutral.vertices).max()
    assert np.abs(faces - cloned).max() < 0.05 * motion


def test_retarget_regions_to_csv_folds_then_converts(s07, rom, arkit_rig, tmp_path):
    take = read_livelinkface(s07)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sk, tk, U = keymodel_pair(arkit_rig, arkit_rig, "rom-30", rom=rom)
        job = retarget_take(take, sk, tk, source_rig=arkit_rig, regions="upper-lower")
    assert any("@" in n for n in job.result.names)
    out = write_result(tmp_path / "rt.csv", job)
    back = read_livelinkface(out)
    expect = job.model.key_weights(job.result.weights) @ U
    got = back.weights[:, [back.names.index(n) for n in ARKIT_NAMES]]
    inside = ((expect >= 0) & (expect <= 1)).all(axis=1)
    assert (got >= 0).all() and (got <= 1).all()                            # in ARKit's range, as written
    assert np.abs(got[inside] - expect[inside]).max(initial=0.0) <= CSV_TOL
    assert np.abs(expect).max() > 0.3


def test_csv_of_undefined_keys_is_an_error_and_writes_nothing(s07, data_dir, arkit_rig, tmp_path, capsys):
    take = read_livelinkface(s07)
    sk, tk, _ = keymodel_pair(arkit_rig, arkit_rig, "emotions6")
    sk, tk = (Rig(r.neutral, r.names, r.deltas, r.unit, r.landmarks, None, "my-keys") for r in (sk, tk))
    job = clone_take(take, sk, tk, source_rig=arkit_rig)
    with pytest.raises(OutputError, match=r"my-keys.*\.glb"):
        write_result(tmp_path / "x.csv", job)
    assert not (tmp_path / "x.csv").exists()
    # the command line: exit code 2, one line naming the key set, nothing written
    write_rig(sk, tmp_path / "src_keys")
    write_rig(tk, tmp_path / "tgt_keys")
    out = tmp_path / "y.csv"
    rc = main(["clone", "--source-keys", str(tmp_path / "src_keys"), "--target-keys", str(tmp_path / "tgt_keys"),
               "--source-rig", str(data_dir / "arkit-face"), "--performance", str(s07), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "tgt_keys" in err and ".glb" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_keys_select_then_retarget_to_csv(s07, data_dir, arkit_rig, tmp_path):
    """``keys select`` of a weight take writes key_weights.csv; a retarget onto keys that carry it writes
    the ARKit curves ``key weights @ U``."""
    from faceretarget.io import read_keys

    rig_dir = str(data_dir / "arkit-face")
    rc = main(["--quiet", "keys", "select", "--performance", str(s07), "--source-rig", rig_dir, "--k", "12",
               "--out", str(tmp_path / "keys")])
    assert rc == 0 and (tmp_path / "keys" / "key_weights.csv").is_file()
    src = read_keyshapes(tmp_path / "keys")
    frames = [int(n[6:]) for n in src.source_names]
    # the "artist" models the target counterparts: here the same rig at the same weights, plus
    # key_weights.csv copied beside them
    take = read_livelinkface(s07)
    V = arkit_rig.evaluate(arkit_rig.map_weights(take.names, take.weights, warn=False))
    write_keyshapes(V, frames, tmp_path / "target", mesh=arkit_rig.neutral, neutral=arkit_rig.neutral.vertices,
                    basis=src.basis, basis_names=src.basis_names, contact_sheet=False)
    out = tmp_path / "r.csv"
    rc = main(["--quiet", "retarget", "--performance", str(s07), "--source-keys", str(tmp_path / "keys"),
               "--target-keys", str(tmp_path / "target"), "--source-rig", rig_dir, "--out", str(out)])
    assert rc == 0
    sk, labels = read_keys(tmp_path / "keys", rig=arkit_rig)
    tk, _ = read_keys(tmp_path / "target")
    job = retarget_take(take, sk, tk, source_labels=labels, source_rig=arkit_rig)
    expect = job.result.weights @ tk.subset(job.result.names).basis
    back = read_livelinkface(out)
    got = back.weights[:, [back.names.index(n) for n in src.basis_names]]
    inside = ((expect >= -1e-9) & (expect <= 1 + 1e-9)).all(axis=1)        # ARKit's range, kept as written
    assert inside.any() and (got >= 0).all() and (got <= 1).all()
    assert np.abs(got[inside] - expect[inside]).max() <= CSV_TOL
    assert np.abs(expect).max() > 0.3


# ------------------------------------------------------------------------------------ --head
@pytest.fixture(scope="module")
def clone_cli(data_dir):
    rig = str(data_dir / "arkit-face")

    def run(perf: Path, out: Path, *extra: str, quiet: bool = True) -> int:
        return main(["--quiet"] * quiet + ["clone", "--source-rig", rig, "--target-rig", rig, "--keys", "arkit",
                                           "--performance", str(perf), "--out", str(out), *extra])
    return run


def test_head_auto_off_and_file_in_glb(headed, clone_cli, tmp_path):
    take = read_livelinkface(headed)
    # auto: the take's own head pose, as a head node above the face
    assert clone_cli(headed, tmp_path / "auto.glb") == 0
    t, pose = read_glb_head(tmp_path / "auto.glb")
    assert pose.n_frames == FRAMES and np.abs(t - (take.times - take.times[0])).max() < 1e-5
    ang = np.degrees((Rotation.from_quat(pose.quaternions).inv() * take.head.rotation).magnitude()).max()
    assert ang < 1e-4, ang                           # float32 quaternions in the file
    assert np.degrees(take.head.rotation.magnitude()).max() > 10
    # off: no head node
    assert clone_cli(headed, tmp_path / "off.glb", "--head", "off") == 0
    with pytest.raises(Exception, match="no node named 'head'"):
        read_glb_head(tmp_path / "off.glb")
    # a BVH at 25 fps, longer than the take: its rotations, resampled (slerp) to the take's times
    bvh_times = np.arange(int(take.duration * 25) + 10) / 25.0
    motion = Performance.from_head(_smooth_head(1.7 * bvh_times, "motion"), times=bvh_times)
    write_head_motion(tmp_path / "motion.bvh", motion)
    assert clone_cli(headed, tmp_path / "bvh.glb", "--head", str(tmp_path / "motion.bvh")) == 0
    _, pose = read_glb_head(tmp_path / "bvh.glb")
    on_file = read_head_motion(tmp_path / "motion.bvh")
    expect = on_file.head.resample(on_file.times, take.times - take.times[0])
    ang = np.degrees((Rotation.from_quat(pose.quaternions).inv() * expect.rotation).magnitude()).max()
    assert ang < 1e-4, ang
    # against the motion itself between the BVH's frames: slerp of a smooth motion at 25 fps
    truth = _smooth_head(1.7 * (take.times - take.times[0]))
    gap = np.degrees((Rotation.from_quat(pose.quaternions).inv() * truth.rotation).magnitude()).max()
    assert gap < 0.05, gap
    # and it is not the take's own head
    own = np.degrees((Rotation.from_quat(pose.quaternions).inv() * take.head.rotation).magnitude()).max()
    assert own > 5


def test_head_file_into_csv_columns(headed, clone_cli, tmp_path):
    take = read_livelinkface(headed)
    bvh_times = np.arange(int(take.duration * 30) + 5) / 30.0
    write_head_motion(tmp_path / "m.bvh", Performance.from_head(_smooth_head(1.7 * bvh_times, "m"), times=bvh_times))
    assert clone_cli(headed, tmp_path / "h.csv", "--head", str(tmp_path / "m.bvh")) == 0
    back = read_livelinkface(tmp_path / "h.csv")
    m = read_head_motion(tmp_path / "m.bvh")
    expect = m.head.resample(m.times, take.times - take.times[0]).to_livelinkface()
    assert np.abs(back.head.to_livelinkface() - expect).max() < 1e-9
    assert _first_cells(tmp_path / "h.csv") == _first_cells(headed)


def test_head_errors_exit_nonzero_naming_the_file(headed, clone_cli, tmp_path, capsys):
    take = read_livelinkface(headed)
    # missing file
    rc = clone_cli(headed, tmp_path / "a.glb", "--head", str(tmp_path / "nope.bvh"))
    err = capsys.readouterr().err
    assert rc == 2 and "nope.bvh" in err and not (tmp_path / "a.glb").exists()
    # a head-motion file shorter than the take
    short = np.arange(int(take.duration * 25 / 2)) / 25.0
    write_head_motion(tmp_path / "short.bvh", Performance.from_head(_smooth_head(short, "s"), times=short))
    rc = clone_cli(headed, tmp_path / "b.glb", "--head", str(tmp_path / "short.bvh"))
    err = capsys.readouterr().err
    assert rc == 2 and "short.bvh" in err and "covers" in err and "needs" in err and not (tmp_path / "b.glb").exists()
    # an explicit head into a format without one
    rc = clone_cli(headed, tmp_path / "c.npz", "--head", str(tmp_path / "short.bvh"))
    err = capsys.readouterr().err
    assert rc == 2 and "c.npz" in err and "cannot hold head motion" in err and not (tmp_path / "c.npz").exists()
    # auto into a format without one: written, and a log line says the head was left out
    rc = clone_cli(headed, tmp_path / "d.npz", quiet=False)
    out = capsys.readouterr().out
    assert rc == 0 and "holds no head motion" in out and (tmp_path / "d.npz").is_file()


def test_head_resample_is_slerp_and_refuses_uncovered_spans():
    t = np.arange(11) / 10.0
    axis = np.array([0.2, 0.9, 0.1]) / np.linalg.norm([0.2, 0.9, 0.1])
    pose = HeadPose.from_rotation(Rotation.from_rotvec(np.outer(0.8 * t, axis)), np.outer(t, [0.01, 0, 0]),
                                  source="p.bvh")
    q = np.linspace(0, 1, 37)
    r = pose.resample(t, q)
    truth = Rotation.from_rotvec(np.outer(0.8 * q, axis))
    assert np.degrees((r.rotation.inv() * truth).magnitude()).max() < 1e-10
    assert np.abs(r.translation[:, 0] - 0.01 * q).max() < 1e-15
    with pytest.raises(InvalidDataError, match=r"p\.bvh.*covers 0\.000-1\.000 s"):
        pose.resample(t, [0.5, 1.2])


def test_head_files_aligned_by_timecode_and_glb(headed, clone_cli, tmp_path, capsys):
    """A Live Link Face head file is aligned with the take by timecode; a ``.glb`` head node (what
    ``headmotion synth`` writes) is read too; a ``.bvh`` output (head only) is refused."""
    full = read_livelinkface(headed)
    part = full.slice(60, 240)
    write_livelinkface(tmp_path / "part.csv", part)
    assert _first_cells(tmp_path / "part.csv") == _first_cells(headed)[60:240]
    assert clone_cli(tmp_path / "part.csv", tmp_path / "tc.glb", "--head", str(headed)) == 0
    _, pose = read_glb_head(tmp_path / "tc.glb")
    ang = np.degrees((Rotation.from_quat(pose.quaternions).inv() * full.head[60:240].rotation).magnitude()).max()
    assert ang < 1e-4, ang                              # frames 60..239 of the head file, not 0..179
    off = np.degrees((Rotation.from_quat(pose.quaternions).inv() * full.head[:180].rotation).magnitude()).max()
    assert off > 1
    # a .glb head node
    t = np.arange(400) / 30.0
    write_head_motion(tmp_path / "synth.glb", Performance.from_head(_smooth_head(0.5 * t, "synth"), times=t))
    assert clone_cli(tmp_path / "part.csv", tmp_path / "g.csv", "--head", str(tmp_path / "synth.glb")) == 0
    back = read_livelinkface(tmp_path / "g.csv")
    expect = _smooth_head(0.5 * (part.times - part.times[0])).to_livelinkface()
    err = np.abs(back.head.to_livelinkface() - expect).max()
    assert err < 1e-3, err                              # float32 file, slerp at 30 fps
    # a head-only format is not a clone output
    rc = clone_cli(tmp_path / "part.csv", tmp_path / "e.bvh", quiet=False)
    err = capsys.readouterr().err
    assert rc == 2 and "e.bvh" in err and "head motion only" in err and not (tmp_path / "e.bvh").exists()
