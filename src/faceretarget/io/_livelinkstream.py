"""Live Link Face's network stream: one UDP packet per frame, as the iPhone app sends to Unreal.

Epic Games does not document the packet; this is the layout Unreal's Live Link receiver
(``AppleARKitLiveLinkSource``, packet version 6) reads, as independent decoders of the app's
packets agree on it (think-biq/LLV ``gesicht.py``, PyLiveLinkFace).  Every number is big-endian::

    uint8                packet version (6)
    int32 n, n bytes     device id (UTF-8; the app sends a UUID string)
    int32 n, n bytes     subject name (UTF-8; the name Unreal lists the source under)
    int32                frame number        } Unreal's FQualifiedFrameTime: the frame in a
    float32              sub-frame (0..1)    } timecode base of numerator / denominator
    int32                rate numerator      } frames per second
    int32                rate denominator    }
    uint8                value count (61)
    61 x float32         the 52 ARKit weights in Live Link Face's order (EyeBlinkLeft ...
                         TongueOut, :data:`~faceretarget.io.LLF_NAMES`), then HeadYaw, HeadPitch,
                         HeadRoll, LeftEyeYaw, LeftEyePitch, LeftEyeRoll, RightEyeYaw,
                         RightEyePitch, RightEyeRoll in radians (the CSV's columns)

The app sends to port 11111 by default.  :func:`arkit_curve_map` turns a character's weights into
the 52 curves once (names mapped, split halves averaged, key-models through their ARKit basis).
"""

from __future__ import annotations

import struct
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import DataWarning, InputFileError, InvalidDataError
from ..names import ARKIT_NAMES
from ._livelinkface import EYE_COLUMNS, HEAD_COLUMNS, _to_arkit_columns

__all__ = ["LLF_PACKET_VERSION", "LLF_PORT", "LiveLinkFacePacket", "livelinkface_packet",
           "read_livelinkface_packet", "arkit_curve_map"]

#: Packet version the app sends (and Unreal reads).
LLF_PACKET_VERSION = 6
#: The app's default target port.
LLF_PORT = 11111
_N = len(ARKIT_NAMES) + len(HEAD_COLUMNS) + len(EYE_COLUMNS)  # 61
_MAX_TEXT = 256  # Unreal's limit on the device id and subject name (TCHARs)


@dataclass(frozen=True)
class LiveLinkFacePacket:
    """One decoded Live Link Face packet.

    Attributes
    ----------
    version : int
    device_id, subject : str
    frame : int
    subframe : float
    rate : (int, int)
        Frame rate as numerator, denominator.
    weights : (52,) float
        ARKit weights in Live Link Face's order.
    head : (3,) float
        HeadYaw, HeadPitch, HeadRoll, radians.
    eyes : (6,) float
        Left and right eye yaw, pitch, roll, radians.
    """

    version: int
    device_id: str
    subject: str
    frame: int
    subframe: float
    rate: tuple[int, int]
    weights: np.ndarray
    head: np.ndarray
    eyes: np.ndarray

    @property
    def time(self) -> float:
        """Seconds: ``(frame + subframe) * denominator / numerator``."""
        num, den = self.rate
        return (self.frame + self.subframe) * den / num if num else float("nan")


def _text(value: str, what: str) -> bytes:
    b = str(value).encode("utf-8")
    if len(b) > _MAX_TEXT:
        raise InvalidDataError(f"Live Link Face packet: the {what} is {len(b)} bytes long, at most {_MAX_TEXT}")
    return struct.pack(">i", len(b)) + b


def livelinkface_packet(weights: np.ndarray, head: np.ndarray | None = None, eyes: np.ndarray | None = None, *,
                        frame: int, subframe: float = 0.0, rate: tuple[int, int] = (60, 1),
                        subject: str = "faceretarget", device_id: str = "faceretarget") -> bytes:
    """One frame as a Live Link Face UDP packet (module docstring).

    Parameters
    ----------
    weights : (52,) float
        ARKit weights in Live Link Face's order (see :func:`arkit_curve_map`).
    head : (3,) float, optional
        HeadYaw, HeadPitch, HeadRoll in radians (:meth:`~faceretarget.headpose.HeadPose.to_livelinkface`);
        zeros when omitted.
    eyes : (6,) float, optional
        Eye yaw, pitch, roll (left, right) in radians; zeros when omitted.
    frame : int
        Frame number in the timecode base ``rate``.
    subframe : float
        Fraction of a frame, in [0, 1).
    rate : (int, int)
        Timecode base, frames per second as numerator and denominator.
    subject, device_id : str
        Names Unreal shows the source and subject under (at most 256 UTF-8 bytes each).

    Returns
    -------
    bytes
        ``1 + 4 + len(device_id) + 4 + len(subject) + 16 + 1 + 61 * 4`` bytes.
    """
    vals = np.zeros(_N, dtype=">f4")
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.size != len(ARKIT_NAMES) or not np.isfinite(w).all():
        raise InvalidDataError(f"Live Link Face packet: expected {len(ARKIT_NAMES)} finite weights, got "
                               f"{w.size} ({'finite' if np.isfinite(w).all() else 'with NaN'})")
    vals[:52] = w
    for arr, lo, n, what in ((head, 52, 3, "head angles"), (eyes, 55, 6, "eye angles")):
        if arr is not None:
            a = np.asarray(arr, dtype=np.float64).reshape(-1)
            if a.size != n or not np.isfinite(a).all():
                raise InvalidDataError(f"Live Link Face packet: {what} must be {n} finite numbers, got {a.size}")
            vals[lo:lo + n] = a
    num, den = (int(x) for x in rate)
    if num <= 0 or den <= 0:
        raise InvalidDataError(f"Live Link Face packet: frame rate {num}/{den} must be positive")
    if not 0.0 <= subframe < 1.0:
        raise InvalidDataError(f"Live Link Face packet: sub-frame {subframe} is outside [0, 1)")
    return b"".join([
        struct.pack(">B", LLF_PACKET_VERSION), _text(device_id, "device id"), _text(subject, "subject name"),
        struct.pack(">ifii", int(frame), float(subframe), num, den), struct.pack(">B", _N), vals.tobytes(),
    ])


