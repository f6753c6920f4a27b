"""Checks a glTF 2.0 file (``.gltf`` or ``.glb``) before trimesh reads it.

trimesh trusts the file: a truncated GLB chunk, a buffer view past its
buffer, an accessor declaring 10^12 elements or a data: URI that is not
base64 reach it as an IndexError, a KeyError or an empty message.  Here the
container (GLB header and chunks), the JSON (UTF-8, an object, not nested
absurdly), every buffer (data: URI in base64, a local file that exists and
is long enough, or the GLB's BIN chunk), every buffer view and accessor
(indices in range, sizes within the bytes present), the node graph (no
cycles) and every image (decodable header, at most MAX_TEXTURE_SIDE pixels a
side, so a decompression bomb costs nothing) are checked first, and a
problem is one line naming the file, the item and the value.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import math
import struct
import urllib.parse
import warnings
from pathlib import Path

from ...files import file_problem

#: Largest base-colour texture of a glTF material, in pixels per side (the
#: same limit as texture() images, SPEC §8a); read from the image's header.
MAX_TEXTURE_SIDE = 8192

COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
GLB_MAGIC = b"glTF"
GLB_JSON = 0x4E4F534A
GLB_BIN = 0x004E4942


class GltfError(Exception):
    """A one-line, user-facing problem with a glTF file."""


def check_gltf(path: Path) -> None:
    """Raise GltfError naming ``path`` and the first problem found."""
    where = f"cannot read glTF '{path}'"
    try:
        data = path.read_bytes()
    except OSError as err:
        raise GltfError(f"{where}: {err.strerror or err}") from None
    if path.suffix.lower() == ".glb":
        text, bin_chunk = _glb_chunks(data, where)
    else:
        text, bin_chunk = data, None
    doc = _json(text, where)
    _Checker(path, where, doc, bin_chunk).run()


def _glb_chunks(data: bytes, where: str) -> tuple[bytes, bytes | None]:
    if len(data) < 12 or data[:4] != GLB_MAGIC:
        raise GltfError(f"{where}: not a binary glTF (it must start with 'glTF' and a 12-byte header)")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise GltfError(f"{where}: binary glTF version {version}; only version 2 is supported")
    if length != len(data):
        raise GltfError(f"{where}: the header declares {length} bytes but the file has {len(data)}")
    chunks = []
    at = 12
    while at < len(data):
        if at + 8 > len(data):
            raise GltfError(f"{where}: chunk {len(chunks)} is cut off in its 8-byte header at byte {at}")
        size, kind = struct.unpack_from("<II", data, at)
        if at + 8 + size > len(data):
            raise GltfError(f"{where}: chunk {len(chunks)} declares {size} bytes but only "
                            f"{len(data) - at - 8} follow (the file is truncated)")
        chunks.append((kind, data[at + 8: at + 8 + size]))
        at += 8 + size
    if not chunks or chunks[0][0] != GLB_JSON:
        raise GltfError(f"{where}: the first chunk must be the JSON chunk")
    bin_chunk = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == GLB_BIN else None
    return chunks[0][1], bin_chunk


def _json(text: bytes, where: str) -> dict:
    try:
        doc = json.loads(text.decode("utf-8"))
    except UnicodeDecodeError as err:
        raise GltfError(f"{where}: the JSON is not UTF-8 (byte {err.start})") from None
    except RecursionError:
        raise GltfError(f"{where}: the JSON is nested too deeply to be glTF") from None
    except json.JSONDecodeError as err:
        raise GltfError(f"{where}: the JSON is malformed: {err}") from None
    if not isinstance(doc, dict):
        raise GltfError(f"{where}: the JSON must be an object, not {type(doc).__name__}")
    version = doc.get("asset", {}).get("version") if isinstance(doc.get("asset"), dict) else None
    if not isinstance(version, str) or not version.startswith("2."):
        raise GltfError(f"{where}: asset.version must be \"2.x\", not {json.dumps(version)}")
    return doc


def _one_of(value, table: dict) -> bool:
    return isinstance(value, (int, str)) and not isinstance(value, bool) and value in table


def _whole(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


class _Checker:
    def __init__(self, path: Path, where: str, doc: dict, bin_chunk: bytes | None):
        self.path, self.where, self.doc, self.bin_chunk = path, where, doc, bin_chunk
        self.buffer_data: list[bytes] = []

    def fail(self, what: str):
        raise GltfError(f"{self.where}: {what}")

    def items(self, key: str) -> list:
        value = self.doc.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            self.fail(f"\"{key}\" must be a list of objects")
        return value

    def index(self, owner: str, field: str, value, key: str, required: bool = True) -> int | None:
        if value is None and not required:
            return None
        count = len(self.items(key))
        if not _whole(value) or value >= count:
            self.fail(f"{owner}.{field} is {json.dumps(value)}, not one of the {count} {key}")
        return value

    def whole(self, owner: str, field: str, value, default=None) -> int:
        if value is None and default is not None:
            return default
        if not _whole(value):
            self.fail(f"{owner}.{field} must be a whole number ≥ 0, not {json.dumps(value)}")
        return value

    def run(self) -> None:
        for i, buffer in enumerate(self.items("buffers")):
            self.buffer_data.append(self.buffer(i, buffer))
        for i, view in enumerate(self.items("bufferViews")):
            self.buffer_view(i, view)
        for i, accessor in enumerate(self.items("accessors")):
            self.accessor(i, accessor)
        for i, mesh in enumerate(self.items("meshes")):
            self.mesh(i, mesh)
        self.nodes()
        for i, texture in enumerate(self.items("textures")):
            self.index(f"textures[{i}]", "source", texture.get("source"), "images", required=False)
        for i, image in enumerate(self.items("images")):
            self.image(i, image)

    def buffer(self, i: int, buffer: dict) -> bytes:
        owner = f"buffers[{i}]"
        length = self.whole(owner, "byteLength", buffer.get("byteLength"))
        uri = buffer.get("uri")
        if uri is None:
            if i != 0 or self.bin_chunk is None:
                self.fail(f"{owner} has no uri and the file has no binary chunk for it")
            data = self.bin_chunk
        else:
            data = self.uri_bytes(owner, uri)
        if len(data) < length:
            self.fail(f"{owner}.byteLength is {length} but its data has {len(data)} bytes")
        return data

    def uri_bytes(self, owner: str, uri) -> bytes:
        if not isinstance(uri, str) or not uri:
            self.fail(f"{owner}.uri must be a non-empty string")
        if uri.startswith("data:"):
            head, comma, payload = uri.partition(",")
            if not comma or not head.endswith(";base64"):
                self.fail(f"{owner}.uri is a data: URI that is not base64 ('{head[:60]}')")
            try:
                return base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError) as err:
                self.fail(f"{owner}.uri is not valid base64 ({err})")
        if "://" in uri or uri.startswith("/"):
            self.fail(f"{owner}.uri '{uri[:200]}' is not a file relative to the glTF")
        name = urllib.parse.unquote(uri)
        if "\0" in name:
            self.fail(f"{owner}.uri contains a NUL byte")
        target = self.path.parent / name
        problem = file_problem(target)
        if problem:
            self.fail(f"{owner}.uri '{target}': {problem}")
        try:
            return target.read_bytes()
        except OSError as err:
            self.fail(f"{owner}.uri '{target}': {err.strerror or err}")

    def buffer_view(self, i: int, view: dict) -> None:
        owner = f"bufferViews[{i}]"
        b = self.index(owner, "buffer", view.get("buffer"), "buffers")
        offset = self.whole(owner, "byteOffset", view.get("byteOffset"), default=0)
        length = self.whole(owner, "byteLength", view.get("byteLength"))
        available = len(self.buffer_data[b])
        if offset + length > available:
            self.fail(f"{owner} covers bytes {offset} to {offset + length} of buffers[{b}], "
                      f"which has {available}")
        stride = view.get("byteStride")
        if stride is not None and (not _whole(stride) or not 4 <= stride <= 252):
            self.fail(f"{owner}.byteStride must be 4 to 252, not {json.dumps(stride)}")

    def accessor(self, i: int, accessor: dict) -> None:
        owner = f"accessors[{i}]"
        component = accessor.get("componentType")
        if not _one_of(component, COMPONENT_BYTES):
            self.fail(f"{owner}.componentType {json.dumps(component)} is not a glTF component type "
                      f"({', '.join(map(str, COMPONENT_BYTES))})")
        kind = accessor.get("type")
        if not _one_of(kind, TYPE_COMPONENTS):
            self.fail(f"{owner}.type {json.dumps(kind)[:60]} is not one of {', '.join(TYPE_COMPONENTS)}")
        count = self.whole(owner, "count", accessor.get("count"))
        if "sparse" in accessor:
            self.fail(f"{owner} is sparse, which is not supported")
        v = self.index(owner, "bufferView", accessor.get("bufferView"), "bufferViews", required=False)
        if v is None:
            if count > 0:
                self.fail(f"{owner} has {count} elements but no bufferView")
            return
        view = self.items("bufferViews")[v]
        element = COMPONENT_BYTES[component] * TYPE_COMPONENTS[kind]
        stride = view.get("byteStride") or element
        offset = self.whole(owner, "byteOffset", accessor.get("byteOffset"), default=0)
        need = offset + (count - 1) * stride + element if count else 0
        if need > view["byteLength"]:
            self.fail(f"{owner} declares {count} elements ({need} bytes from byte {offset}) but "
                      f"bufferViews[{v}] has {view['byteLength']} bytes")

    def mesh(self, i: int, mesh: dict) -> None:
        primitives = mesh.get("primitives")
        if not isinstance(primitives, list) or not all(isinstance(p, dict) for p in primitives):
            self.fail(f"meshes[{i}].primitives must be a list of objects")
        for k, primitive in enumerate(primitives):
            owner = f"meshes[{i}].primitives[{k}]"
            attributes = primitive.get("attributes")
            if not isinstance(attributes, dict):
                self.fail(f"{owner}.attributes must be an object")
            for name, accessor in attributes.items():
                self.index(f"{owner}.attributes", name, accessor, "accessors")
            self.index(owner, "indices", primitive.get("indices"), "accessors", required=False)
            self.index(owner, "material", primitive.get("material"), "materials", required=False)
            mode = primitive.get("mode", 4)
            if not _whole(mode) or mode > 6:
                self.fail(f"{owner}.mode must be 0 to 6, not {json.dumps(mode)}")

    def nodes(self) -> None:
        nodes = self.items("nodes")
        parent: dict[int, int] = {}
        for i, node in enumerate(nodes):
            self.index(f"nodes[{i}]", "mesh", node.get("mesh"), "meshes", required=False)
            children = node.get("children", [])
            if not isinstance(children, list):
                self.fail(f"nodes[{i}].children must be a list")
            for child in children:
                self.index(f"nodes[{i}]", "children", child, "nodes")
                if child == i or child in parent:
                    self.fail(f"nodes[{child}] is a child twice or of itself (the node graph must be a tree)")
                parent[child] = i
            for field, n in (("matrix", 16), ("translation", 3), ("rotation", 4), ("scale", 3)):
                value = node.get(field)
                if value is not None and (not isinstance(value, list) or len(value) != n or not all(
                        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                        for x in value)):
                    self.fail(f"nodes[{i}].{field} must be a list of {n} finite numbers")
        for i in range(len(nodes)):          # a cycle through several nodes
            seen, at = {i}, i
            while at in parent:
                at = parent[at]
                if at in seen:
                    self.fail(f"nodes[{i}] is its own ancestor (the node graph must be a tree)")
                seen.add(at)
        for i, scene in enumerate(self.items("scenes")):
            roots = scene.get("nodes", [])
            if not isinstance(roots, list):
                self.fail(f"scenes[{i}].nodes must be a list")
            for root in roots:
                self.index(f"scenes[{i}]", "nodes", root, "nodes")

    def image(self, i: int, image: dict) -> None:
        from PIL import Image, UnidentifiedImageError

        owner = f"images[{i}]"
        v = self.index(owner, "bufferView", image.get("bufferView"), "bufferViews", required=False)
        if v is not None:
            view = self.items("bufferViews")[v]
            start = view.get("byteOffset", 0)
            data = self.buffer_data[view["buffer"]][start: start + view["byteLength"]]
        elif "uri" in image:
            data = self.uri_bytes(owner, image["uri"])
        else:
            self.fail(f"{owner} has neither a bufferView nor a uri")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)   # the side is checked below
                with Image.open(io.BytesIO(data)) as picture:
                    w, h = picture.size
        except Image.DecompressionBombError as err:
            self.fail(f"{owner} is too large to decode ({err}); at most "
                      f"{MAX_TEXTURE_SIDE}x{MAX_TEXTURE_SIDE} pixels are supported")
        except (OSError, UnidentifiedImageError, ValueError) as err:
            self.fail(f"{owner} is not an image that can be read ({err})")
        if max(w, h) > MAX_TEXTURE_SIDE:
            self.fail(f"{owner} is {w}x{h} pixels; at most {MAX_TEXTURE_SIDE}x{MAX_TEXTURE_SIDE} are supported")
