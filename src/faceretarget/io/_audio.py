"""Audio: the one reader of the package, mono float32 samples in [-1, 1] and the rate.

WAV files are read with SciPy (no optional dependency): integer PCM (8-bit unsigned, 16-, 24- and
32-bit signed) is scaled by its full range, float WAVs are kept (and clipped to [-1, 1]).  Any
other file (``.mp3``, ``.m4a``, the audio track of a video) is decoded with PyAV, the ``capture``
extra.  Several channels are averaged to one.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from ..errors import InputFileError
from ..files import input_file

__all__ = ["read_audio"]


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
