"""The viewer's web server: serves the page (``static/``, with the vendored
three.js), the current result and a stream of change notices, on 127.0.0.1
only.

``ViewerState`` is what the watch loop publishes (thread-safe); the page
reads it through

- ``GET /api/state``   JSON: status, generation, quality, the run's numbers,
  property ranges, the number of iterations, compile errors;
- ``GET /api/mesh``    binary: uint32 n, uint32 m, float32 positions (3n),
  float32 normals (3n), uint32 triangles (3m), float32 texture coordinates (2n);
- ``GET /api/frame?generation=G&iteration=I``  binary float32: the
  appearance colour per vertex (3n), its roughness, metallic and occlusion
  (n each), then each property per vertex (n each, in the order of
  ``properties``);
- ``GET /api/events``  server-sent events, one message per published change;
- ``POST /api/preview`` body: the preview fraction of the γ-tons (0 < f <= 1);
- ``GET /api/mask?index=K``  the K-th image the effect reads with mask() (state ``masks``);
- ``POST /api/mask?index=K`` body: a PNG of the same size, painted in the page: it
  replaces the file (atomically, keeping its atlas record), and the watch loop
  re-runs as after an edit;
- ``GET /api/mask-points?index=K``  for a mask laid out in the scene's atlas
  (``atlas`` in its state, driver/running/mask_atlas.py): uint32 size, float32 scene
  units per texel, float32 (size² x 3) the scene point under each texel (NaN
  where there is none), so the brush paints in space, across chart seams.
"""

from __future__ import annotations

import json
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlparse

#: The largest painted mask the page may send.
MAX_MASK_BYTES = 256 << 20

CONTENT_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
                 ".css": "text/css; charset=utf-8"}


def _png8(path) -> bool:
    """An 8-bit PNG: what the page paints and saves without losing precision."""
    try:
        with open(path, "rb") as f:
            head = f.read(26)
    except OSError:
        return False
    return head[:8] == b"\x89PNG\r\n\x1a\n" and head[24] == 8


class ViewerState:
    """The result on show, changed by the watch loop, read by request threads."""

    def __init__(self, effect: str, scene: str, preview: float = 0.25):
        self.cond = threading.Condition()
        self.version = 0          # bumped on every publish (the events stream follows it)
        self.closing = False
        self.preview = preview    # fraction of the γ-tons of the quick first pass
        self.preview_changed = threading.Event()
        self.info = {"effect": effect, "scene": scene, "status": "starting", "generation": 0,
                     "quality": "final", "iterations": 0, "properties": [], "appearance": False,
                     "error": None, "run": None, "mesh": None, "camera": None, "progress": None,
                     "masks": []}
        self.mesh_bytes = b""
        self.frames: list[bytes] = []
        self.mask_paths: list = []  # the files behind info["masks"], in the same order
        self.mask_points = None     # path -> (points, units per texel) of an atlas mask (the watch loop's)

    def publish(self, frames: list[bytes] | None = None, mesh_bytes: bytes | None = None, **info) -> None:
        with self.cond:
            if mesh_bytes is not None:
                self.mesh_bytes = mesh_bytes
            if frames is not None:
                self.frames = frames
            self.info.update(info)
            self.info["iterations"] = len(self.frames)
            self.version += 1
            self.cond.notify_all()

    def set_masks(self, paths: list, atlas: frozenset = frozenset(), points=None) -> None:
        """The images the effect reads with mask(), as the page may paint them;
        those in ``atlas`` are laid out in the scene's atlas, and ``points``
        (path -> (points, units per texel)) gives their texels' places."""
        from pathlib import Path

        with self.cond:
            self.mask_paths = [Path(p) for p in paths]
            self.mask_points = points
            self.info["masks"] = [{"name": p.name, "paintable": _png8(p), "atlas": str(p) in atlas}
                                  for p in self.mask_paths]
            self.version += 1
            self.cond.notify_all()

    def mask_path(self, index: int):
        with self.cond:
            return self.mask_paths[index] if 0 <= index < len(self.mask_paths) else None

    def texel_points(self, index: int) -> bytes | None:
        """``/api/mask-points``'s body for the index-th mask, None if it is not an atlas mask."""
        import struct

        with self.cond:
            if not 0 <= index < len(self.mask_paths) or not self.info["masks"][index]["atlas"]:
                return None
            path, points_of = self.mask_paths[index], self.mask_points
        found = points_of(path) if points_of is not None else None
        if found is None:
            return None
        points, per_texel = found
        return struct.pack("<If", points.shape[0], per_texel) + points.astype("<f4").tobytes()

    def snapshot(self) -> dict:
        with self.cond:
            return dict(self.info, preview=self.preview)

    def frame(self, generation: int, iteration: int) -> bytes | None:
        with self.cond:
            if generation != self.info["generation"] or not 1 <= iteration <= len(self.frames):
                return None
            return self.frames[iteration - 1]

    def wait_change(self, seen: int, timeout: float) -> int:
        with self.cond:
            self.cond.wait_for(lambda: self.version != seen or self.closing, timeout)
            return self.version

    def close(self) -> None:
        with self.cond:
            self.closing = True
            self.cond.notify_all()


