"""Shared fixtures: the one place tests find ../shared/data."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _data_root() -> Path:
    env = os.environ.get("FACERETARGET_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def require_data() -> bool:
    return os.environ.get("FACERETARGET_REQUIRE_DATA", "") not in ("", "0")


# ------------------------------------------------------------------------------ a hermetic environment
# Set when conftest is imported, before any test module is (tests/_blender.py imports bpy while collecting):
# the suite runs with a home, configuration, data and cache folders of its own, so nothing the user installed
# (a Blender extension, a matplotlib style, a faceretarget cache) changes a result, and nothing is written
# into the user's home.  Child processes inherit it.
_HERMETIC = Path(tempfile.mkdtemp(prefix="faceretarget-tests-"))
_SAVED_ENV = {k: os.environ.get(k) for k in ("HOME", "XDG_CACHE_HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME",
                                             "FACERETARGET_CACHE", "FACERETARGET_NO_CACHE")}
for _k, _sub in (("HOME", "home"), ("XDG_CACHE_HOME", "home/.cache"), ("XDG_CONFIG_HOME", "home/.config"),
                 ("XDG_DATA_HOME", "home/.local/share"), ("FACERETARGET_CACHE", "faceretarget-cache")):
    (_HERMETIC / _sub).mkdir(parents=True, exist_ok=True)
    os.environ[_k] = str(_HERMETIC / _sub)
os.environ.pop("FACERETARGET_NO_CACHE", None)
for _k in [k for k in os.environ if k.startswith("BLENDER_")]:     # the user's Blender folders
    del os.environ[_k]


def _tree(root: Path) -> dict[str, tuple[int, int]]:
    """Every file and folder below ``root``: (size, mtime in ns)."""
    out = {}
    for p in [root, *root.rglob("*")]:
        st = p.lstat()
        out[p.relative_to(root).as_posix()] = (st.st_size if p.is_file() else 0, st.st_mtime_ns)
    return out


_SHARED_BEFORE = _tree(_data_root()) if _data_root().is_dir() else None


def pytest_sessionfinish(session, exitstatus):
    """The shared data is read in place and never written: a file that appeared, changed or went away under it
    fails the run (issue 31: nothing is written beside an input).  Then the hermetic folders go."""
    if _SHARED_BEFORE is not None:
        after = _tree(_data_root())
        new = sorted(set(after) - set(_SHARED_BEFORE))
        gone = sorted(set(_SHARED_BEFORE) - set(after))
        changed = sorted(k for k in set(after) & set(_SHARED_BEFORE) if after[k] != _SHARED_BEFORE[k] and k != ".")
        if new or gone or changed:
            rep = session.config.pluginmanager.get_plugin("terminalreporter")
            msg = (f"the tests wrote into the shared data {_data_root()}: new {new[:10]}, changed {changed[:10]}, "
                   f"gone {gone[:10]}")
            if rep is not None:
                rep.write_line(f"FAILED (shared data): {msg}", red=True)
            session.exitstatus = 1
    for k, v in _SAVED_ENV.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    shutil.rmtree(_HERMETIC, ignore_errors=True)


# ------------------------------------------------------------------------------------------ progress
@pytest.fixture(scope="session")
def progress(pytestconfig):
    """``progress(message)``: one line on the terminal now, past pytest's output capture (also from a worker of
    ``pytest -n``): a test that runs for long says what it is doing at least every 30 s."""
    capman = pytestconfig.pluginmanager.getplugin("capturemanager")
    t0 = time.monotonic()

    def say(message: str) -> None:
        line = f"\n[progress {time.monotonic() - t0:6.0f} s] {message}\n"
        if capman is None:
            sys.stderr.write(line)
            return
        with capman.global_and_fixture_disabled():
            sys.stderr.write(line)
            sys.stderr.flush()

    return say


def run_with_progress(cmd: list[str], progress, what: str, *, every: float = 20.0, timeout: float = 1800,
                      **popen) -> subprocess.CompletedProcess:
    """``subprocess.run(cmd, capture_output=True, text=True)`` that says, every ``every`` seconds, how long
    ``what`` has run and the last line the child printed."""
    import threading

    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)
    out, err = [], []

    def pump(stream, into):
        for line in stream:
            into.append(line)

    threads = [threading.Thread(target=pump, args=(proc.stdout, out), daemon=True),
               threading.Thread(target=pump, args=(proc.stderr, err), daemon=True)]
    for th in threads:
        th.start()
    t0 = time.monotonic()
    while True:
        try:
            proc.wait(timeout=every)
            break
        except subprocess.TimeoutExpired:
            if time.monotonic() - t0 > timeout:
                proc.kill()
                proc.wait()
                raise subprocess.TimeoutExpired(cmd, timeout) from None
            last = next((ln.strip() for ln in reversed(out) if ln.strip()), "")    # the child's own lines first
            last = last or next((ln.strip() for ln in reversed(err) if ln.strip()), "")
            progress(f"{what}: {time.monotonic() - t0:.0f} s{', last: ' + last[:120] if last else ''}")
    for th in threads:
        th.join(5)
    return subprocess.CompletedProcess(cmd, proc.returncode, "".join(out), "".join(err))


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """``../shared/data``; skips when absent, fails instead under FACERETARGET_REQUIRE_DATA=1."""
    root = _data_root()
    if not root.is_dir():
        msg = f"shared data folder not found at {root} (set FACERETARGET_DATA)"
        if require_data():
            pytest.fail(msg)
        pytest.skip(msg)
    return root


@pytest.fixture(scope="session")
def chars(data_dir) -> Path:
    """``../shared/data/characters``: the real avatars (VALID, Rocketbox, RobotExpressive)."""
    return data_dir / "characters"


@pytest.fixture(scope="session")
def ict_rig(data_dir):
    from faceretarget.io import read_rig

    return read_rig(data_dir / "ict-face")


@pytest.fixture(scope="session")
def arkit_rig(data_dir):
    from faceretarget.io import read_rig

    return read_rig(data_dir / "arkit-face")
