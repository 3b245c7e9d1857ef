"""The binary FBX node tree, read and written back byte for byte (no Blender, no FBX SDK).

A binary FBX file (versions 7100-7700) is a header (``Kaydara FBX Binary  \\x00\\x1a\\x00`` and the
version), a list of node records and a footer.  A record is its end offset, its number of properties,
the byte length of its properties (32-bit numbers before version 7500, 64-bit from 7500), its name,
its properties and, when it has children (or the writer chose to), its children followed by a null
record (a record of zeros).  A property is a type code and its value: ``Y`` int16, ``C`` bool, ``I``
int32, ``F`` float32, ``D`` float64, ``L`` int64, ``R`` raw bytes and ``S`` string (a 32-bit length
and the bytes; object names are ``name\\x00\\x01class``), or an array ``f d l i b`` (count, encoding:
0 plain or 1 zlib, byte length, data).  The footer is a 16-byte code tied to the file's time stamps,
padding to 16 bytes, the version, zeros and a 16-byte magic.

:func:`parse_fbx` reads the tree; an array is kept as the bytes the file holds (:class:`FbxArray`)
and decoded only when asked, so :func:`encode_fbx` writes every record the caller did not change as
the very bytes it was read from: parsing and encoding a file gives the same file back (the footer's
code and time stamps are the file's own, so it stays consistent with them).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputFileError

__all__ = ["FbxNode", "FbxArray", "FbxDocument", "parse_fbx", "encode_fbx", "is_binary_fbx", "BINARY_MAGIC"]

BINARY_MAGIC = b"Kaydara FBX Binary  \x00\x1a\x00"
_FOOTER_MAGIC = bytes.fromhex("f8 5a 8c 6a de f5 d9 7e ec e9 0c e3 75 8f 29 0b".replace(" ", ""))
_SCALARS = {b"Y": "<h", b"C": "<B", b"I": "<i", b"F": "<f", b"D": "<d", b"L": "<q"}
_ARRAYS = {b"f": np.dtype("<f4"), b"d": np.dtype("<f8"), b"l": np.dtype("<i8"), b"i": np.dtype("<i4"),
           b"b": np.dtype("u1")}
#: Arrays shorter than this are written plain (zlib would not pay; writers do the same).
_COMPRESS_FROM = 16


class FbxArray:
    """An array property as the file holds it (``code`` one of ``f d l i b``): decoded on first use.

    Built from values (``FbxArray.of(code, values)``) it is encoded when written (zlib from
    :data:`_COMPRESS_FROM` values)."""

    __slots__ = ("code", "count", "encoding", "raw", "_values")

    def __init__(self, code: bytes, count: int, encoding: int, raw: bytes | None, values: np.ndarray | None = None):
        self.code, self.count, self.encoding, self.raw, self._values = code, count, encoding, raw, values

    @classmethod
    def of(cls, code: bytes, values) -> FbxArray:
        v = np.ascontiguousarray(values, dtype=_ARRAYS[code]).reshape(-1)
        return cls(code, len(v), 1 if len(v) >= _COMPRESS_FROM else 0, None, v)

    @property
    def values(self) -> np.ndarray:
        """The values (read-only when decoded from the file)."""
        if self._values is None:
            data = zlib.decompress(self.raw) if self.encoding == 1 else self.raw
            self._values = np.frombuffer(data, dtype=_ARRAYS[self.code], count=self.count)
        return self._values

    def encoded(self) -> tuple[int, bytes]:
        """``(encoding, bytes)`` as written: the file's own bytes when unchanged."""
        if self.raw is None:
            data = self._values.astype(_ARRAYS[self.code], copy=False).tobytes()
            self.raw = zlib.compress(data, 1) if self.encoding == 1 else data
        return self.encoding, self.raw


