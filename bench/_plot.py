"""Plot helpers shared by the benchmarks (Pillow only)."""

from __future__ import annotations

import numpy as np


def font(size: int):
    """Pillow's default font at ``size`` (its fixed bitmap font on Pillow < 10.1)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError, ImportError):  # Pillow < 10.1
        return ImageFont.load_default()


def nice_step(x: float) -> float:
    """The smallest of 1, 2, 2.5, 5, 10 times a power of ten that is at least ``x`` (axis tick spacing)."""
    e = 10.0 ** np.floor(np.log10(max(x, 1e-12)))
    for m in (1, 2, 2.5, 5, 10):
        if m * e >= x:
            return m * e
    return 10 * e
