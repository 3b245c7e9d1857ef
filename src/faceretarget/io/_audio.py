"""Audio: the one reader of the package, mono float32 samples in [-1, 1] and the rate.

WAV files are read with SciPy (no optional dependency): integer PCM (8-bit unsigned, 16-, 24- and
32-bit signed) is scaled by its full range, float WAVs are kept (and clipped to [-1, 1]).  Any
other file (``.mp3``, ``.m4a``, the audio track of a video) is decoded with PyAV, the ``capture``
extra.  Several channels are averaged to one.
"""

from __future__ import annotations

import io
import os
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InputFileError, InvalidDataError, excerpt
from ..files import input_file
from ..formats import WAV

__all__ = ["read_audio", "checked_audio", "write_wav", "write_audio"]


def read_audio(path: str | os.PathLike, *, speech: bool = False) -> tuple[np.ndarray, float]:
    """Read the audio of a file: ``.wav`` with SciPy, anything else with PyAV.

    Parameters
    ----------
    path : path-like
        A RIFF/WAVE file (PCM or IEEE float).
    speech : bool
        The audio is the speech a job follows (new speech to re-time to, speech that drives head motion):
        silence is an error, not a warning.

    Returns
    -------
    samples : (N,) float32
        Mono samples in [-1, 1] (channels averaged).
    rate : float
        Sampling rate in Hz.

    Raises
    ------
    InputFileError
        Missing file, a file that is not a WAV (no RIFF/WAVE header or data chunk, or an unsupported
        WAV encoding), one without samples or with NaN / infinite float samples; with ``speech``, a
        silent one (peak under :data:`SILENCE_DBFS`); the message names the file.

    Warns
    -----
    DataWarning
        A truncated file (a data chunk larger than the rest of the file): the samples it holds are
        read.  Float samples beyond +-1 (clipped), channels that cancel when averaged, silence (peak
        under :data:`SILENCE_DBFS`) or a rate under :data:`MIN_SPEECH_RATE`: one line each.
    """
    from scipy.io import wavfile

    path = input_file(path)
    if path.suffix.lower() not in (WAV, ".wave"):
        from ._video import read_video_audio

        got = read_video_audio(path)
        if got is None:
            raise InputFileError(f"{path}: no audio stream could be decoded")
        _check_heard(path, got[0], float(got[1]), speech)
        return got[0], float(got[1])
    source = _wav_source(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wavfile.WavFileWarning)  # unknown chunks (LIST, bext...)
            rate, data = wavfile.read(source)
    except (ValueError, EOFError, OSError, TypeError, KeyError, IndexError, ZeroDivisionError, OverflowError,
            MemoryError, NameError, struct.error) as e:  # NameError: scipy's UnboundLocalError on odd chunks
        raise InputFileError(f"{path}: cannot read as a WAV file ({excerpt(e, 120)}); convert it to PCM WAV") from e
    data = np.asarray(data)
    if data.size == 0:
        raise InputFileError(f"{path}: the WAV file holds no samples")
    if data.dtype.kind == "f" and not np.isfinite(data).all():
        raise InputFileError(f"{path}: the WAV file holds non-finite samples")
    if data.dtype == np.uint8:
        x = (data.astype(np.float32) - 128.0) / 128.0
    elif data.dtype.kind == "i":
        x = data.astype(np.float32) / float(-np.iinfo(data.dtype).min)
    elif data.dtype.kind == "f":
        x = data.astype(np.float64)  # float64 samples beyond float32's range are clipped, not overflowed
    else:
        raise InputFileError(f"{path}: unsupported WAV sample type {data.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):
        if data.dtype.kind == "f" and (np.abs(x) > 1.0).any():
            warnings.warn(f"{path}: {(np.abs(x) > 1.0).mean():.2%} of the float samples lie beyond +-1 (peak "
                          f"{np.abs(x).max():.3g}) and are clipped to +-1", DataWarning, stacklevel=2)
        mix = x.mean(axis=1, dtype=x.dtype) if x.ndim == 2 else x
        if x.ndim == 2 and x.shape[1] > 1:
            _check_mix(path, x, mix)
        x = np.clip(mix, -1.0, 1.0).astype(np.float32)
    if not np.isfinite(x).all():
        raise InputFileError(f"{path}: the WAV file holds non-finite samples")
    if not rate or rate <= 0:
        raise InputFileError(f"{path}: invalid sampling rate {rate}")
    _check_heard(path, x, float(rate), speech)
    return x, float(rate)


#: Peak level (dBFS) under which a recording is taken for silence: 16-bit dither is about -90 dBFS, a quiet
#: room recorded with speech gain about -60 dBFS, speech -30 to -3 dBFS.
SILENCE_DBFS = -60.0
#: Lowest sampling rate of speech audio (telephone speech is 8 kHz).
MIN_SPEECH_RATE = 8000.0


def _dbfs(x: np.ndarray) -> float:
    peak = float(np.abs(x).max()) if x.size else 0.0
    return 20.0 * np.log10(peak) if peak > 0 else -np.inf


def _check_heard(path: Path, x: np.ndarray, rate: float, speech: bool = False) -> None:
    """One warning line when the audio holds nothing a speech method can use: silence, or a rate below speech's
    (``speech``: silence is an :class:`~faceretarget.errors.InputFileError`)."""
    level = _dbfs(x)
    if speech and level < SILENCE_DBFS:
        raise InputFileError(f"{path}: the audio is silent (peak {level:.0f} dBFS, under {SILENCE_DBFS:.0f}): there is no "
                             "speech to follow; give a recording of the speech")
    if level < SILENCE_DBFS:
        warnings.warn(f"{path}: the audio is silent (peak {level:.0f} dBFS, under {SILENCE_DBFS:.0f}): no speech to "
                      "drive head motion or emotion", DataWarning, stacklevel=3)
    if rate < MIN_SPEECH_RATE:
        warnings.warn(f"{path}: sampled at {rate:g} Hz, under the {MIN_SPEECH_RATE:g} Hz of telephone speech: pitch "
                      "and speech features will not be found", DataWarning, stacklevel=3)


def _check_mix(path: Path, x: np.ndarray, mix: np.ndarray) -> None:
    """One warning line when averaging the channels cancels them (out of phase): the mono mix is not what was heard."""
    with np.errstate(over="ignore", invalid="ignore"):
        ch = float(np.sqrt(np.mean(x.astype(np.float64) ** 2)))
        mono = float(np.sqrt(np.mean(mix.astype(np.float64) ** 2)))
    if ch > 10 ** (SILENCE_DBFS / 20) and mono < 0.1 * ch:
        warnings.warn(f"{path}: its {x.shape[1]} channels cancel when averaged to mono ({20 * np.log10(max(mono, 1e-12) / ch):.0f} dB; "
                      "out of phase?); give one channel", DataWarning, stacklevel=3)


def _wav_source(path: Path):
    """``path``, or the file's bytes with its data chunk cut to what the file holds when it is
    truncated (with a warning): SciPy would allocate the size the header declares.

    Raises :class:`InputFileError` for a file without a RIFF/WAVE header or without a data chunk.
    """
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise InputFileError(f"{path}: cannot read ({e.strerror or e})") from e
    if len(raw) < 12 or raw[:4] not in (b"RIFF", b"RIFX", b"RF64") or raw[8:12] != b"WAVE":
        raise InputFileError(f"{path}: cannot read as a WAV file: no RIFF/WAVE header (it starts with "
                             f"{excerpt(raw[:12])})")
    if raw[:4] == b"RF64":
        return path  # sizes are in the ds64 chunk; SciPy checks them
    end = "<" if raw[:4] == b"RIFF" else ">"
    pos = 12
    while pos + 8 <= len(raw):
        cid, n = struct.unpack_from(end + "4sI", raw, pos)
        if cid == b"data":
            have = len(raw) - pos - 8
            if n <= have:
                return path
            warnings.warn(f"{path}: the data chunk declares {n} bytes but the file holds {have} after it; "
                          "the file is truncated, its samples are read up to its end", DataWarning, stacklevel=3)
            patched = bytearray(raw)
            struct.pack_into(end + "I", patched, pos + 4, have)
            struct.pack_into(end + "I", patched, 4, len(raw) - 8)
            return io.BytesIO(bytes(patched))
        pos += 8 + n + (n & 1)
    raise InputFileError(f"{path}: cannot read as a WAV file: no data chunk (or a chunk size runs past the end "
                         "of the file)")


def checked_audio(path, audio, audio_rate) -> tuple[np.ndarray, int] | None:
    """``(samples, integer rate)`` of audio an output file carries, checked (messages name ``path``);
    None for no audio."""
    if audio is None:
        return None
    a = np.asarray(audio, dtype=np.float64)
    if a.ndim == 2 and a.shape[0] < a.shape[1] and a.shape[0] <= 8:
        raise InvalidDataError(f"{path}: audio must be (n,) or (n, channels) samples, got {a.shape} "
                               "(channels first?)")
    if a.ndim not in (1, 2) or a.shape[0] == 0 or (a.ndim == 2 and not 1 <= a.shape[1] <= 8):
        raise InvalidDataError(f"{path}: audio must be (n,) or (n, channels) samples, got {a.shape}")
    if not np.isfinite(a).all():
        raise InvalidDataError(f"{path}: the audio holds non-finite samples")
    if audio_rate is None or not (np.isfinite(audio_rate) and audio_rate > 0):
        raise InvalidDataError(f"{path}: audio needs a positive audio_rate in Hz, got {audio_rate}")
    rate = int(round(float(audio_rate)))
    if abs(rate - float(audio_rate)) > 1e-6 * rate:
        raise InvalidDataError(f"{path}: a WAV needs an integer sampling rate, got {audio_rate} Hz")
    return a, rate


def write_audio(path: str | os.PathLike, audio: np.ndarray, rate: float) -> Path:
    """Write a take's sound as a 16-bit PCM WAV, checked first (:func:`checked_audio`: finite samples, an
    integer rate; the message names ``path``) and written whole or not at all; returns the path."""
    from ..files import atomic_path, check_output_path

    path = check_output_path(path)
    a, r = checked_audio(path, audio, rate)
    with atomic_path(path) as tmp:
        write_wav(tmp, a, r)
    return path


def write_wav(path: str | os.PathLike, audio: np.ndarray, rate: int) -> Path:
    """Write samples in [-1, 1] as a 16-bit PCM WAV (clipped), in place; returns the path."""
    from scipy.io import wavfile

    path = Path(path)
    wavfile.write(path, int(rate), np.round(np.clip(audio, -1.0, 1.0) * 32767.0).astype(np.int16))
    return path
