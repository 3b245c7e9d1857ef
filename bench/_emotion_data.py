"""P6 data: talking-face clips of one sentence in several emotions, captured and normalised.

File naming (the two corpora in ``../shared/data/emotion-video`` and any other speaker named the
same way):

* MEAD: ``{SPEAKER}_{camera}_{emotion}_level{N}_{sentence}.mp4`` (``M030_front_angry_level3_001.mp4``);
* CREMA-D: ``{ACTOR}_{SENTENCE}_{EMO}_{LEVEL}.flv`` (``1001_DFA_ANG_XX.flv``), audio in
  ``{stem}.16k.wav`` beside it when present.

Every clip is tracked once (MediaPipe, ``faceretarget.pipelines.capture_take``) and cached as a
:class:`~faceretarget.capture.Capture` ``.npz`` under ``--cache`` (keyed by the file's size and
modification time), so the benchmark's reruns skip tracking.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: CREMA-D's emotion codes in MEAD's names.
CREMA = {"ANG": "angry", "DIS": "disgusted", "FEA": "fear", "HAP": "happy", "NEU": "neutral", "SAD": "sad"}
MEAD_EMOTIONS = ("angry", "contempt", "disgusted", "fear", "happy", "neutral", "sad", "surprised")
VIDEO_EXT = (".mp4", ".flv", ".avi", ".mov", ".mkv", ".webm")

_MEAD = re.compile(r"^(?P<spk>[A-Za-z0-9]+)_(?P<cam>[a-z_]+?)_(?P<emo>[a-z]+)_level(?P<lvl>\d+)_(?P<sent>\d+)$")
_CREMA = re.compile(r"^(?P<spk>\d{4})_(?P<sent>[A-Z]{3})_(?P<emo>[A-Z]{3})_(?P<lvl>[A-Z]{2}|[A-Z]{1,2}\d?)$")


@dataclass
class Clip:
    speaker: str
    emotion: str
    sentence: str
    level: str
    video: Path
    audio: Path | None


def parse_name(path: Path) -> Clip | None:
    """The speaker, emotion and sentence a clip's file name gives (None: not a clip we know)."""
    stem = path.name
    for ext in VIDEO_EXT:
        if stem.lower().endswith(ext):
            stem = stem[: -len(ext)]
            break
    else:
        return None
    m = _MEAD.match(stem)
    if m and m["emo"] in MEAD_EMOTIONS:
        return Clip(m["spk"], m["emo"], m["sent"], m["lvl"], path, None)
    m = _CREMA.match(stem)
    if m and m["emo"] in CREMA:
        wav = path.with_name(stem + ".16k.wav")
        return Clip(m["spk"], CREMA[m["emo"]], m["sent"], m["lvl"], path, wav if wav.is_file() else None)
    return None


def find_clips(data: Path) -> dict[str, dict[str, Clip]]:
    """``{speaker: {emotion: clip}}`` of every clip under ``data`` (recursively).

    A speaker with several clips of one emotion keeps the one of the speaker's most common sentence
    (the neutral one's when it has one) and, among those, the highest intensity level.
    """
    clips: dict[str, list[Clip]] = {}
    for p in sorted(Path(data).rglob("*")):
        c = parse_name(p) if p.is_file() else None
        if c is not None:
            clips.setdefault(c.speaker, []).append(c)
    out = {}
    for spk, cs in clips.items():
        neutral = [c for c in cs if c.emotion == "neutral"]
        sents = [c.sentence for c in (neutral or cs)]
        sent = max(set(sents), key=sents.count)
        best: dict[str, Clip] = {}
        for c in sorted((c for c in cs if c.sentence == sent), key=lambda c: c.level):
            best[c.emotion] = c
        out[spk] = best
    return out


def cached_capture(clip: Clip | Path, cache: Path | None, log=print, tag: str = "", **capture):
    """The clip's :class:`~faceretarget.capture.Capture` (tracked once, then read from ``cache``).

    ``capture`` goes to :func:`~faceretarget.pipelines.capture_take` (default: raw scores, so an
    emotion's resting offset is kept); ``tag`` tells differently processed captures apart in the cache.
    """
    from faceretarget.capture import Capture
    from faceretarget.pipelines import capture_take

    video = clip.video if isinstance(clip, Clip) else Path(clip)
    path = None
    if cache is not None:
        st = video.stat()
        path = Path(cache) / f"{video.stem}.{st.st_size}.{int(st.st_mtime)}{tag}.npz"
        if path.is_file():
            return Capture.read_npz(path)
    cap = capture_take(video, log=log, **capture)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        cap.write_npz(path)
    return cap


def audio_of(clip: Clip):
    """``(samples, rate)`` of the clip's sidecar WAV, or None."""
    if clip.audio is None:
        return None
    from faceretarget.io import read_audio

    a = read_audio(clip.audio)
    return np.asarray(a[0]), float(a[1])
