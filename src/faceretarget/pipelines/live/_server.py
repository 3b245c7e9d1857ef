"""The live page's server: the standard library's HTTP server in a thread, plus a minimal WebSocket.

``GET /`` is the page (``faceretarget/data/web/index.html`` + ``live.js``), ``GET /character.glb``
the character, ``GET /three/...`` the three.js files shipped with the package (never a CDN: npm
``three@0.187.0``'s ``build/three.module.js``, ``build/three.core.js`` and
``examples/jsm/loaders/GLTFLoader.js`` with the two utils it imports, unchanged, as
``data/web/three/`` and ``three/addons/``, MIT licence beside them), and
``GET /ws`` upgrades to a WebSocket (RFC 6455, text frames; the subset a browser needs): the
server pushes one JSON message per frame, the page sends its sliders back.  Each page has its own
small outgoing queue written by its own thread, so a slow or frozen page loses old frames instead
of stalling the session; a WebSocket is accepted only from the page's own origin (or from a client
that sends no ``Origin``, such as a script), so another web site open in the same browser cannot
read the stream or move the sliders.
"""

from __future__ import annotations

import base64
import collections
import hashlib
import json
import re
import socket
import struct
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import urlsplit

from ...errors import InvalidDataError, OutputError
from ...formats import GLB, JSON

__all__ = ["LiveServer", "websocket_accept", "encode_ws_frame", "read_ws_frame", "parse_address", "WebSocketError"]

_GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"
#: Largest message a page may send (its slider messages are a few dozen bytes).
MAX_INCOMING = 1 << 16
_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
          GLB: "model/gltf-binary", JSON: "application/json", "": "text/plain; charset=utf-8"}
_SAFE_PART = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
OP_CONT, OP_TEXT, OP_BINARY, OP_CLOSE, OP_PING, OP_PONG = 0x0, 0x1, 0x2, 0x8, 0x9, 0xA


class WebSocketError(ConnectionError):
    """A peer broke the WebSocket protocol (the connection is closed with ``code``)."""

    def __init__(self, message: str, code: int = 1002):
        super().__init__(message)
        self.code = code


def parse_address(text: str, *, what: str = "--serve", default_port: int | None = None) -> tuple[str, int]:
    """``"HOST:PORT"`` (or ``"PORT"``, or ``"HOST"`` with ``default_port``) -> ``(host, port)``."""
    t = str(text).strip()
    host, sep, port = t.rpartition(":")
    if not sep:
        host, port = ("127.0.0.1", t) if t.isdigit() else (t, "" if default_port is None else str(default_port))
    host = host.strip("[]") or "127.0.0.1"
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise InvalidDataError(f"{what} {text!r}: expected HOST:PORT with a port in 0..65535")
    return host, int(port)


def websocket_accept(key: str) -> str:
    """``Sec-WebSocket-Accept`` for a client's ``Sec-WebSocket-Key`` (RFC 6455, Sec. 4.2.2)."""
    return base64.b64encode(hashlib.sha1((key.strip() + _GUID).encode("ascii")).digest()).decode("ascii")


