"""Putting appearance-model faces back into video frames (Chuang, thesis Sec. 2.2.1 and Fig. 2.6).

An :class:`~faceretarget.capture.AppearanceModel` configuration vector decodes to a shape on the
model's canvas and a shape-free texture on the mean shape.  :class:`FaceCompositor` renders such a
face into the frame it came from:

1. **Shape to the frame.**  The canvas shape is mapped back into the frame by the inverse of the
   frame's Procrustes similarity (``x = (aligned - c_ref) / a + c``, the ``a``, ``c`` of
   :meth:`AppearanceModel.shape_params` of the frame's tracked landmarks), so the edited face sits
   where the input's face is, with the input's head position, size and in-plane rotation.
2. **Surroundings follow the face** (``morph``).  A ring of anchor points around the face, fixed
   relative to the head (the mean shape's outline scaled by ``ring`` about its centre, mapped into
   the frame by the same similarity), is triangulated together with the face's points once on the
   canvas.  The frame between the face outline and the ring is warped piecewise-affinely from the
   tracked outline to the rendered one, so a chin that rises or a jaw that drops moves the neck and
   cheeks' edge with it instead of leaving a second chin; outside the ring the frame is untouched.
3. **Texture.**  The shape-free texture (grey levels, canvas pixels outside the mesh filled with the
   nearest inside pixel so the bilinear samples at the edge are not darkened) is warped
   piecewise-affinely from the mean shape onto the frame shape.
4. **Feathered composite.**  The face replaces the frame inside the mesh with a weight rising from 0
   at the mesh boundary to 1 at ``feather`` times the face width inside it (smoothstep of the
   distance to the boundary), so hair, background and the neck stay the input's.

Only the frame's bounding box of the face and ring is touched; everything runs per frame with
``cv2.remap`` (OpenCV, the ``capture`` extra).
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError
from ..numerics import smoothstep
from ..optional import optional_import
from ._appearance import AppearanceModel
from ._warp import PiecewiseAffineWarp

__all__ = ["FaceCompositor", "image_shapes"]


def _cv2():
    return optional_import("cv2", "compositing faces into video frames")


def image_shapes(model: AppearanceModel, shapes: np.ndarray, a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Canvas shapes mapped into their frames by the inverse Procrustes similarity.

    Parameters
    ----------
    model : AppearanceModel
        Fitted; its ``reference_`` defines the canvas.
    shapes : (N, P, 2) float
        Shapes on the canvas, pixels (e.g. :meth:`AppearanceModel.reconstruct_shape`).
    a, c : (N,) complex
        Each frame's similarity from :meth:`AppearanceModel.shape_params` (``aligned = a (x - c) + c_ref``).

    Returns
    -------
    (N, P, 2) float
        The shapes in frame pixels (x right, y down).
    """
    S = np.asarray(shapes, np.float64)
    a = np.asarray(a).reshape(-1)
    c = np.asarray(c).reshape(-1)
    if S.ndim != 3 or S.shape[2] != 2 or len(a) != len(S) or len(c) != len(S):
        raise InvalidDataError(f"shapes (N, P, 2) with N similarities a, c; got {S.shape}, {a.shape}, {c.shape}")
    cr = (model.reference_[:, 0] + 1j * model.reference_[:, 1]).mean()
    z = ((S[..., 0] + 1j * S[..., 1]) - cr) / a[:, None] + c[:, None]
    return np.stack([z.real, z.imag], axis=-1)


