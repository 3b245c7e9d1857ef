"""glTF 2.0 / VRM characters read whole: every node, mesh primitive, skin, morph target and texture.

:func:`read_gltf_character` reads a ``.glb``, a ``.gltf`` (with its ``.bin`` and images beside it or as
data URIs) or a ``.vrm`` (VRM 0.x and 1.0 are glTF binaries with a ``VRM`` / ``VRMC_vrm`` extension)
into a :class:`~faceretarget.character.Character`:

* Every node of the scene that draws a mesh becomes a :class:`~faceretarget.character.SceneMesh`
  (a mesh used by several nodes gives one per node): its primitives joined, posed at rest in world
  space (the node's world matrix, or for a skinned mesh linear blend skinning with the skeleton's rest
  pose and the inverse bind matrices, the node's own transform ignored as the specification says), in
  metres.  Morph targets become world-space deltas (the skinning's linear part applied) under their
  exact names (``mesh.extras.targetNames``; ``target{k}`` when the file has none).
* Every node is a :class:`~faceretarget.character.Joint` (rest world matrix), so the head, neck, jaw
  and eye joints are found by name (:func:`faceretarget.names.find_joints`) or, in a VRM, from its
  humanoid map.
* Decoded: ``EXT_meshopt_compression`` (the ``meshopt`` package, meshoptimizer's decoder),
  ``KHR_mesh_quantization`` (normalised and plain integer attributes), ``KHR_draco_mesh_compression``
  (``DracoPy``), sparse accessors, triangle strips and fans, ``KHR_texture_transform`` (applied to the
  UVs), ``EXT_texture_webp`` and PNG / JPEG images (Pillow).  An extension the file *requires* that
  changes geometry and is not in this list is an error naming it; an image that cannot be had
  (``KHR_texture_basisu``, a missing file) is a note, and the mesh renders in its base colour.
* VRM: 0.x faces -Z (its front is known), 1.0 faces +Z; the humanoid bones give the head, neck, jaw
  and eye joints; the expressions (``blendShapeMaster`` / ``expressions``) are kept with their binds.
"""

from __future__ import annotations

import base64
import json
import os
import struct
import urllib.parse
from pathlib import Path

import numpy as np

from ..character import Character, EncodedImage, Joint, Material, SceneMesh
from ..errors import FaceRetargetError, InputFileError, MissingDependencyError, excerpt
from ..mesh import Mesh
from ..optional import optional_import

__all__ = ["read_gltf_character", "GltfDocument", "GLTF_DECODED_EXTENSIONS"]

_GLB_MAGIC, _JSON, _BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
_DTYPE = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: Extensions this reader decodes or may safely ignore (materials, lights, metadata).
GLTF_DECODED_EXTENSIONS = frozenset({
    "EXT_meshopt_compression", "KHR_mesh_quantization", "KHR_draco_mesh_compression", "KHR_texture_transform",
    "EXT_texture_webp", "KHR_materials_unlit", "KHR_materials_emissive_strength", "KHR_materials_ior",
    "KHR_materials_specular", "KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_clearcoat",
    "KHR_materials_sheen", "KHR_materials_iridescence", "KHR_materials_anisotropy", "KHR_materials_variants",
    "KHR_materials_pbrSpecularGlossiness", "KHR_lights_punctual", "KHR_xmp_json_ld", "KHR_texture_basisu",
    "MSFT_texture_dds", "EXT_lights_image_based", "KHR_animation_pointer", "VRM", "VRMC_vrm",
    "VRMC_springBone", "VRMC_materials_mtoon", "VRMC_node_constraint", "VRMC_vrm_animation",
    "KHR_materials_dispersion", "EXT_mesh_gpu_instancing",
})