def _masked(data: bytes, mask: bytes) -> bytes:
    n = len(data)
    if n == 0:
        return b""
    m = (mask * (n // 4 + 1))[:n]
    return (int.from_bytes(data, "big") ^ int.from_bytes(m, "big")).to_bytes(n, "big")


def encode_ws_frame(payload: bytes | str, opcode: int = OP_TEXT, *, mask: bytes | None = None) -> bytes:
    """One final WebSocket frame (servers send unmasked frames; a client passes a 4-byte ``mask``)."""
    data = payload.encode("utf-8") if isinstance(payload, str) else bytes(payload)
    n = len(data)
    bit = 0x80 if mask is not None else 0
    head = bytes([0x80 | opcode])
    if n < 126:
        head += bytes([bit | n])
    elif n < 1 << 16:
        head += bytes([bit | 126]) + struct.pack(">H", n)
    else:
        head += bytes([bit | 127]) + struct.pack(">Q", n)
    if mask is not None:
        if len(mask) != 4:
            raise ValueError("a WebSocket mask is 4 bytes")
        return head + mask + _masked(data, mask)
    return head + data


def _read_exact(rfile, n: int) -> bytes:
    data = rfile.read(n) if n else b""
    if len(data) != n:
        raise ConnectionError("the WebSocket peer closed the connection")
    return data


def read_ws_frame(rfile, *, require_mask: bool = True, limit: int = MAX_INCOMING) -> tuple[bool, int, bytes]:
    """Read one frame: ``(fin, opcode, payload)`` (unmasked).

    Raises
    ------
    ConnectionError
        The peer closed the connection.
    WebSocketError
        An unmasked client frame (``require_mask``), reserved bits, or a payload over ``limit``
        bytes (code 1009).
    """
    b0, b1 = _read_exact(rfile, 2)
    fin, opcode, masked, n = bool(b0 & 0x80), b0 & 0x0F, bool(b1 & 0x80), b1 & 0x7F
    if b0 & 0x70:
        raise WebSocketError("reserved WebSocket bits set (no extension was agreed)")
    if require_mask and not masked:
        raise WebSocketError("a client's WebSocket frames must be masked")
    if n == 126:
        (n,) = struct.unpack(">H", _read_exact(rfile, 2))
    elif n == 127:
        (n,) = struct.unpack(">Q", _read_exact(rfile, 8))
    if n > limit:
        raise WebSocketError(f"WebSocket message of {n} bytes, at most {limit}", code=1009)
    mask = _read_exact(rfile, 4) if masked else None
    data = _read_exact(rfile, n)
    return fin, opcode, _masked(data, mask) if mask is not None else data


class _Client:
    """One page: its socket, a short queue of outgoing frames and the thread that writes them."""

    def __init__(self, sock: socket.socket, address, queue: int):
        self.sock = sock
        self.address = address
        self.frames: collections.deque[bytes] = collections.deque(maxlen=queue)
        self.cv = threading.Condition()
        self.write_lock = threading.Lock()
        self.closing = False
        self.final: bytes | None = None
        self.dropped = 0
        self.sent = 0
        self.writer = threading.Thread(target=self._write_loop, name="faceretarget-live-ws-writer", daemon=True)
        self.writer.start()

    def push(self, frame: bytes) -> None:
        with self.cv:
            if self.closing:
                return
            if len(self.frames) == self.frames.maxlen:
                self.dropped += 1
            self.frames.append(frame)
            self.cv.notify()

    def send_now(self, frame: bytes) -> None:
        """Write a control frame from the reading thread (pong, close echo)."""
        with self.write_lock:
            self.sock.sendall(frame)

    def _write_loop(self) -> None:
        while True:
            with self.cv:
                while not self.frames and not self.closing:
                    self.cv.wait()
                if self.frames:
                    frame = self.frames.popleft()
                elif self.final is not None:
                    frame, self.final = self.final, None
                else:
                    return
            try:
                with self.write_lock:
                    self.sock.sendall(frame)
                self.sent += 1
            except OSError:
                with self.cv:
                    self.closing = True
                    self.frames.clear()
                    self.final = None
                return

    def close(self, code: int = 1001, reason: str = "", *, timeout: float = 1.0) -> None:
        """Send what is queued and a close frame, then shut the socket (unblocks the reader)."""
        with self.cv:
            if not self.closing:
                self.closing = True
                self.final = encode_ws_frame(struct.pack(">H", code) + reason.encode("utf-8")[:120], OP_CLOSE)
            self.cv.notify()
        if threading.current_thread() is not self.writer:
            self.writer.join(timeout)
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class _Handler(BaseHTTPRequestHandler):
    server_version = "faceretarget-live"
    protocol_version = "HTTP/1.1"

    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        pass

    def do_GET(self):  # noqa: N802 - http.server's name
        app: LiveServer = self.server.app
        path = urlsplit(self.path).path
        if path == "/ws":
            self._websocket(app)
            return
        found = app.resource(path)
        if found is None:
            self.send_error(404, "not found")
            return
        body, ctype = found
        self.send_response(200)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _websocket(self, app: LiveServer) -> None:
        h = self.headers
        key = h.get("Sec-WebSocket-Key", "")
        if (h.get("Upgrade", "").lower() != "websocket" or "upgrade" not in h.get("Connection", "").lower()
                or not key or h.get("Sec-WebSocket-Version", "").strip() != "13"):
            self.send_error(400, "expected a WebSocket upgrade (version 13)")
            return
        origin = h.get("Origin")
        if origin is not None and urlsplit(origin).netloc.lower() != h.get("Host", "").lower():
            self.send_error(403, "WebSocket from another origin")
            return
        self.send_response(101, "Switching Protocols")
        self.send_header("Upgrade", "websocket")
        self.send_header("Connection", "Upgrade")
        self.send_header("Sec-WebSocket-Accept", websocket_accept(key))
        self.end_headers()
        self.close_connection = True
        app._serve_client(self.connection, self.rfile, self.client_address)


class _HTTPServer(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True


class LiveServer:
    """The page, the character and the WebSocket stream of a live session, on ``host:port``.

    Parameters
    ----------
    host : str
        Interface to listen on (``"127.0.0.1"``: this machine only; ``"0.0.0.0"`` exposes the
        stream to the network).
    port : int
        TCP port (0: any free port; see :attr:`port`).
    glb : bytes
        The character as a ``.glb`` (served as ``/character.glb``).
    on_message : callable, optional
        Called with each JSON object a page sends (from that page's thread).
    hello : callable, optional
        Returns the messages (JSON-able objects) to send a page when it connects.
    queue : int
        Outgoing frames kept per page; when a page falls behind, the oldest are dropped.

    Raises
    ------
    OutputError
        The address cannot be listened on (in use, not this machine's), naming it.
    """

    def __init__(self, host: str, port: int, *, glb: bytes, on_message: Callable[[dict], None] | None = None,
                 hello: Callable[[], list] | None = None, queue: int = 4):
        self.glb = bytes(glb)
        self.on_message = on_message
        self.hello = hello
        self.queue = int(queue)
        self._clients: set[_Client] = set()
        self._cv = threading.Condition()
        self._cache: dict[str, bytes] = {}
        self._web = resources.files("faceretarget").joinpath("data", "web")
        self.bad_messages = 0
        try:
            self._httpd = _HTTPServer((host, int(port)), _Handler)
        except OSError as e:
            raise OutputError(f"{host}:{port}: cannot serve the live page there ({e.strerror or e}); "
                              "choose another --serve HOST:PORT (port 0 picks a free one)") from None
        self._httpd.app = self
        self.host = host
        self.port = int(self._httpd.server_address[1])
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.1},
                                        name="faceretarget-live-http", daemon=True)
        self._thread.start()
        self._closed = False

    @property
    def url(self) -> str:
        """``http://host:port/`` (``127.0.0.1`` when listening on every interface)."""
        h = "127.0.0.1" if self.host in ("", "0.0.0.0") else ("[" + self.host + "]" if ":" in self.host else self.host)
        return f"http://{h}:{self.port}/"

    @property
    def n_clients(self) -> int:
        """Pages connected now."""
        with self._cv:
            return len(self._clients)

    @property
    def dropped(self) -> int:
        """Frames dropped so far for pages that fell behind (connected pages)."""
        with self._cv:
            return sum(c.dropped for c in self._clients)

    def wait_for_clients(self, n: int = 1, timeout: float | None = None) -> bool:
        """Block until ``n`` pages are connected (True) or ``timeout`` seconds pass (False)."""
        with self._cv:
            return self._cv.wait_for(lambda: len(self._clients) >= n, timeout)

    # ------------------------------------------------------------------------------ content
    def resource(self, path: str) -> tuple[bytes, str] | None:
        """The body and content type served at ``path``, or None (404)."""
        if path in ("/", "/index.html"):
            return self._file("index.html"), _TYPES[".html"]
        if path == "/live.js":
            return self._file("live.js"), _TYPES[".js"]
        if path == "/character.glb":
            return self.glb, _TYPES[GLB]
        if path.startswith("/three/"):
            parts = path[1:].split("/")
            if all(_SAFE_PART.match(p) for p in parts):
                try:
                    body = self._file(*parts)
                except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
                    return None
                ext = "." + parts[-1].rsplit(".", 1)[-1] if "." in parts[-1] else ""
                return body, _TYPES.get(ext, "application/octet-stream")
        return None

    def _file(self, *parts: str) -> bytes:
        key = "/".join(parts)
        if key not in self._cache:
            self._cache[key] = self._web.joinpath(*parts).read_bytes()
        return self._cache[key]

    # ------------------------------------------------------------------------------ streaming
    def broadcast(self, message) -> int:
        """Queue ``message`` (a JSON-able object or a JSON string) for every page; how many pages."""
        text = message if isinstance(message, str) else json.dumps(message, separators=(",", ":"))
        frame = encode_ws_frame(text)
        with self._cv:
            clients = list(self._clients)
        for c in clients:
            c.push(frame)
        return len(clients)

    def _serve_client(self, sock: socket.socket, rfile, address) -> None:
        client = _Client(sock, address, self.queue)
        for msg in (self.hello() if self.hello else []):
            client.push(encode_ws_frame(json.dumps(msg, separators=(",", ":"))))
        with self._cv:
            if self._closed:
                client.close(1001, "session ended")
                return
            self._clients.add(client)
            self._cv.notify_all()
        code = 1000
        try:
            parts: list[bytes] = []
            while True:
                fin, op, data = read_ws_frame(rfile)
                if op == OP_CLOSE:
                    break
                if op == OP_PING:
                    client.send_now(encode_ws_frame(data[:125], OP_PONG))
                    continue
                if op == OP_PONG:
                    continue
                if op not in (OP_TEXT, OP_BINARY, OP_CONT):
                    raise WebSocketError(f"unknown WebSocket opcode {op}")
                parts.append(data)
                if sum(map(len, parts)) > MAX_INCOMING:
                    raise WebSocketError(f"WebSocket message over {MAX_INCOMING} bytes", code=1009)
                if fin:
                    self._message(b"".join(parts), op if op != OP_CONT else OP_TEXT)
                    parts = []
        except WebSocketError as e:
            code = e.code
        except (ConnectionError, OSError, ValueError):
            code = 1001
        finally:
            with self._cv:
                self._clients.discard(client)
                self._cv.notify_all()
            client.close(code)

    def _message(self, data: bytes, op: int) -> None:
        if self.on_message is None:
            return
        try:
            msg = json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            self.bad_messages += 1
            return
        if not isinstance(msg, dict):
            self.bad_messages += 1
            return
        try:
            self.on_message(msg)
        except Exception:  # noqa: BLE001 - a page's bad message never ends its connection
            self.bad_messages += 1

    # ------------------------------------------------------------------------------ end
    def close(self, reason: str = "session ended") -> None:
        """Close every page's WebSocket (after what is queued) and stop serving."""
        with self._cv:
            if self._closed:
                return
            self._closed = True
            clients = list(self._clients)
        for c in clients:
            c.close(1001, reason)
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(2.0)

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