class FaceCompositor:
    """Render appearance-model faces into video frames (module docstring).

    Parameters
    ----------
    model : AppearanceModel
        Fitted.
    feather : float
        Width of the blend at the face's boundary as a share of the face width (0: a hard edge).
    morph : bool
        Warp the frame around the face (between its outline and a ring of fixed anchors) from the
        tracked shape to the rendered one.
    ring : float
        The anchors' distance from the face centre relative to the mean shape's outline (> 1).

    Attributes
    ----------
    triangles : (F, 3) int
        The model's triangulation of the face points.
    ring_triangles : (G, 3) int
        Triangulation of the face points plus the anchors (indices ``P ..`` are anchors).
    """

    def __init__(self, model: AppearanceModel, *, feather: float = 0.08, morph: bool = True, ring: float = 1.35):
        model._check_fitted("render")
        if not (np.isfinite(feather) and 0 <= feather <= 1):
            raise InvalidDataError(f"feather must be a share of the face width in [0, 1], got {feather}")
        if not (np.isfinite(ring) and ring > 1):
            raise InvalidDataError(f"ring must be > 1 (times the face outline), got {ring}")
        from scipy.ndimage import distance_transform_edt
        from scipy.spatial import ConvexHull, Delaunay

        self.model, self.feather, self.morph, self.ring = model, float(feather), bool(morph), float(ring)
        warp = model.warp_
        self.triangles = warp.triangles
        # canvas pixels outside the mesh take their nearest inside pixel (edge samples stay face-coloured)
        _, idx = distance_transform_edt(~warp.mask, return_indices=True)
        self._fill = (idx[0], idx[1])
        mean = model.mean_shape_
        hull = mean[ConvexHull(mean).vertices]
        centre = mean.mean(axis=0)
        dense = np.concatenate([np.linspace(p, q, 3, endpoint=False) for p, q in zip(hull, np.roll(hull, -1, 0),
                                                                                        strict=True)])
        self.anchors = centre + self.ring * (dense - centre)             # (A, 2) canvas pixels
        pts = np.concatenate([mean, self.anchors])
        tri = Delaunay(pts).simplices
        P = len(mean)
        self.ring_triangles = tri[(tri >= P).any(axis=1)]               # only triangles touching the ring
        self._face_px = float(np.ptp(mean[:, 0]))

    # ---------------------------------------------------------------------------------------------
    def _canvas_texture(self, texture: np.ndarray) -> np.ndarray:
        """(n_pixels, 3) texture -> (h, w, 3) float32 canvas image, filled outside the mesh."""
        img = self.model.warp_.unpack(np.asarray(texture, np.float32))
        return img[self._fill[0], self._fill[1]]

    def _anchors_in_frame(self, a: complex, c: complex) -> np.ndarray:
        return image_shapes(self.model, self.anchors[None], np.array([a]), np.array([c]))[0]

    def render(self, frame: np.ndarray, vector: np.ndarray, a: complex, c: complex,
               tracked: np.ndarray | None = None) -> np.ndarray:
        """One frame with the face of configuration ``vector`` composited in.

        Parameters
        ----------
        frame : (H, W, 3) uint8
            The input frame (RGB).
        vector : (D,) float
            Configuration vector (:meth:`AppearanceModel.transform`), possibly edited.
        a, c : complex
            The frame's similarity (:meth:`AppearanceModel.shape_params` of its tracked landmarks).
        tracked : (P, 2) float, optional
            The frame's tracked shape (the model's points, frame pixels), where the surroundings are
            warped from (``morph``); default: the shape of ``vector`` (no warp of the surroundings).

        Returns
        -------
        (H, W, 3) uint8
        """
        out, _ = self.render_with_mask(frame, vector, a, c, tracked)
        return out

    def render_with_mask(self, frame: np.ndarray, vector: np.ndarray, a: complex, c: complex,
                         tracked: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`render` and the blend weight ``(H, W)`` float in [0, 1] of the rendered face."""
        cv2 = _cv2()
        img = np.asarray(frame)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise InvalidDataError(f"frame must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
        H, W = img.shape[:2]
        m = self.model
        v = np.asarray(vector, np.float64).reshape(1, -1)
        shape = image_shapes(m, m.reconstruct_shape(v), np.array([a]), np.array([c]))[0]
        tex = self._canvas_texture(m.reconstruct_texture(v)[0])
        anchors = self._anchors_in_frame(a, c)
        box_pts = np.concatenate([shape] + ([anchors] if self.morph and tracked is not None else []))
        x0, y0 = np.floor(box_pts.min(axis=0)).astype(int) - 2
        x1, y1 = np.ceil(box_pts.max(axis=0)).astype(int) + 3
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        out = img.copy()
        alpha_full = np.zeros((H, W), np.float32)
        if x1 - x0 < 2 or y1 - y0 < 2:                                  # the face is outside the frame
            return out, alpha_full
        off = np.array([x0, y0], np.float64)
        size = (y1 - y0, x1 - x0)
        crop = img[y0:y1, x0:x1].astype(np.float32)
        if self.morph and tracked is not None:
            src = np.concatenate([np.asarray(tracked, np.float64)[:, :2], anchors])   # frame pixels
            ringwarp = PiecewiseAffineWarp(np.concatenate([shape, anchors]) - off, self.ring_triangles, shape=size)
            moved = ringwarp.warp(img.astype(np.float32), src)                         # (crop) <- (frame)
            crop = np.where(ringwarp.mask[..., None], moved, crop)
        fw = PiecewiseAffineWarp(shape - off, self.triangles, shape=size)
        face = fw.warp(tex, m.mean_shape_)
        mask = fw.mask.astype(np.uint8)
        if self.feather > 0:
            width_px = self._face_px / max(abs(a), 1e-12)
            dist = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
            alpha = smoothstep(np.clip(dist / max(self.feather * width_px, 1e-6), 0.0, 1.0)).astype(np.float32)
        else:
            alpha = mask.astype(np.float32)
        blend = crop * (1 - alpha[..., None]) + face * alpha[..., None]
        out[y0:y1, x0:x1] = np.clip(np.rint(blend), 0, 255).astype(np.uint8)
        alpha_full[y0:y1, x0:x1] = alpha
        return out, alpha_full
