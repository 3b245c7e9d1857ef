"""Files in and out: inputs checked once, outputs written whole or not at all.

Every reader opens its input through :func:`input_file` (one message for a missing path or a
folder where a file was expected); every writer checks its destination with
:func:`check_output_path` before any work and writes through :func:`atomic_path` /
:func:`atomic_dir`: to a temporary name beside the target, renamed when complete, removed on any
failure.  :func:`save_npz_arrays` / :func:`load_npz_arrays` are the one ``.npz`` container of the
package (no pickles), used by every model's ``save``/``load`` and by the ``.npz`` take format.
:func:`cache_dir` is the one folder the package keeps caches in (never beside an input).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import struct
import tempfile
import tokenize
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .errors import InputFileError, OutputError, excerpt

__all__ = ["input_file", "read_text", "check_output_path", "atomic_path", "atomic_dir", "protect_inputs",
           "cache_dir", "cache_enabled", "file_sha256",
           "save_npz_arrays", "load_npz_arrays"]


# ------------------------------------------------------------------------------------------ caches
#: Environment variables: the cache folder, and caching switched off (what ``faceretarget --no-cache`` sets).
CACHE_ENV, NO_CACHE_ENV = "FACERETARGET_CACHE", "FACERETARGET_NO_CACHE"


def cache_dir(*parts: str) -> Path:
    """The folder faceretarget keeps its caches in, or a sub-folder of it (not created).

    ``$FACERETARGET_CACHE`` when set; else the platform's user cache folder (:mod:`platformdirs`:
    ``$XDG_CACHE_HOME/faceretarget``, by default ``~/.cache/faceretarget``, on Linux;
    ``~/Library/Caches/faceretarget`` on macOS; ``%LOCALAPPDATA%\\faceretarget\\Cache`` on Windows).
    Every cache entry is named by the SHA-256 of the content it was made from, never by a path, and
    nothing is ever written beside a user's input.

    >>> cache_dir("landmarks") == cache_dir() / "landmarks"
    True
    """
    env = os.environ.get(CACHE_ENV)
    if env:
        base = Path(env).expanduser()
    else:
        import platformdirs

        base = Path(platformdirs.user_cache_dir("faceretarget", appauthor=False))
    return base.joinpath(*parts)


def file_sha256(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    """The SHA-256 of a file's bytes, as 64 hex digits: what every cache entry is named by."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        while b := f.read(chunk):
            h.update(b)
    return h.hexdigest()


def cache_enabled() -> bool:
    """False when ``$FACERETARGET_NO_CACHE`` is set to anything but ``""`` / ``0`` (``faceretarget --no-cache``):
    no cache is read or written."""
    return os.environ.get(NO_CACHE_ENV, "") in ("", "0")


# ------------------------------------------------------------------------------------------ inputs
def input_file(path: str | os.PathLike) -> Path:
    """``path`` as a :class:`~pathlib.Path`; :class:`InputFileError` naming it when it is missing or not a file."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: file not found" if not path.exists() else f"{path}: not a file")
    return path


_BOMS = ((b"\xff\xfe\x00\x00", "utf-32"), (b"\x00\x00\xfe\xff", "utf-32"), (b"\xef\xbb\xbf", "utf-8-sig"),
         (b"\xff\xfe", "utf-16"), (b"\xfe\xff", "utf-16"))


def read_text(path: str | os.PathLike, encoding: str = "utf-8") -> str:
    """The text of an input file; :class:`InputFileError` when it cannot be read.

    A byte-order mark chooses the encoding (UTF-8, UTF-16 or UTF-32, as spreadsheets save "Unicode
    text"); otherwise ``encoding``.  Undecodable bytes are replaced (U+FFFD), so what they were in is
    reported by the reader's own checks.
    """
    path = input_file(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise InputFileError(f"{path}: cannot read ({e.strerror or e})") from e
    enc = next((e for bom, e in _BOMS if raw.startswith(bom)), encoding)
    return raw.decode(enc, errors="replace")


# ----------------------------------------------------------------------------------------- outputs
def _check_parent(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise OutputError(f"{path}: cannot write, '{parent}' is a file, not a folder")
    if not parent.exists():
        raise OutputError(f"{path}: cannot write, folder '{parent}' does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputError(f"{path}: cannot write, folder '{parent}' is not writable")
    if path.exists() and path.is_dir() and not path.suffix == "":
        raise OutputError(f"{path}: cannot write, a folder of that name exists")


def check_output_path(path: str | os.PathLike) -> Path:
    """Raise :class:`OutputError` early when ``path`` cannot be created; returns it as a Path.

    Checks that its folder exists, is a folder and really accepts a new file (a probe file is
    created and removed, which also catches read-only file systems and root on ``/proc``), so the
    atomic writers fail before doing any work and never leave anything behind.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    _check_parent(path)
    try:
        with tempfile.TemporaryFile(dir=parent, prefix=f".{path.name}.", suffix=".probe"):
            pass
    except OSError as e:
        raise OutputError(f"{path}: cannot write in folder '{parent}' ({e.strerror or e})") from e
    return path


def protect_inputs(out: str | os.PathLike, inputs) -> None:
    """Refuse an output path that names one of the ``inputs`` (or a file inside an input folder)."""
    o = Path(out).resolve()
    for p in inputs:
        if p is None:
            continue
        p = Path(p).resolve()
        if o == p or (p.is_dir() and p in o.parents and o.suffix == ""):
            raise OutputError(f"{out}: refusing to write over the input '{p}'")


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
        if p is not None and Path(p).exists() and path.exists() and os.path.samefile(p, path):
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


# ------------------------------------------------------------------------------------- npz container
def load_npz_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file (no pickles), or an :class:`InputFileError` naming the file."""
    path = input_file(path)
    try:
        with open(path, "rb") as f:  # ours to close: np.load leaks the file of a broken zip
            head = f.read(12)
            if not head.startswith(b"PK\x03\x04"):
                raise InputFileError(f"{path}: not a readable .npz file: not a zip archive of .npy arrays "
                                     f"(it starts with {excerpt(head)})")
            f.seek(0)
            with np.load(f, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, zlib.error, NotImplementedError, RuntimeError,
            KeyError, struct.error, OverflowError, MemoryError, SyntaxError, tokenize.TokenError) as e:
        # what numpy's zip and .npy header parsers raise on a corrupt archive
        if isinstance(e, InputFileError):
            raise
        raise InputFileError(f"{path}: not a readable .npz file ({excerpt(e, 120)})") from e


def save_npz_arrays(path: str | os.PathLike, arrays: dict[str, np.ndarray], *, compress: bool = True) -> Path:
    """Write arrays to an ``.npz`` (compressed by default), whole or not at all."""
    path = check_output_path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        (np.savez_compressed if compress else np.savez)(f, **arrays)
    return path