class _Handler(BaseHTTPRequestHandler):
    state: ViewerState          # set on the subclass made by serve()
    server_version = "gammac-watch"

    def log_message(self, format, *args):   # noqa: A002 - the base class's name
        pass                                 # requests are not the user's business

    def _send(self, body: bytes, content_type: str, status=HTTPStatus.OK) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self):  # noqa: N802 - http.server's name
        url = urlparse(self.path)
        query = {k: v[-1] for k, v in parse_qs(url.query).items()}
        if url.path in ("/", "/index.html"):
            return self._static("index.html")
        if url.path.startswith("/static/"):
            return self._static(url.path[len("/static/"):])
        if url.path == "/api/state":
            return self._send(json.dumps(self.state.snapshot()).encode(), "application/json")
        if url.path == "/api/mesh":
            return self._send(self.state.mesh_bytes, "application/octet-stream")
        if url.path == "/api/frame":
            try:
                data = self.state.frame(int(query.get("generation", -1)), int(query.get("iteration", -1)))
            except ValueError:
                data = None
            if data is None:
                return self._send(b"no such frame", "text/plain", HTTPStatus.NOT_FOUND)
            return self._send(data, "application/octet-stream")
        if url.path == "/api/mask":
            path = self._mask_path(query)
            if path is None or not path.is_file():
                return self._send(b"no such mask", "text/plain", HTTPStatus.NOT_FOUND)
            return self._send(path.read_bytes(), "image/png")
        if url.path == "/api/mask-points":
            try:
                data = self.state.texel_points(int(query.get("index", -1)))
            except ValueError:
                data = None
            if data is None:
                return self._send(b"no such atlas mask", "text/plain", HTTPStatus.NOT_FOUND)
            return self._send(data, "application/octet-stream")
        if url.path == "/favicon.ico":
            return self._send(b"", "image/x-icon", HTTPStatus.NO_CONTENT)
        if url.path == "/api/events":
            return self._events()
        self._send(b"not found", "text/plain", HTTPStatus.NOT_FOUND)

    def _mask_path(self, query: dict):
        try:
            return self.state.mask_path(int(query.get("index", -1)))
        except ValueError:
            return None

    def _save_mask(self, query: dict) -> None:
        """A painted mask: the same kind of PNG, the same size, written whole or not at all."""
        import os
        import tempfile
        from io import BytesIO

        from PIL import Image

        path = self._mask_path(query)
        length = int(self.headers.get("Content-Length") or 0)
        if path is None or not _png8(path):
            return self._send(b"no such paintable mask (8-bit PNG)", "text/plain", HTTPStatus.NOT_FOUND)
        if not 0 < length <= MAX_MASK_BYTES:
            return self._send(b"a mask must be a PNG of at most 256 MB", "text/plain", HTTPStatus.BAD_REQUEST)
        body = self.rfile.read(length)
        try:
            with Image.open(BytesIO(body)) as new, Image.open(path) as old:
                ok = new.format == "PNG" and new.size == old.size
        except (OSError, ValueError, Image.DecompressionBombError):
            ok = False
        if not ok:
            return self._send(b"not a PNG of the mask's size", "text/plain", HTTPStatus.BAD_REQUEST)
        from ..driver.running.mask_atlas import keep_record

        try:
            body = keep_record(body, path)
        except (OSError, ValueError) as err:
            return self._send(f"cannot read {path.name}: {err}".encode(), "text/plain", HTTPStatus.BAD_REQUEST)
        fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(body)
            os.replace(temporary, path)
        except OSError as err:
            try:
                os.unlink(temporary)
            except OSError:
                pass
            return self._send(f"cannot write {path.name}: {err.strerror or err}".encode(), "text/plain",
                              HTTPStatus.INTERNAL_SERVER_ERROR)
        self._send(b"ok", "text/plain")

    def do_POST(self):  # noqa: N802
        url = urlparse(self.path)
        if url.path == "/api/mask":
            return self._save_mask({k: v[-1] for k, v in parse_qs(url.query).items()})
        if url.path != "/api/preview":
            return self._send(b"not found", "text/plain", HTTPStatus.NOT_FOUND)
        length = int(self.headers.get("Content-Length") or 0)
        try:
            fraction = float(self.rfile.read(min(length, 64)).decode())
        except ValueError:
            fraction = -1.0
        if not 0.0 < fraction <= 1.0:
            return self._send(b"preview must be a fraction in (0, 1]", "text/plain", HTTPStatus.BAD_REQUEST)
        self.state.preview = fraction
        self.state.preview_changed.set()
        self._send(b"ok", "text/plain")

    def _static(self, name: str) -> None:
        root = resources.files("gamma.viewer") / "static"
        parts = [p for p in name.split("/") if p]
        if not parts or any(p in (".", "..") or p.startswith(".") for p in parts):
            return self._send(b"not found", "text/plain", HTTPStatus.NOT_FOUND)
        item = root.joinpath(*parts)
        if not item.is_file():
            return self._send(b"not found", "text/plain", HTTPStatus.NOT_FOUND)
        suffix = "." + parts[-1].rpartition(".")[2]
        self._send(item.read_bytes(), CONTENT_TYPES.get(suffix, "application/octet-stream"))

    def _events(self) -> None:
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        seen = -1
        try:
            while not self.state.closing:
                version = self.state.wait_change(seen, timeout=10.0)
                if self.state.closing:
                    break
                if version == seen:
                    self.wfile.write(b": keep-alive\n\n")
                else:
                    seen = version
                    self.wfile.write(f"data: {version}\n\n".encode())
                self.wfile.flush()
        except (BrokenPipeError, ConnectionResetError):
            pass


def serve(state: ViewerState, port: int = 0) -> ThreadingHTTPServer:
    """Start serving on 127.0.0.1:port (0: any free port) in a daemon thread."""
    handler = type("Handler", (_Handler,), {"state": state})
    server = ThreadingHTTPServer(("127.0.0.1", port), handler)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, name="gamma-viewer", daemon=True).start()
    return server
