"""Head-motion jobs: the ``headmotion build`` command as a library function."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..errors import InvalidDataError
from ..headmotion import HeadMotionDatabase, take_duration
from ..io import read_head_take

__all__ = ["build_head_database"]


def _quiet(*_a) -> None:
    return None


def build_head_database(pairs: Sequence[tuple[str | os.PathLike, str | os.PathLike]], *,
                        allow_mismatch: bool = False, log: Callable[..., None] = _quiet,
                        **params) -> HeadMotionDatabase:
    """A :class:`~faceretarget.headmotion.HeadMotionDatabase` of (speech, head motion) file pairs.

    Each take is named after its motion file (``_2``, ``_3``... when two share a name); takes
    without voiced speech are skipped with a warning in the log.

    Parameters
    ----------
    pairs : sequence of (audio path, motion path)
        Speech (``.wav``) and its head motion (``.bvh``, SMPL-X ``.npz``, ``.c3d``).
    allow_mismatch : bool
        Accept a pair whose durations differ beyond the tolerance of
        :func:`~faceretarget.io.read_head_take` (a warning instead of an error).
    **params
        :class:`~faceretarget.headmotion.HeadMotionDatabase` parameters.
    """
    db = HeadMotionDatabase(**params)
    takes, pitches, used = [], [], set()
    for audio, motion in ((Path(a), Path(m)) for a, m in pairs):
        name, k = motion.stem, 2
        while name in used:
            name, k = f"{motion.stem}_{k}", k + 1
        used.add(name)
        log(f"reading {audio.name} + {motion.name}")
        take = read_head_take(audio, motion, name=name, allow_mismatch=allow_mismatch)
        pitch = db.pitch(take.audio, take.audio_rate)
        n_voiced = int(np.isfinite(pitch.f0).sum())
        log(f"{audio.name} + {motion.name}: {take_duration(take):.1f} s, head motion at {take.fps:g} fps, "
            f"{n_voiced * pitch.time_step:.1f} s voiced")
        if n_voiced == 0:
            log(f"warning: {audio}: no voiced speech found; take skipped")
            continue
        takes.append(take)
        pitches.append(pitch)
    if not takes:
        raise InvalidDataError("no take has voiced speech: " + ", ".join(str(a) for a, _ in pairs))
    return db.fit(takes, pitch=pitches)
