"""Write outputs whole or not at all: to a temporary name beside the target, renamed when done."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..errors import OutputError

__all__ = ["atomic_path", "atomic_dir"]


def _check_parent(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise OutputError(f"{path}: cannot write, folder '{parent}' does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputError(f"{path}: cannot write, folder '{parent}' is not writable")
    if path.exists() and path.is_dir() and not path.suffix == "":
        raise OutputError(f"{path}: cannot write, a folder of that name exists")


def _umask_mode(p: Path, mode: int) -> None:
    """Give a temporary file the permissions a plain ``open()`` would (mkstemp uses 0600)."""
    umask = os.umask(0)
    os.umask(umask)
    with contextlib.suppress(OSError):
        os.chmod(p, mode & ~umask)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, protect: tuple[str | os.PathLike, ...] = ()) -> Iterator[Path]:
    """Yield a temporary file path; on success rename it to ``path``, on failure delete it.

    ``protect`` lists input files that must never be overwritten: naming one as the output raises
    :class:`OutputError` before anything is written.
    """
    path = Path(path)
    for p in protect:
        if Path(p).exists() and path.exists() and os.path.samefile(p, path):
            raise OutputError(f"{path}: refusing to overwrite an input file")
    _check_parent(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent or ".")
    except OSError as e:
        raise OutputError(f"{path}: cannot write ({e.strerror or e})") from e
    os.close(fd)
    tmp_path = Path(tmp)
    _umask_mode(tmp_path, 0o666)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except OSError as e:
        tmp_path.unlink(missing_ok=True)
        if isinstance(e, OutputError):
            raise
        raise OutputError(f"{path}: cannot write ({e.strerror or e})") from e
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder; on success it replaces ``path`` (which must not hold other files)."""
    path = Path(path)
    _check_parent(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: cannot write a folder, a file of that name exists")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent or "."))
    except OSError as e:
        raise OutputError(f"{path}: cannot write ({e.strerror or e})") from e
    _umask_mode(tmp, 0o777)
    try:
        yield tmp
        if path.exists():
            # merge: move our files in, replacing same-named ones only
            for f in tmp.iterdir():
                os.replace(f, path / f.name)
            tmp.rmdir()
        else:
            os.replace(tmp, path)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(e, OutputError):
            raise
        raise OutputError(f"{path}: cannot write ({e.strerror or e})") from e
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