class GltfDocument:
    """A glTF file's JSON and binary data, with decoded accessors (also used to write back)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.folder = self.path.parent
        raw = self._read_bytes(self.path)
        self.is_glb = raw[:4] == b"glTF"
        self.bin: bytes = b""
        if self.is_glb:
            self.json, self.bin = self._parse_glb(raw)
        else:
            try:
                self.json = json.loads(raw.decode("utf-8-sig"))
            except ValueError as e:
                raise InputFileError(f"{self.path}: neither a glTF binary nor glTF JSON ({excerpt(e, 80)})") from e
        if not isinstance(self.json, dict) or "asset" not in self.json:
            raise InputFileError(f"{self.path}: not a glTF document (no 'asset')")
        version = str(self.json.get("asset", {}).get("version", ""))
        if not version.startswith("2."):
            raise InputFileError(f"{self.path}: glTF version {excerpt(version)}, only 2.x is read")
        unknown = sorted(set(self.json.get("extensionsRequired", [])) - GLTF_DECODED_EXTENSIONS)
        if unknown:
            raise InputFileError(f"{self.path}: requires the glTF extension(s) {', '.join(unknown)}, which this reader "
                                 f"does not decode (it decodes {', '.join(sorted(GLTF_DECODED_EXTENSIONS)[:6])} ...); "
                                 "re-export without them (e.g. gltf-transform copy)")
        self._buffers: dict[int, bytes] = {}
        self._views: dict[int, bytes] = {}
        self.notes: list[str] = []

    # ----------------------------------------------------------------------------- raw data
    def _read_bytes(self, p: Path) -> bytes:
        try:
            return p.read_bytes()
        except FileNotFoundError:
            raise InputFileError(f"{p}: file not found") from None
        except IsADirectoryError:
            raise InputFileError(f"{p}: is a folder, not a glTF file") from None
        except OSError as e:
            raise InputFileError(f"{p}: cannot be read ({e.strerror or e})") from None

    def _parse_glb(self, data: bytes) -> tuple[dict, bytes]:
        if len(data) < 20:
            raise InputFileError(f"{self.path}: too short to be a .glb file")
        magic, version, total = struct.unpack_from("<III", data, 0)
        if magic != _GLB_MAGIC or version != 2:
            raise InputFileError(f"{self.path}: not a glTF 2.0 binary file (version {version})")
        if total > len(data):
            raise InputFileError(f"{self.path}: truncated ({len(data)} of {total} bytes)")
        off, js, binchunk = 12, None, b""
        while off + 8 <= total:
            n, kind = struct.unpack_from("<II", data, off)
            body = data[off + 8: off + 8 + n]
            if kind == _JSON and js is None:
                try:
                    js = json.loads(body.decode("utf-8"))
                except ValueError as e:
                    raise InputFileError(f"{self.path}: the JSON chunk is not UTF-8 JSON ({excerpt(e, 80)})") from e
            elif kind == _BIN and not binchunk:
                binchunk = body
            off += 8 + n + (-n % 4 if off + 8 + n < total and n % 4 else 0)
        if js is None:
            raise InputFileError(f"{self.path}: no JSON chunk")
        return js, binchunk

    def uri_bytes(self, uri: str, what: str) -> bytes:
        if uri.startswith("data:"):
            head, _, data = uri.partition(",")
            try:
                return base64.b64decode(data) if head.endswith(";base64") else urllib.parse.unquote_to_bytes(data)
            except ValueError as e:
                raise InputFileError(f"{self.path}: {what} has a malformed data URI ({excerpt(e, 60)})") from e
        p = self.folder / urllib.parse.unquote(uri)
        if not p.is_file():
            raise InputFileError(f"{self.path}: {what} '{excerpt(uri, 60)}' not found beside it ({p})")
        return self._read_bytes(p)

    def buffer(self, i: int) -> bytes:
        if i not in self._buffers:
            b = self.json["buffers"][i]
            if "uri" in b:
                data = self.uri_bytes(b["uri"], f"buffer {i}")
            elif i == 0 and self.is_glb:
                data = self.bin
            elif b.get("extensions", {}).get("EXT_meshopt_compression", {}).get("fallback"):
                data = b""                                  # a meshopt fallback: only decoded views refer to it
            else:
                raise InputFileError(f"{self.path}: buffer {i} has no data (no uri, and not the GLB binary chunk)")
            if len(data) < int(b.get("byteLength", 0)) and data:
                raise InputFileError(f"{self.path}: buffer {i} holds {len(data)} of its {b.get('byteLength')} bytes")
            self._buffers[i] = data
        return self._buffers[i]

    def view(self, i: int) -> bytes:
        if i not in self._views:
            v = self.json["bufferViews"][i]
            ext = v.get("extensions", {}).get("EXT_meshopt_compression")
            if ext is not None:
                self._views[i] = self._meshopt(i, ext)
            else:
                data = self.buffer(int(v.get("buffer", 0)))
                a = int(v.get("byteOffset", 0))
                n = int(v["byteLength"])
                if a < 0 or a + n > len(data):
                    raise InputFileError(f"{self.path}: bufferView {i} ({n} bytes at {a}) lies outside buffer "
                                         f"{v.get('buffer', 0)} of {len(data)} bytes")
                self._views[i] = data[a:a + n]
        return self._views[i]

    def _meshopt(self, i: int, ext: dict) -> bytes:
        meshopt = optional_import("meshopt", "reading EXT_meshopt_compression (pip install meshopt)")
        src = self.buffer(int(ext.get("buffer", 0)))
        a, n = int(ext.get("byteOffset", 0)), int(ext["byteLength"])
        count, stride = int(ext["count"]), int(ext["byteStride"])
        mode, filt = ext.get("mode", "ATTRIBUTES"), ext.get("filter", "NONE")
        if a < 0 or a + n > len(src):
            raise InputFileError(f"{self.path}: compressed bufferView {i} lies outside its buffer")
        try:
            out = meshopt.decode_gltf_buffer(src[a:a + n], count, stride, mode, None if filt == "NONE" else filt)
        except (ValueError, RuntimeError) as e:
            raise InputFileError(f"{self.path}: bufferView {i}: EXT_meshopt_compression data does not decode "
                                 f"({excerpt(e, 80)})") from e
        return np.ascontiguousarray(out).tobytes()

    def accessor(self, i: int, *, normalize: bool = True) -> np.ndarray:
        """Accessor ``i`` as ``(count, ncomp)`` (float64 for float or normalised data, else its integers)."""
        acc = self.json["accessors"][i]
        dt = np.dtype(_DTYPE[acc["componentType"]]).newbyteorder("<")
        n = _NCOMP[acc["type"]]
        count = int(acc["count"])
        if not 0 <= count <= 1 << 27:
            raise InputFileError(f"{self.path}: accessor {i} has count {excerpt(count)}")
        if "bufferView" in acc:
            vi = int(acc["bufferView"])
            data = self.view(vi)
            view = self.json["bufferViews"][vi]
            stride = int(view.get("byteStride", 0)) or n * dt.itemsize
            ext = view.get("extensions", {}).get("EXT_meshopt_compression")
            if ext is not None:
                stride = int(view.get("byteStride", ext.get("byteStride", stride)))
            start = int(acc.get("byteOffset", 0))
            need = start + max(count - 1, 0) * stride + n * dt.itemsize * (count > 0)
            if start < 0 or need > len(data):
                raise InputFileError(f"{self.path}: accessor {i} ({count} x {n} {dt}) lies outside bufferView {vi} "
                                     f"of {len(data)} bytes")
            arr = np.ndarray((count, n), dt, buffer=data, offset=start, strides=(stride, dt.itemsize)).copy()
        else:
            arr = np.zeros((count, n), dt)
        sp = acc.get("sparse")
        if sp:
            k = int(sp["count"])
            it = np.dtype(_DTYPE[sp["indices"]["componentType"]]).newbyteorder("<")
            idx = np.frombuffer(self.view(int(sp["indices"]["bufferView"])), it, count=k,
                                offset=int(sp["indices"].get("byteOffset", 0))).astype(np.int64)
            vals = np.frombuffer(self.view(int(sp["values"]["bufferView"])), dt, count=k * n,
                                 offset=int(sp["values"].get("byteOffset", 0))).reshape(k, n)
            if idx.size and (idx.min() < 0 or idx.max() >= count):
                raise InputFileError(f"{self.path}: accessor {i}: a sparse index is outside 0..{count - 1}")
            arr[idx] = vals
        if acc.get("normalized") and dt.kind in "iu" and normalize:
            m = float(np.iinfo(dt).max)
            out = arr.astype(np.float64) / m
            return np.maximum(out, -1.0) if dt.kind == "i" else out
        if dt.kind == "f":
            with np.errstate(invalid="ignore"):
                arr = arr.astype(np.float64)
            if not np.isfinite(arr).all():
                raise InputFileError(f"{self.path}: accessor {i} holds NaN or infinite values")
        return arr


# ------------------------------------------------------------------------------------------ nodes
def _node_local(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T      # column-major
    from scipy.spatial.transform import Rotation

    M = np.eye(4)
    q = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    s = np.asarray(node.get("scale", [1.0, 1.0, 1.0]), dtype=np.float64)
    if np.linalg.norm(q) > 0:
        M[:3, :3] = Rotation.from_quat(q).as_matrix() * s
    else:
        M[:3, :3] = np.diag(s)
    M[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return M


def _world_matrices(doc: GltfDocument) -> tuple[list[np.ndarray], list[np.ndarray], list[int]]:
    nodes = doc.json.get("nodes", [])
    parent = [-1] * len(nodes)
    for i, n in enumerate(nodes):
        for c in n.get("children", []):
            if not (isinstance(c, int) and 0 <= c < len(nodes)):
                raise InputFileError(f"{doc.path}: node {i} has child {excerpt(c)}, not a node index")
            if parent[c] != -1:
                raise InputFileError(f"{doc.path}: node {c} has two parents ({parent[c]} and {i})")
            parent[c] = i
    local = [_node_local(n) for n in nodes]
    world: list[np.ndarray | None] = [None] * len(nodes)

    def get(i: int, depth: int = 0) -> np.ndarray:
        if world[i] is None:
            if depth > 512:
                raise InputFileError(f"{doc.path}: the node hierarchy has a cycle through node {i}")
            world[i] = local[i] if parent[i] < 0 else get(parent[i], depth + 1) @ local[i]
        return world[i]

    return [get(i) for i in range(len(nodes))], local, parent


def _scene_nodes(doc: GltfDocument, parent: list[int]) -> list[int]:
    """The nodes of the default scene (all nodes reachable from its roots), in order."""
    scenes = doc.json.get("scenes", [])
    nodes = doc.json.get("nodes", [])
    if not scenes:
        return list(range(len(nodes)))
    roots = scenes[int(doc.json.get("scene", 0))].get("nodes", [])
    keep, stack = set(), list(roots)
    while stack:
        i = stack.pop()
        if i in keep:
            continue
        keep.add(i)
        stack.extend(nodes[i].get("children", []))
    return sorted(keep)


# ------------------------------------------------------------------------------------------ meshes
def _triangles(mode: int, idx: np.ndarray) -> np.ndarray | None:
    if mode == 4:
        return idx[: len(idx) // 3 * 3].reshape(-1, 3)
    if mode == 5:                                             # strip: alternate winding
        n = len(idx) - 2
        if n <= 0:
            return np.zeros((0, 3), np.int64)
        a, b, c = idx[:-2], idx[1:-1], idx[2:]
        odd = np.arange(n) % 2 == 1
        t = np.stack([a, np.where(odd, c, b), np.where(odd, b, c)], axis=1)
        return t
    if mode == 6:                                             # fan
        if len(idx) < 3:
            return np.zeros((0, 3), np.int64)
        return np.stack([np.full(len(idx) - 2, idx[0]), idx[1:-1], idx[2:]], axis=1)
    return None


def _draco(doc: GltfDocument, prim: dict, ext: dict) -> tuple[dict, np.ndarray]:
    dracopy = optional_import("DracoPy", "reading KHR_draco_mesh_compression (pip install DracoPy)")
    data = doc.view(int(ext["bufferView"]))
    try:
        dm = dracopy.decode(data)
    except Exception as e:  # DracoPy raises its own failure types from C++
        raise InputFileError(f"{doc.path}: Draco-compressed primitive does not decode ({excerpt(e, 80)})") from e
    attrs: dict[str, np.ndarray] = {}
    for name, uid in ext.get("attributes", {}).items():
        a = dm.get_attribute_by_unique_id(int(uid))
        if a is None:
            continue
        arr = np.asarray(a["data"], dtype=np.float64)
        acc = doc.json["accessors"][prim["attributes"][name]] if name in prim.get("attributes", {}) else {}
        if acc.get("normalized") and np.issubdtype(np.asarray(a["data"]).dtype, np.integer):
            arr = arr / float(np.iinfo(np.asarray(a["data"]).dtype).max)
        attrs[name] = arr.reshape(len(arr), -1)
    faces = np.asarray(dm.faces, dtype=np.int64).reshape(-1)
    return attrs, faces


def _uv_transform(uv: np.ndarray, tex: dict) -> np.ndarray:
    t = tex.get("extensions", {}).get("KHR_texture_transform")
    if not t:
        return uv
    off = np.asarray(t.get("offset", [0.0, 0.0]), dtype=np.float64)
    r = float(t.get("rotation", 0.0))
    sc = np.asarray(t.get("scale", [1.0, 1.0]), dtype=np.float64)
    c, s = np.cos(r), np.sin(r)
    R = np.array([[c, s], [-s, c]])
    return (uv * sc) @ R.T + off


def _material(doc: GltfDocument, mi: int | None, images: dict) -> tuple[Material, int, dict]:
    """The material (base colour and image, alpha mode, sides), the TEXCOORD set it samples, and its
    texture info."""
    if mi is None:
        return Material("default", np.ones(4), double_sided=False), 0, {}   # glTF's default material
    m = doc.json["materials"][mi]
    mode = str(m.get("alphaMode", "OPAQUE")).upper()
    if mode not in ("OPAQUE", "MASK", "BLEND"):
        doc.notes.append(f"material '{m.get('name', mi)}': alphaMode '{excerpt(mode, 20)}' is not glTF's; drawn "
                         "opaque")
        mode = "OPAQUE"
    sides = {"alpha_mode": mode, "alpha_cutoff": float(m.get("alphaCutoff", 0.5)),
             "double_sided": bool(m.get("doubleSided", False))}
    pbr = m.get("pbrMetallicRoughness", {})
    color = np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), dtype=np.float64)
    tex = pbr.get("baseColorTexture")
    image = None
    texcoord = 0
    if tex is not None:
        texcoord = int(tex.get("extensions", {}).get("KHR_texture_transform", {}).get("texCoord",
                                                                                      tex.get("texCoord", 0)))
        t = doc.json.get("textures", [])[int(tex["index"])]
        exts = t.get("extensions", {})
        src = t.get("source")
        for e in ("EXT_texture_webp", "MSFT_texture_dds"):
            if e in exts and "source" in exts[e]:
                src = exts[e]["source"]
                break
        if src is None and "KHR_texture_basisu" in exts:
            doc.notes.append(f"material '{m.get('name', mi)}': KHR_texture_basisu textures are not decoded; "
                             "rendered in its base colour")
        if src is not None:
            src = int(src)
            if src not in images:
                images[src] = _lazy_image(doc, src)
            image = images[src]
    return Material(str(m.get("name", f"material{mi}")), color, image, **sides), texcoord, tex or {}


def _lazy_image(doc: GltfDocument, i: int) -> EncodedImage | None:
    img = doc.json.get("images", [])[i]
    name = img.get("name") or img.get("uri") or f"image {i}"
    try:
        if "bufferView" in img:
            return EncodedImage(bytes(doc.view(int(img["bufferView"]))), None, name, doc.notes)
        if "uri" in img:
            uri = img["uri"]
            if uri.startswith("data:"):
                return EncodedImage(doc.uri_bytes(uri, f"image {i}"), None, name, doc.notes)
            p = doc.folder / urllib.parse.unquote(uri)
            if not p.is_file():
                raise InputFileError(f"{doc.path}: image '{excerpt(uri, 60)}' not found beside it ({p})")
            return EncodedImage(None, str(p), name, doc.notes)
    except InputFileError as e:
        doc.notes.append(f"missing texture: {e}; rendered in its base colour")
        return None
    doc.notes.append(f"image '{name}' has no data: rendered without it")
    return None


def _primitive(doc: GltfDocument, mesh_i: int, p_i: int, prim: dict, images: dict):
    """One primitive: positions (V, 3), triangles (F, 3), uvs (V, 2) or None, material, targets
    (K, V, 3), joints/weights or None."""
    attrs_idx = prim.get("attributes", {})
    mode = int(prim.get("mode", 4))
    ext = prim.get("extensions", {})
    draco = ext.get("KHR_draco_mesh_compression")
    if draco is not None:
        dattrs, faces = _draco(doc, prim, draco)

        def attr(name):
            if name in dattrs:
                return dattrs[name]
            return doc.accessor(attrs_idx[name]) if name in attrs_idx else None
        idx = faces
    else:
        def attr(name):
            return doc.accessor(attrs_idx[name]) if name in attrs_idx else None
        idx = None
    if "POSITION" not in attrs_idx and not (draco and "POSITION" in dattrs):
        return None
    pos = attr("POSITION").astype(np.float64)[:, :3]
    V = len(pos)
    if idx is None:
        idx = (doc.accessor(prim["indices"]).astype(np.int64).reshape(-1) if "indices" in prim
               else np.arange(V, dtype=np.int64))
    tri = _triangles(mode, idx)
    if tri is None:
        doc.notes.append(f"mesh {mesh_i} primitive {p_i}: mode {mode} (points or lines) is not a surface; left out")
        return None
    if tri.size and (tri.min() < 0 or tri.max() >= V):
        raise InputFileError(f"{doc.path}: mesh {mesh_i} primitive {p_i}: an index is outside 0..{V - 1}")
    mat, texcoord, tex = _material(doc, prim.get("material"), images)
    uv = attr(f"TEXCOORD_{texcoord}")
    if uv is not None:
        uv = _uv_transform(uv[:, :2].astype(np.float64), tex)
    col = attr("COLOR_0")
    if col is not None:                                       # linear RGB(A), normalised when integer
        col = np.clip(col.astype(np.float64), 0.0, 1.0)
        col = np.concatenate([col[:, :3], col[:, 3:4] if col.shape[1] > 3 else np.ones((V, 1))], axis=1)
    targets = []
    for k, tg in enumerate(prim.get("targets", [])):
        if "POSITION" in tg:
            d = doc.accessor(tg["POSITION"])[:, :3].astype(np.float64)
            if len(d) != V:
                raise InputFileError(f"{doc.path}: mesh {mesh_i} primitive {p_i} morph target {k} has {len(d)} "
                                     f"positions for {V} vertices")
        else:
            d = np.zeros((V, 3))
        targets.append(d)
    joints = weights = None
    sets = sorted({int(a.split("_")[1]) for a in attrs_idx if a.startswith("JOINTS_")})
    if sets:
        js, ws = [], []
        for s in sets:
            if f"WEIGHTS_{s}" not in attrs_idx:
                continue
            js.append(doc.accessor(attrs_idx[f"JOINTS_{s}"], normalize=False).astype(np.int64)[:, :4])
            ws.append(doc.accessor(attrs_idx[f"WEIGHTS_{s}"]).astype(np.float64)[:, :4])
        if js:
            joints, weights = np.concatenate(js, axis=1), np.concatenate(ws, axis=1)
    return pos, tri, uv, mat, targets, joints, weights, col


def _skin_matrices(doc: GltfDocument, skin_i: int, world: list[np.ndarray]) -> tuple[np.ndarray, list[int]]:
    skin = doc.json["skins"][skin_i]
    joints = [int(j) for j in skin["joints"]]
    if "inverseBindMatrices" in skin:
        ibm = doc.accessor(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
        if len(ibm) < len(joints):
            raise InputFileError(f"{doc.path}: skin {skin_i} has {len(ibm)} inverse bind matrices for "
                                 f"{len(joints)} joints")
    else:
        ibm = np.broadcast_to(np.eye(4), (len(joints), 4, 4))
    return np.stack([world[j] @ ibm[k] for k, j in enumerate(joints)]), joints


def _pose(doc: GltfDocument, node_i: int, node: dict, pos: np.ndarray, deltas: np.ndarray, joints, weights,
          world: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Rest pose in world space: (positions, deltas, skin joints as node indices, skin weights)."""
    if "skin" in node and joints is not None:
        J, jnodes = _skin_matrices(doc, int(node["skin"]), world)
        if joints.size and (joints.min() < 0 or joints.max() >= len(J)):
            raise InputFileError(f"{doc.path}: node {node_i}: a JOINTS index is outside the skin's {len(J)} joints")
        w = weights.copy()
        tot = w.sum(axis=1, keepdims=True)
        w = np.where(tot > 0, w / np.where(tot > 0, tot, 1.0), 0.0)
        none = tot[:, 0] <= 0
        M = (w[:, :, None, None] * J[joints]).sum(axis=1)             # (V, 4, 4)
        if none.any():
            M[none] = world[node_i]
        L = M[:, :3, :3]
        p = (L * pos[:, None, :]).sum(axis=2) + M[:, :3, 3]
        d = _apply_linear(L, deltas)
        top = np.argsort(-weights, axis=1)[:, :4]
        jn = np.asarray(jnodes)[np.take_along_axis(joints, top, axis=1)]
        return p, d, jn, np.take_along_axis(w, top, axis=1)
    G = world[node_i]
    p = pos @ G[:3, :3].T + G[:3, 3]
    d = deltas @ G[:3, :3].T if len(deltas) else deltas
    return p, d, None, None


