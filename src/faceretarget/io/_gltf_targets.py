"""New morph target data for a copy of a user's glTF file, each array in the smallest valid form.

:class:`MorphData` takes each new morph target attribute (a ``POSITION`` or ``NORMAL`` delta per vertex of
one primitive, in the primitive's own space) and stores it as the file stores its own data, adding no
extension the file does not already require:

Values
    Quantized like the file's own: ``SHORT`` / ``BYTE`` normalized (``KHR_mesh_quantization``) when the
    primitive's existing targets are (else, for a ``POSITION``, when its base ``POSITION`` is an integer
    type), rounded to that type's step, the step the file's own positions have; an array out of the
    type's range (a normal turning by more than 90 degrees, a delta longer than half the mesh's
    quantization box) is float32 instead.  Otherwise float32.
Which vertices moved
    Quantized: those whose stored delta is not zero (a delta under half a step rounds to zero).  Float:
    those where the file's float32 attribute plus the delta is not the attribute itself (a smaller delta
    changes nothing the renderer can show, so leaving it out changes nothing).
Layout
    The smallest of three: no data at all (every vertex still: an accessor without ``bufferView`` is
    zeros, the specification's own default; one is shared by every all-zero target of a vertex count), a
    sparse accessor (``accessor.sparse``: the moved vertices' indices and values over a zero base), or a
    dense one (every vertex, with ``byteStride`` and ``target`` as vertex data needs).
Compression
    When the file requires ``EXT_meshopt_compression`` (as gltfpack / glTF-Transform files do), the new
    buffer views are meshopt-compressed too (codec version 0, which every decoder reads; the uncompressed
    views point into the file's fallback buffer, grown to hold them), and the layout is chosen by the
    compressed size.  Without it nothing is compressed: a file that loads without a meshopt decoder keeps
    loading without one.

All new arrays of one kind (dense, sparse values, sparse indices; per attribute and component type) share
one buffer view, so the JSON grows by an accessor per target and a handful of views.  The views' bytes
are appended to ``new`` by :meth:`MorphData.finish` with ``buffer`` -1, placed by
``_character_write._attach_glb_buffer`` / ``_write_gltf_json`` like every other new view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MorphData", "Encoding", "FLOAT", "normal_delta"]

FLOAT, BYTE, SHORT, USHORT, UINT = 5126, 5120, 5122, 5123, 5125
_NP = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_MESHOPT = "EXT_meshopt_compression"
_ARRAY_BUFFER = 34962


@dataclass(frozen=True)
class Encoding:
    """The component type a target attribute is stored as (VEC3)."""

    ctype: int = FLOAT
    normalized: bool = False

    @property
    def step(self) -> float:
        """Local units per stored integer (0 for float)."""
        if self.ctype == FLOAT:
            return 0.0
        return 1.0 / np.iinfo(_NP[self.ctype]).max if self.normalized else 1.0

    @property
    def size(self) -> int:
        """Bytes of one VEC3 element, tightly packed."""
        return 3 * np.dtype(_NP[self.ctype]).itemsize

    def stored(self, values: np.ndarray) -> np.ndarray | None:
        """``values`` (n, 3) float as this type stores them; None when one is out of its range."""
        if self.ctype == FLOAT:
            return np.asarray(values, dtype=np.float32)
        q = np.round(np.asarray(values, dtype=np.float64) / self.step)
        info = np.iinfo(_NP[self.ctype])
        lo = -info.max if self.normalized else info.min               # -128 / -32768 normalize below -1
        if q.size and (q.min() < lo or q.max() > info.max):
            return None
        return q.astype(_NP[self.ctype])

    @classmethod
    def of(cls, acc: dict | None) -> Encoding | None:
        """The signed VEC3 type like accessor ``acc`` (an integer one: SHORT / BYTE, its normalization)."""
        if acc is None or int(acc.get("componentType", FLOAT)) == FLOAT:
            return None
        ct = int(acc["componentType"])
        return cls(BYTE if ct in (5120, 5121) else SHORT, bool(acc.get("normalized", False)))


#: The largest angle (degrees) by which a quantized NORMAL target may miss the exact normal at weight 1.
NORMAL_TOLERANCE_DEG = 1.0


def normal_delta(n0: np.ndarray, n1: np.ndarray, enc: Encoding) -> tuple[np.ndarray, Encoding]:
    """The NORMAL target delta turning unit normals ``n0`` (n, 3) into ``n1``, and the type to store it as:
    ``enc`` when it is close enough, else float32.

    A renderer normalizes ``n0 + w * delta``, so ``s * n1 - n0`` for any ``s > 0`` gives ``n1`` at weight 1 as
    well: where ``n1 - n0`` has a component beyond a normalized type's [-1, 1] (the normal turns by more than
    about 60 degrees, in a fold), ``s`` is the largest value up to 1 that brings every component within range;
    the shape at weights 0 and 1 is as exact as the type's step allows, in between such a normal blends a
    little differently.  Where no ``s`` gives the turned normal within :data:`NORMAL_TOLERANCE_DEG` once
    rounded to the type (a normal turned over, on a folded triangle), the whole array is float32, on a grid
    of 2^-15 (finer than SHORT's step, a few thousandths of a degree; the low mantissa bytes then zero, so it
    compresses to half)."""
    d = n1 - n0
    if enc.ctype == FLOAT or not enc.normalized or not len(d):
        return d, enc
    if np.abs(d).max() > 1.0:
        with np.errstate(divide="ignore", invalid="ignore"):
            up = np.where(n1 > 0, (n0 + 1.0) / n1, np.where(n1 < 0, (n0 - 1.0) / n1, np.inf))
        s = np.clip(up.min(axis=1), 0.0, 1.0)[:, None]
        d = np.clip(s * n1 - n0, -1.0, 1.0)
    q = enc.stored(d).astype(np.float64) * enc.step
    got = n0 + q
    ln = np.linalg.norm(got, axis=1)
    live = np.linalg.norm(n1, axis=1) > 0
    cos = np.sum(got * n1, axis=1) / np.where(ln > 0, ln, 1.0)
    if (live & ((ln == 0) | (cos < np.cos(np.radians(NORMAL_TOLERANCE_DEG))))).any():
        return np.round((n1 - n0) * 2.0 ** 15) / 2.0 ** 15, Encoding()
    return d, enc


def _row_stride(size: int) -> int:
    """A stride of whole elements, a multiple of 4 (meshopt's attribute codec works on such rows)."""
    return int(np.lcm(size, 4))


def _meshopt(data: bytes, stride: int, mode: str) -> bytes:
    """``data`` (rows of ``stride`` bytes, or 2- / 4-byte indices) as EXT_meshopt_compression stores it: the
    attribute codec's version 0, which every decoder reads."""
    import meshopt

    if mode == "INDICES":
        return meshopt.encode_gltf_buffer(np.frombuffer(data, _NP[UINT if stride == 4 else USHORT]), mode)
    return meshopt.encode_gltf_buffer(np.frombuffer(data, np.uint8).reshape(-1, stride), mode, 0)


class _View:
    """The bytes of one new buffer view, its JSON and how it is compressed."""

    def __init__(self, js: dict, kind: str, stride: int, mode: str = "ATTRIBUTES"):
        self.kind, self.stride, self.mode = kind, stride, mode
        self.data = bytearray()
        js["bufferViews"].append({"buffer": -1, "byteOffset": 0, "byteLength": 0})
        self.index = len(js["bufferViews"]) - 1

    def put(self, data: bytes, align: int) -> int:
        self.data.extend(b"\0" * ((-len(self.data)) % align))
        off = len(self.data)
        self.data.extend(data)
        return off


class MorphData:
    """New morph target accessors appended to ``js`` (module docstring); their bytes go to ``new``."""

    def __init__(self, js: dict, new: bytearray):
        self.js, self.new = js, new
        js.setdefault("bufferViews", [])
        js.setdefault("accessors", [])
        self.meshopt = _MESHOPT in js.get("extensionsRequired", [])
        self._views: dict[tuple, _View] = {}
        self._zeros: dict[tuple, int] = {}
        self.counts = {"zero": 0, "sparse": 0, "dense": 0}

    # ------------------------------------------------------------------------------------------ accessors
    def zeros(self, count: int, position: bool) -> int:
        """An all-zero VEC3 accessor of ``count`` (no data: zeros by the specification), shared."""
        key = (int(count), position)
        if key not in self._zeros:
            acc = {"componentType": FLOAT, "count": int(count), "type": "VEC3"}
            if position:
                acc["min"], acc["max"] = [0.0] * 3, [0.0] * 3
            self.js["accessors"].append(acc)
            self._zeros[key] = len(self.js["accessors"]) - 1
        return self._zeros[key]

    def add(self, values: np.ndarray, enc: Encoding, base: np.ndarray, *, position: bool) -> int:
        """One target attribute: ``values`` (n, 3) local deltas over ``base`` (n, 3), the primitive's own
        attribute values (positions, or unit normals); the accessor's index."""
        values = np.asarray(values, dtype=np.float64)
        n = len(values)
        stored = enc.stored(values)
        if stored is None:                                    # out of the quantized range: float32
            enc = Encoding()
            stored = enc.stored(values)
        if enc.ctype == FLOAT:
            b = np.asarray(base, dtype=np.float32)
            moved = ((b + stored) != b).any(axis=1)
            stored = np.where(moved[:, None], stored, np.float32(0))
        else:
            moved = (stored != 0).any(axis=1)
        idx = np.flatnonzero(moved)
        if not len(idx):
            self.counts["zero"] += 1
            return self.zeros(n, position)
        acc = {"componentType": enc.ctype, "count": n, "type": "VEC3"}
        if enc.normalized:
            acc["normalized"] = True
        if position:
            lo, hi = stored.min(axis=0), stored.max(axis=0)
            num = float if enc.ctype == FLOAT else int
            acc["min"], acc["max"] = [num(x) for x in lo], [num(x) for x in hi]
        dense, sparse = self._candidates(stored, idx, enc, n)
        if self._cost(*sparse) <= self._cost(*dense):
            (vkey, vdata, vstride, valign), (ikey, idata, istride, ialign) = sparse
            iview, vview = self._view(ikey, istride, "INDICES"), self._view(vkey, vstride)
            acc["sparse"] = {
                "count": len(idx),
                "indices": {"bufferView": iview.index, "byteOffset": iview.put(idata, ialign),
                            "componentType": UINT if istride == 4 else USHORT},
                "values": {"bufferView": vview.index, "byteOffset": vview.put(vdata, valign)}}
            self.counts["sparse"] += 1
        else:
            ((key, data, stride, align),) = dense
            view = self._view(key, stride)
            acc["bufferView"], acc["byteOffset"] = view.index, view.put(data, align)
            self.counts["dense"] += 1
        for part in [acc.get("sparse", {}).get("indices"), acc.get("sparse", {}).get("values"), acc]:
            if part is not None and part.get("byteOffset") == 0:
                del part["byteOffset"]
        self.js["accessors"].append(acc)
        return len(self.js["accessors"]) - 1

    def _candidates(self, stored: np.ndarray, idx: np.ndarray, enc: Encoding, n: int):
        """The dense and the sparse form: ``[(view key, bytes, row stride, alignment), ...]`` each."""
        size = enc.size
        csize = size // 3
        vstride = (size + 3) // 4 * 4                          # a vertex attribute's elements start at 4 bytes
        rows = np.zeros((n, vstride // csize), dtype=stored.dtype)
        rows[:, :3] = stored
        dense = [(("dense", enc, vstride), rows.tobytes(), vstride, vstride)]
        wide = n > 65536
        istride = 4 if wide else 2
        ibytes = idx.astype(np.uint32 if wide else np.uint16).tobytes()
        vbytes = np.ascontiguousarray(stored[idx]).tobytes()
        sparse = [(("values", enc, _row_stride(size)), vbytes, _row_stride(size), csize),
                  (("indices", istride), ibytes, istride, istride)]
        return dense, sparse

    def _cost(self, *parts) -> int:
        """Bytes the parts add to the file (compressed when the file's views are)."""
        total = 0
        for key, data, stride, _align in parts:
            if not self.meshopt:
                total += len(data)
            else:
                pad = b"\0" * ((-len(data)) % stride)
                total += len(_meshopt(data + pad, stride, "INDICES" if key[0] == "indices" else "ATTRIBUTES"))
        return total

    def _view(self, key: tuple, stride: int, mode: str = "ATTRIBUTES") -> _View:
        if key not in self._views:
            self._views[key] = _View(self.js, key[0], stride, mode)
        return self._views[key]

    # ------------------------------------------------------------------------------------------ bytes
    def finish(self) -> None:
        """Append every view's bytes to ``new`` (compressed when the file's are) and fill in the views."""
        views = self.js["bufferViews"]
        fallback = self._fallback() if self.meshopt and self._views else None
        for view in self._views.values():
            data = bytes(view.data)
            data += b"\0" * ((-len(data)) % view.stride)
            v = views[view.index]
            if view.kind == "dense":
                v["byteStride"], v["target"] = view.stride, _ARRAY_BUFFER
            if fallback is None:
                self.new.extend(b"\0" * ((-len(self.new)) % 4))
                v.update(buffer=-1, byteOffset=len(self.new), byteLength=len(data))
                self.new.extend(data)
                continue
            enc = _meshopt(data, view.stride, view.mode)
            fb = self.js["buffers"][fallback]
            start = (int(fb.get("byteLength", 0)) + 15) // 16 * 16
            v.update(buffer=fallback, byteOffset=start, byteLength=len(data))
            fb["byteLength"] = start + len(data)
            self.new.extend(b"\0" * ((-len(self.new)) % 4))
            v.setdefault("extensions", {})[_MESHOPT] = {
                "buffer": -1, "byteOffset": len(self.new), "byteLength": len(enc), "byteStride": view.stride,
                "count": len(data) // view.stride, "mode": view.mode}
            self.new.extend(enc)

    def _fallback(self) -> int:
        """The file's meshopt fallback buffer (a placeholder without data), added if it has none."""
        buffers = self.js.setdefault("buffers", [])
        for i in range(len(buffers) - 1, -1, -1):
            if buffers[i].get("extensions", {}).get(_MESHOPT, {}).get("fallback") and "uri" not in buffers[i]:
                return i
        buffers.append({"byteLength": 0, "extensions": {_MESHOPT: {"fallback": True}}})
        return len(buffers) - 1
