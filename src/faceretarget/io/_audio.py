"""Audio: the one reader of the package, mono float32 samples in [-1, 1] and the rate.

WAV files are read with SciPy (no optional dependency): integer PCM (8-bit unsigned, 16-, 24- and
32-bit signed) is scaled by its full range, float WAVs are kept (and clipped to [-1, 1]).  Any
other file (``.mp3``, ``.m4a``, the audio track of a video) is decoded with PyAV, the ``capture``
extra.  Several channels are averaged to one.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ..errors import InputFileError, InvalidDataError
from ..files import input_file

__all__ = ["read_audio", "checked_audio", "write_wav"]


def read_audio(path: str | os.PathLike) -> tuple[np.ndarray, float]:
    """Read the audio of a file: ``.wav`` with SciPy, anything else with PyAV.

    Parameters
    ----------
    path : path-like
        A RIFF/WAVE file (PCM or IEEE float).

    Returns
    -------
    samples : (N,) float32
        Mono samples in [-1, 1] (channels averaged).
    rate : float
        Sampling rate in Hz.

    Raises
    ------
    InputFileError
        Missing file, a file that is not a WAV (or an unsupported WAV encoding), or one without
        samples; the message names the file.
    """
    from scipy.io import wavfile

    path = input_file(path)
    if path.suffix.lower() not in (".wav", ".wave"):
        from ._video import read_video_audio

        got = read_video_audio(path)
        if got is None:
            raise InputFileError(f"{path}: no audio stream could be decoded")
        return got[0], float(got[1])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wavfile.WavFileWarning)  # unknown chunks (LIST, bext...)
            rate, data = wavfile.read(path)
    except (ValueError, EOFError, OSError, TypeError, KeyError) as e:
        raise InputFileError(f"{path}: cannot read as a WAV file ({e}); convert it to PCM WAV") from e
    data = np.asarray(data)
    if data.size == 0:
        raise InputFileError(f"{path}: the WAV file holds no samples")
    if data.dtype == np.uint8:
        x = (data.astype(np.float32) - 128.0) / 128.0
    elif data.dtype.kind == "i":
        x = data.astype(np.float32) / float(-np.iinfo(data.dtype).min)
    elif data.dtype.kind == "f":
        x = data.astype(np.float32)
    else:
        raise InputFileError(f"{path}: unsupported WAV sample type {data.dtype}")
    if x.ndim == 2:
        x = x.mean(axis=1, dtype=np.float32)
    if not np.isfinite(x).all():
        raise InputFileError(f"{path}: the WAV file holds non-finite samples")
    if not rate or rate <= 0:
        raise InputFileError(f"{path}: invalid sampling rate {rate}")
    return np.clip(x, -1.0, 1.0), float(rate)


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


def write_wav(path: str | os.PathLike, audio: np.ndarray, rate: int) -> Path:
    """Write samples in [-1, 1] as a 16-bit PCM WAV (clipped), in place; returns the path."""
    from scipy.io import wavfile

    path = Path(path)
    wavfile.write(path, int(rate), np.round(np.clip(audio, -1.0, 1.0) * 32767.0).astype(np.int16))
    return path