def _apply_linear(L: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """Per-vertex linear maps ``L`` (V, 3, 3) applied to deltas (K, V, 3), on the vertices some shape moves
    (a body mesh's face shapes move a fraction of it), one row of L at a time."""
    out = np.zeros(deltas.shape, np.float32)
    if not deltas.size:
        return out
    moved = np.flatnonzero(np.abs(deltas).max(axis=(0, 2)) > 0)
    d = deltas[:, moved].astype(np.float32)
    Lm = L[moved].astype(np.float32)
    for m in range(3):
        out[:, moved, m] = (d * Lm[None, :, m, :]).sum(axis=2)
    return out


def _target_names(doc: GltfDocument, mesh: dict, K: int) -> list[str]:
    names = mesh.get("extras", {}).get("targetNames")
    if not names:
        prim = (mesh.get("primitives") or [{}])[0]
        names = prim.get("extras", {}).get("targetNames")
    if not (isinstance(names, list) and len(names) == K and all(isinstance(n, str) for n in names)):
        if names:
            doc.notes.append(f"mesh '{mesh.get('name', '')}': targetNames does not name its {K} morph targets; "
                             "called target0 ...")
        names = [f"target{k}" for k in range(K)]
    return [str(n) for n in names]


def read_gltf_character(path: str | os.PathLike) -> Character:
    """Read a ``.glb`` / ``.gltf`` / ``.vrm`` character whole (module docstring).

    Returns
    -------
    Character
        ``format`` ``"gltf"``, ``"vrm0"`` or ``"vrm1"``; meshes in metres in the file's world frame
        (+Y up); every node a joint (``ref`` ``"node:i"``).

    Raises
    ------
    InputFileError
        Not a glTF 2.0 file, a malformed one (naming the node, mesh, accessor or buffer), or an
        extension it requires that this reader does not decode.
    """
    path = Path(path)
    try:
        return _read(path)
    except FaceRetargetError as e:
        if str(path) in str(e):
            raise
        raise InputFileError(f"{path}: {e}") from e
    except MissingDependencyError:
        raise
    except (KeyError, IndexError, TypeError, ValueError, AttributeError, struct.error, OverflowError) as e:
        raise InputFileError(f"{path}: malformed glTF ({type(e).__name__}: {excerpt(e, 80)})") from e


def _read(path: Path) -> Character:
    doc = GltfDocument(path)
    js = doc.json
    used = set(js.get("extensionsUsed", []))
    world, local, parent = _world_matrices(doc)
    nodes = js.get("nodes", [])
    in_scene = _scene_nodes(doc, parent)
    images: dict[int, np.ndarray | None] = {}
    meshes: list[SceneMesh] = []
    node_names = [str(n.get("name") or f"node{i}") for i, n in enumerate(nodes)]
    for ni in in_scene:
        node = nodes[ni]
        if "mesh" not in node:
            continue
        mi = int(node["mesh"])
        gm = js["meshes"][mi]
        parts = []
        for p_i, prim in enumerate(gm.get("primitives", [])):
            r = _primitive(doc, mi, p_i, prim, images)
            if r is not None:
                parts.append(r)
        if not parts:
            continue
        K = max(len(p[4]) for p in parts)
        if any(len(p[4]) != K for p in parts):
            doc.notes.append(f"mesh '{gm.get('name', mi)}': primitives have different morph target counts; "
                             "the missing ones are zero")
        pos, tris, uvs, mats, tmat, tg, js_, ws_, cols = [], [], [], [], [], [], [], [], []
        off = 0
        for k, (p, t, uv, mat, targets, jn, wt, col) in enumerate(parts):
            cols.append(col if col is not None else np.ones((len(p), 4)))
            pos.append(p)
            tris.append(t + off)
            uvs.append(uv if uv is not None else np.zeros((len(p), 2)))
            mats.append(mat)
            tmat.append(np.full(len(t), k))
            tg.append(np.stack(targets + [np.zeros_like(p)] * (K - len(targets))) if K else np.zeros((0, len(p), 3)))
            js_.append(jn if jn is not None else np.zeros((len(p), 4), np.int64))
            ws_.append(wt if wt is not None else np.zeros((len(p), 4)))
            off += len(p)
        P = np.concatenate(pos)
        T = np.concatenate(tris)
        D = np.concatenate(tg, axis=1)
        skinned = "skin" in node and any(p[5] is not None for p in parts)
        J = np.concatenate([j[:, :4] if j.shape[1] >= 4 else np.pad(j, ((0, 0), (0, 4 - j.shape[1])))
                            for j in js_]) if skinned else None
        W = np.concatenate([w[:, :4] if w.shape[1] >= 4 else np.pad(w, ((0, 0), (0, 4 - w.shape[1])))
                            for w in ws_]) if skinned else None
        P, D, jn, jw = _pose(doc, ni, node, P, D, J, W, world)
        has_uv = any(p[2] is not None for p in parts)
        UV = np.concatenate(uvs) if has_uv else None
        m = Mesh(P, np.full(len(T), 3), T.reshape(-1), UV, T.reshape(-1) if has_uv else None,
                 name=node_names[ni])
        rigid = None
        if jn is not None:
            dom = np.unique(jn[:, 0][jw[:, 0] > 0.999])
            if len(dom) == 1 and (jw[:, 0] > 0.999).all():
                rigid = node_names[int(dom[0])]
        meshes.append(SceneMesh(node_names[ni], f"node:{ni}", m, _target_names(doc, gm, K), D.astype(np.float32),
                                mats, np.concatenate(tmat), joint=rigid,
                                skin_joints=jn, skin_weights=jw,
                                vertex_colors=np.concatenate(cols) if any(p[7] is not None for p in parts) else None))
    joints = [Joint(node_names[i], parent[i], world[i], f"node:{i}", local[i]) for i in range(len(nodes))]
    fmt, up, front = "gltf", np.array([0.0, 1.0, 0.0]), None
    expressions: dict = {}
    roles: dict[str, int] = {}
    if "VRMC_vrm" in used or "VRMC_vrm" in js.get("extensions", {}):
        fmt, front = "vrm1", np.array([0.0, 0.0, 1.0])
        expressions, roles = _vrm1(js, meshes)
    elif "VRM" in used or "VRM" in js.get("extensions", {}):
        fmt, front = "vrm0", np.array([0.0, 0.0, -1.0])
        expressions, roles = _vrm0(js, meshes)
    route = "glTF reader" + "".join(f" + {e}" for e in sorted(used & {"EXT_meshopt_compression", "KHR_mesh_quantization",
                                                                     "KHR_draco_mesh_compression", "EXT_texture_webp",
                                                                     "KHR_texture_transform"}))
    ch = Character(path, fmt, route, meshes, joints, up=up, front=front, expressions=expressions,
                   notes=doc.notes, source_unit="m")
    ch.named_roles = roles
    return ch


def _node_mesh_index(meshes: list[SceneMesh]) -> dict[int, int]:
    return {int(m.ref.split(":")[1]): i for i, m in enumerate(meshes)}


def _vrm1(js: dict, meshes: list[SceneMesh]) -> tuple[dict, dict]:
    ext = js.get("extensions", {}).get("VRMC_vrm", {})
    bones = ext.get("humanoid", {}).get("humanBones", {})
    roles = {r: int(bones[r]["node"]) for r in ("head", "neck", "jaw", "leftEye", "rightEye")
             if r in bones and "node" in bones[r]}
    by_node = _node_mesh_index(meshes)
    out = {}
    exprs = ext.get("expressions", {})
    for group in ("preset", "custom"):
        for name, e in exprs.get(group, {}).items():
            binds = [(by_node[int(b["node"])], int(b["index"]), float(b.get("weight", 1.0)))
                     for b in e.get("morphTargetBinds", []) if int(b.get("node", -1)) in by_node]
            overrides = any(e.get(k, "none") not in ("none", None) for k in ("overrideBlink", "overrideLookAt",
                                                                             "overrideMouth"))
            out[name] = {"binds": binds, "preset": group == "preset", "binary": bool(e.get("isBinary", False)),
                         "overrides": overrides, "colors": bool(e.get("materialColorBinds"))}
    return out, roles


def _vrm0(js: dict, meshes: list[SceneMesh]) -> tuple[dict, dict]:
    ext = js.get("extensions", {}).get("VRM", {})
    roles = {}
    for b in ext.get("humanoid", {}).get("humanBones", []):
        r = b.get("bone")
        if r in ("head", "neck", "jaw", "leftEye", "rightEye") and "node" in b:
            roles[r] = int(b["node"])
    mesh_nodes: dict[int, list[int]] = {}
    for i, m in enumerate(meshes):
        node = int(m.ref.split(":")[1])
        mesh_nodes.setdefault(int(js["nodes"][node]["mesh"]), []).append(i)
    out = {}
    for g in ext.get("blendShapeMaster", {}).get("blendShapeGroups", []):
        preset = g.get("presetName") not in (None, "", "unknown")
        name = _VRM0_PRESETS.get(g.get("presetName"), g.get("presetName")) if preset else g.get("name")
        binds = []
        for b in g.get("binds", []):
            for mi in mesh_nodes.get(int(b.get("mesh", -1)), []):
                binds.append((mi, int(b["index"]), float(b.get("weight", 100.0)) / 100.0))
        if name:
            out[str(name)] = {"binds": binds, "preset": preset, "binary": bool(g.get("isBinary", False)),
                              "overrides": False, "colors": bool(g.get("materialValues"))}
    return out, roles


#: VRM 0.x expression presets by their VRM 1.0 names (as three-vrm maps them).
_VRM0_PRESETS = {"a": "aa", "i": "ih", "u": "ou", "e": "ee", "o": "oh", "joy": "happy", "angry": "angry",
                 "sorrow": "sad", "fun": "relaxed", "blink": "blink", "blink_l": "blinkLeft", "blink_r": "blinkRight",
                 "lookup": "lookUp", "lookdown": "lookDown", "lookleft": "lookLeft", "lookright": "lookRight",
                 "neutral": "neutral"}
