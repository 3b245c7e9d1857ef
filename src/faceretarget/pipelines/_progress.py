"""Progress for steps that take seconds: a bar whose clock keeps running while one long call works."""

from __future__ import annotations

import contextlib
import threading

__all__ = ["ticking", "working"]


@contextlib.contextmanager
def ticking(bar, on: bool, every: float = 1.0):
    """Redraw the tqdm ``bar`` every ``every`` seconds inside the block (its clock runs while nothing
    updates it: workers starting, one long solve)."""
    if not on:
        yield
        return
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(every):
            bar.refresh()

    t = threading.Thread(target=tick, name="faceretarget-progress", daemon=True)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join()


@contextlib.contextmanager
def working(desc: str, on: bool):
    """A one-line indicator ``desc: 0:03`` counting the seconds of a step that reports no progress of
    its own (a whole-take solve), removed when the step ends."""
    from tqdm.auto import tqdm

    with tqdm(total=None, desc=desc, disable=not on, leave=False, bar_format="{desc}: {elapsed}") as bar, \
            ticking(bar, on):
        yield
