"""Opening input files: one check and one message for every reader."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputFileError

__all__ = ["input_file", "read_text"]


def input_file(path: str | os.PathLike) -> Path:
    """``path`` as a :class:`~pathlib.Path`; :class:`InputFileError` naming it when it is missing or not a file."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: file not found" if not path.exists() else f"{path}: not a file")
    return path


def read_text(path: str | os.PathLike, encoding: str = "utf-8") -> str:
    """The text of an input file (undecodable bytes replaced); :class:`InputFileError` when it cannot be read."""
    path = input_file(path)
    try:
        return path.read_text(encoding=encoding, errors="replace")
    except OSError as e:
        raise InputFileError(f"{path}: cannot read ({e.strerror or e})") from e