@dataclass(eq=False)
class FbxNode:
    """One record: its ``name``, properties (``props``: Python values; strings and raw data as bytes,
    arrays as :class:`FbxArray`) with their type codes (``types``, one byte each), its children, and
    whether the file closes it with a null record though it has no children (``block``)."""

    name: str
    props: list = field(default_factory=list)
    types: bytes = b""
    children: list[FbxNode] = field(default_factory=list)
    block: bool = False

    def find(self, name: str) -> FbxNode | None:
        """The first child called ``name``."""
        return next((c for c in self.children if c.name == name), None)

    def find_all(self, name: str) -> list[FbxNode]:
        return [c for c in self.children if c.name == name]

    def add(self, name: str, *props, types: bytes | None = None, block: bool = False) -> FbxNode:
        """Append a child with ``props`` (types inferred unless given: int -> ``L``... see :func:`_type_of`)."""
        node = FbxNode(name, list(props), types if types is not None else b"".join(_type_of(p) for p in props),
                       block=block)
        self.children.append(node)
        return node


def _type_of(p) -> bytes:
    if isinstance(p, bool):
        return b"C"
    if isinstance(p, int):
        return b"L"
    if isinstance(p, float):
        return b"D"
    if isinstance(p, (bytes, str)):
        return b"S"
    if isinstance(p, FbxArray):
        return p.code
    raise TypeError(f"no FBX property type for {type(p).__name__}")


@dataclass(eq=False)
class FbxDocument:
    """A parsed binary FBX: ``version`` (7100-7700), the top-level records under ``root`` (a nameless node),
    and the footer's own bytes (``footer_code``: the 16 bytes after the last record; ``footer_tail``: from
    the version on; ``footer_align``: the zeros between them and where the version sits modulo 16)."""

    version: int
    root: FbxNode
    footer_code: bytes
    footer_tail: bytes
    footer_align: tuple[int, int] = (4, 4)


def is_binary_fbx(head: bytes) -> bool:
    """Whether a file's first bytes are a binary FBX header."""
    return head[:len(BINARY_MAGIC)] == BINARY_MAGIC


class _Reader:
    def __init__(self, data: bytes, where: str, version: int):
        self.data, self.where = memoryview(data), where
        self.wide = version >= 7500
        self.head = struct.Struct("<QQQB" if self.wide else "<IIIB")

    def fail(self, at: int, what: str = "truncated binary FBX"):
        if "(" in what:
            head, _, tail = what.partition(" (")
            raise InputFileError(f"{self.where}: {head} at byte {at} ({tail}")
        raise InputFileError(f"{self.where}: {what} at byte {at}")

    def need(self, at: int, n: int) -> None:
        if n < 0 or at + n > len(self.data):
            self.fail(at)

    def record(self, at: int) -> tuple[FbxNode | None, int]:
        """The record at ``at`` (None for a null record) and the offset after it."""
        hs = self.head.size
        self.need(at, hs)
        end, n_props, props_len, name_len = self.head.unpack_from(self.data, at)
        if end == 0 and n_props == 0 and props_len == 0 and name_len == 0:
            return None, at + hs
        if end > len(self.data):
            self.fail(len(self.data), f"truncated binary FBX (the record at byte {at} ends at byte {end}) or bad "
                      f"record offset")
        if end <= at:
            self.fail(at, "bad record end offset")
        p = at + hs
        self.need(p, name_len)
        name = bytes(self.data[p:p + name_len]).decode("latin-1")
        p += name_len
        props_end = p + props_len
        if props_end > end:
            self.fail(p)
        props, types = [], bytearray()
        for _ in range(n_props):
            value, code, p = self.prop(p, props_end)
            props.append(value)
            types += code
        if p != props_end:
            self.fail(p, f"record '{name}' properties do not fill their length")
        node = FbxNode(name, props, bytes(types))
        if p < end:
            node.block = True
            while True:
                child, p = self.record(p)
                if child is None:
                    break
                node.children.append(child)
                if p > end:
                    self.fail(end, f"record '{name}' children overrun it")
            if p != end:
                self.fail(p, f"record '{name}' does not end at its end offset {end}")
            node.block = not node.children
        return node, end

    def prop(self, p: int, limit: int):
        if p >= limit:
            self.fail(p)
        code = bytes(self.data[p:p + 1])
        p += 1
        fmt = _SCALARS.get(code)
        if fmt is not None:
            n = struct.calcsize(fmt)
            if p + n > limit:
                self.fail(p)
            return struct.unpack_from(fmt, self.data, p)[0], code, p + n
        if code in (b"S", b"R"):
            if p + 4 > limit:
                self.fail(p)
            n = struct.unpack_from("<I", self.data, p)[0]
            if p + 4 + n > limit:
                self.fail(p + 4)
            return bytes(self.data[p + 4:p + 4 + n]), code, p + 4 + n
        if code in _ARRAYS:
            if p + 12 > limit:
                self.fail(p)
            count, encoding, n = struct.unpack_from("<III", self.data, p)
            if p + 12 + n > limit:
                self.fail(p + 12)
            if encoding not in (0, 1):
                self.fail(p, f"unknown array encoding {encoding}")
            return FbxArray(code, count, encoding, bytes(self.data[p + 12:p + 12 + n])), code, p + 12 + n
        self.fail(p - 1, f"unknown property type {code!r}")


