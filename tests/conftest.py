"""Shared fixtures: the one place tests find ../shared/data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _data_root() -> Path:
    env = os.environ.get("FACERETARGET_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def require_data() -> bool:
    return os.environ.get("FACERETARGET_REQUIRE_DATA", "") not in ("", "0")


@pytest.fixture(scope="session", autouse=True)
def _own_cache(tmp_path_factory):
    """Landmarks and character reads are cached in the session's folder (also for the CLI run in a child
    process), never beside the shared files or in the user's ~/.cache."""
    old = os.environ.get("FACERETARGET_CACHE")
    os.environ["FACERETARGET_CACHE"] = str(tmp_path_factory.mktemp("faceretarget-cache"))
    yield
    if old is None:
        os.environ.pop("FACERETARGET_CACHE", None)
    else:
        os.environ["FACERETARGET_CACHE"] = old


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
