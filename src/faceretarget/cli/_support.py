"""What every ``faceretarget`` command shares: quiet-able logging, input protection, warnings as
one line each, and the error-to-exit-code policy (2 for bad input, 1 for system errors)."""

from __future__ import annotations

import sys
import warnings
from contextlib import contextmanager

from ..errors import FaceRetargetError
from ..files import protect_inputs as protect

__all__ = ["Log", "protect", "warnings_to_log", "run_command"]


class Log:
    """``print`` unless quiet."""

    def __init__(self, quiet: bool):
        self.quiet = quiet

    def __call__(self, *a):
        if not self.quiet:
            print(*a, flush=True)




@contextmanager
def warnings_to_log(log):
    """Print each distinct warning raised inside the block once, on one line."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        finally:
            seen = set()
            for c in caught:
                msg = str(c.message)
                if msg not in seen:
                    seen.add(msg)
                    log(f"warning: {msg}")


def run_command(args) -> int:
    """Run ``args.func(args, log)``: errors a user can act on as one line and exit code 2."""
    log = Log(getattr(args, "quiet", False))
    try:
        with warnings_to_log(log):          # every command prints warnings the same way: one line each
            return int(args.func(args, log) or 0)
    except FaceRetargetError as e:
        print(f"faceretarget: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("faceretarget: interrupted", file=sys.stderr)
        return 130
    except OSError as e:
        print(f"faceretarget: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return 1


def run_alone(register, argv=None, description: str | None = None) -> int:
    """Run one module's sub-commands on their own (``python -m faceretarget.cli._capture ...``), with
    ``faceretarget``'s options and error conventions: ``register(subparsers)`` adds them."""
    import argparse

    p = argparse.ArgumentParser(prog="faceretarget", description=description)
    p.add_argument("--quiet", "-q", action="store_true", help="print errors only")
    register(p.add_subparsers(dest="command", required=True))
    return run_command(p.parse_args(argv))