def read_livelinkface_packet(data: bytes, source: str = "packet") -> LiveLinkFacePacket:
    """Decode a Live Link Face packet (module docstring).

    Parameters
    ----------
    data : bytes
    source : str
        Where it came from (``"udp 127.0.0.1:11111"``), for messages.

    Raises
    ------
    InputFileError
        A truncated or malformed packet, naming ``source`` and what is wrong.
    """
    mv = memoryview(bytes(data))
    pos = 0

    def take(n: int, what: str) -> bytes:
        nonlocal pos
        if n < 0 or pos + n > len(mv):
            raise InputFileError(f"{source}: Live Link Face packet of {len(mv)} bytes ends inside the {what} "
                                 f"(byte {pos}, {n} more needed)")
        out = bytes(mv[pos:pos + n])
        pos += n
        return out

    def text(what: str) -> str:
        (n,) = struct.unpack(">i", take(4, what + " length"))
        if not 0 <= n <= _MAX_TEXT:
            raise InputFileError(f"{source}: Live Link Face packet {what} length {n} is outside 0..{_MAX_TEXT}")
        try:
            return take(n, what).decode("utf-8")
        except UnicodeDecodeError as e:
            raise InputFileError(f"{source}: Live Link Face packet {what} is not UTF-8 ({e})") from None

    (version,) = struct.unpack(">B", take(1, "version"))
    device = text("device id")
    subject = text("subject name")
    frame, sub, num, den = struct.unpack(">ifii", take(16, "frame time"))
    (count,) = struct.unpack(">B", take(1, "value count"))
    vals = np.frombuffer(take(4 * count, f"{count} values"), dtype=">f4").astype(np.float64)
    if pos != len(mv):
        raise InputFileError(f"{source}: Live Link Face packet has {len(mv) - pos} bytes after its {count} values")
    full = np.zeros(_N)
    full[:min(count, _N)] = vals[:_N]
    return LiveLinkFacePacket(version=int(version), device_id=device, subject=subject, frame=int(frame),
                              subframe=float(sub), rate=(int(num), int(den)), weights=full[:52],
                              head=full[52:55], eyes=full[55:61])


def arkit_curve_map(names: list[str], basis: np.ndarray | None = None, basis_names: list[str] | None = None,
                    *, source: str = "character") -> np.ndarray:
    """The matrix ``M`` with ``curves = W @ M``: a character's weights as the 52 Live Link Face curves.

    Parameters
    ----------
    names : list of str (K)
        The weights' shape names.  ARKit names in any spelling map to their curve, split halves
        (``browInnerUp_L``, ``_R``) are averaged into the whole curve, other shapes are dropped
        (one :class:`~faceretarget.errors.DataWarning`).
    basis : (K, B) float, optional
        Each shape as weights of ``basis_names`` (a key-model set's
        :attr:`~faceretarget.rig.Rig.basis`): the curves are then ``W @ basis`` mapped by
        ``basis_names``.
    basis_names : list of str (B), optional
    source : str
        For the warning.

    Returns
    -------
    (K, 52) float
    """
    k = len(names)
    if basis is not None:
        B = np.asarray(basis, dtype=np.float64)
        if basis_names is None or B.shape != (k, len(basis_names)):
            raise InvalidDataError(f"{source}: basis must be (K, B) = ({k}, {len(basis_names or [])}) with its names")
        return B @ arkit_curve_map(list(basis_names), source=source)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        M = _to_arkit_columns(list(names), np.eye(k), source)
    for c in caught:  # re-raised from here, once (the message names the dropped shapes)
        msg = str(c.message).replace("to the Live Link Face CSV", "to Live Link Face").replace(
            "Live Link Face CSV", "Live Link Face")
        warnings.warn(msg, DataWarning, stacklevel=2)
    return M