def parse_fbx(data: bytes, where: str = "FBX") -> FbxDocument:
    """The node tree of a binary FBX file's bytes (``where`` names the file in errors).

    Raises
    ------
    InputFileError
        Not a binary FBX, a version outside 7100-7700, or a record that runs past the end or past its
        parent ("X.fbx: truncated binary FBX at byte N").
    """
    if not is_binary_fbx(data):
        raise InputFileError(f"{where}: not a binary FBX file (an ASCII FBX or another format)")
    if len(data) < 27:
        raise InputFileError(f"{where}: truncated binary FBX at byte {len(data)}")
    version = struct.unpack_from("<I", data, 23)[0]
    if not 7100 <= version < 8000:
        raise InputFileError(f"{where}: binary FBX version {version} (7100-7700 are read)")
    r = _Reader(data, where, version)
    root = FbxNode("")
    p = 27
    while True:
        node, p = r.record(p)
        if node is None:
            break
        root.children.append(node)
    footer_code = bytes(data[p:p + 16])
    q = p + 16
    # zeros, then the version: writers align it differently (the FBX SDK puts it 4 bytes past a 16-byte
    # boundary, Blender on one); the file's own alignment is kept (FbxDocument.footer_align)
    at = q
    while at < min(len(data), q + 40) and data[at] == 0:
        at += 1
    if len(footer_code) < 16 or data[at:at + 4] != struct.pack("<I", version) or _FOOTER_MAGIC not in data[at:]:
        raise InputFileError(f"{where}: truncated binary FBX at byte {min(len(data), q)} (no footer)")
    return FbxDocument(version, root, footer_code, bytes(data[at:]), (at - q, at % 16))


def _write_node(out: bytearray, node: FbxNode, head: struct.Struct) -> None:
    at = len(out)
    out += b"\0" * head.size
    name = node.name.encode("latin-1")
    out += name
    props_at = len(out)
    if len(node.types) != len(node.props):
        raise ValueError(f"FBX record '{node.name}': {len(node.props)} properties, {len(node.types)} types")
    for code, value in zip(node.types, node.props, strict=True):
        c = bytes((code,))
        out += c
        fmt = _SCALARS.get(c)
        if fmt is not None:
            out += struct.pack(fmt, value)
        elif c in (b"S", b"R"):
            b = value.encode("utf-8") if isinstance(value, str) else bytes(value)
            out += struct.pack("<I", len(b)) + b
        else:
            enc, b = value.encoded()
            out += struct.pack("<III", value.count, enc, len(b)) + b
    props_len = len(out) - props_at
    if node.children or node.block:
        for child in node.children:
            _write_node(out, child, head)
        out += b"\0" * head.size
    head.pack_into(out, at, len(out), len(node.props), props_len, len(name))


def encode_fbx(doc: FbxDocument) -> bytes:
    """The bytes of ``doc`` as a binary FBX file: header, records, footer (its code and tail kept, the
    zeros before the version recomputed so the version sits where the file's writer puts it)."""
    head = struct.Struct("<QQQB" if doc.version >= 7500 else "<IIIB")
    out = bytearray(BINARY_MAGIC + struct.pack("<I", doc.version))
    for node in doc.root.children:
        _write_node(out, node, head)
    out += b"\0" * head.size
    out += doc.footer_code
    least, mod = doc.footer_align
    least = min(least, 4)
    out += b"\0" * (least + (mod - len(out) - least) % 16)
    out += doc.footer_tail
    return bytes(out)
