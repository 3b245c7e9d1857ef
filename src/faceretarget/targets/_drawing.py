"""2-D targets: keys are drawings with one path structure, or 2-D point sets (Chuang Fig. 3.11, 3.14)."""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InvalidDataError
from ..files import save_npz_arrays
from ..formats import MP4, NPZ, PNG, SVG
from ..io import Drawing, write_drawing_preview, write_svg_animation, write_svg_frames
from ..mesh import Mesh
from ..rig import Rig
from ._base import Target, _quiet

__all__ = ["DrawingTarget"]


class DrawingTarget(Target):
    """Keys given as 2-D drawings of the character (SVG files with the same paths and commands, point
    order kept), or as 2-D point sets.

    A frame's points are the neutral's plus the weighted key offsets, ``P(w) = P0 + sum_k w_k (P_k -
    P0)``: path points and curve control points blend linearly, and a Bezier curve is linear in its
    control points, so the drawn curve is the same blend of the key curves.  :attr:`solve_keys` is
    the points as a point set ``(x, -y, 0)`` (+y up, as the source faces), in the drawing's units.

    Parameters
    ----------
    neutral : Drawing
        The character at rest (its document gives the styles and other elements of the output).
    keys : mapping of str to Drawing
        Key name -> the key's drawing (same structure as ``neutral``).
    source : str, optional
        For messages (default the neutral's folder).
    """

    kind = "drawing"
    key_word = "key drawings"
    formats = (SVG, "folder", PNG, MP4, NPZ)

    def __init__(self, neutral: Drawing, keys: Mapping[str, Drawing], *, source: str | None = None) -> None:
        src = source or str(Path(neutral.source).parent)
        names = list(keys)
        if not names:
            raise InvalidDataError(f"{src}: no key drawings besides the neutral")
        super().__init__(src, names, [Path(keys[n].source).name for n in names])
        for n in names:
            neutral.check_like(keys[n])
            changed = neutral.static_changes(keys[n])
            if changed:
                warnings.warn(f"{keys[n].source}: {', '.join(changed[:6])} drawn otherwise than in {neutral.source}; "
                              "only <path> elements are animated (the output draws the neutral's): convert "
                              "them to paths to animate them", DataWarning, stacklevel=2)
        self.neutral = neutral
        self.keys = dict(keys)
        P0 = neutral.points
        self.offsets = np.stack([keys[n].points - P0 for n in names])            # (K, N, 2)
        flip = np.array([1.0, -1.0])
        pts = np.zeros((neutral.n_points, 3))
        pts[:, :2] = P0 * flip
        d = np.zeros((len(names), neutral.n_points, 3))
        d[:, :, :2] = self.offsets * flip
        self._keys = Rig(Mesh(pts, name="drawing"), names, d, "mm", None, None, src)

    @property
    def solve_keys(self) -> Rig:
        return self._keys

    def describe(self) -> str:
        return (f"drawing target {self.name}: {self.n_keys} key drawings, {len(self.neutral.commands)} paths, "
                f"{self.neutral.n_points} points")

    def params(self, weights: np.ndarray) -> np.ndarray:
        """The drawing's points per frame ``(T, N, 2)`` (SVG user units, +y down)."""
        W = self._weights(weights)
        return self.neutral.points + np.einsum("tk,knc->tnc", W, self.offsets)

    def write(self, path: str | os.PathLike, weights: np.ndarray, times: np.ndarray, *, head=None,
              log=_quiet, **extra) -> Path:
        """Write the animated drawing: ``.svg`` (SMIL, one file), a folder (one SVG per frame), ``.png``
        (a contact sheet of frames), ``.mp4`` (every frame; PyAV; ``progress=True`` in ``extra`` shows a
        progress bar) or ``.npz`` (``points`` ``(T, N, 2)`` and ``times``)."""
        path = self.check_output(path)
        P = self.params(weights)
        ext = self.output_ext(path)
        if ext == SVG:
            return write_svg_animation(path, self.neutral, P, times)
        if ext == "folder":
            return write_svg_frames(path, self.neutral, P, times)
        if ext == NPZ:
            return save_npz_arrays(path, {"points": P, "times": np.asarray(times, dtype=np.float64)})
        return write_drawing_preview(path, self.neutral, P, times, progress=bool(extra.get("progress")))
