"""The parts of a ``gammac`` export (``export/SCENE_NNNN.glb``) as numpy
arrays: per node its name, positions, normals, texture coordinates, the
per-point property attributes and, per primitive, its triangles and material.

The add-on builds Blender meshes from these itself rather than through
Blender's glTF importer, so that the weathered mesh lands in the object the
user selected (same name, same datablock slot) instead of in new objects
whose names Blender may suffix with ".001".  No ``bpy`` here.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


@dataclass
class Primitive:
    triangles: np.ndarray        # (T, 3) indices into the part's vertices
    material: str                # the material's name ("" for none)


@dataclass
class Part:
    name: str
    positions: np.ndarray        # (V, 3) float32, glTF axes (+Y up), world space
    normals: np.ndarray | None   # (V, 3)
    uvs: np.ndarray | None       # (V, 2), glTF convention (v down)
    attributes: dict = field(default_factory=dict)   # "_PATINA" -> (V,) float32
    primitives: list = field(default_factory=list)


def _chunks(data: bytes) -> tuple[dict, bytes]:
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2:
        raise ValueError("not a glTF 2.0 binary file")
    offset, document, binary = 12, None, b""
    while offset < min(length, len(data)):
        size, kind = struct.unpack_from("<II", data, offset)
        body = data[offset + 8: offset + 8 + size]
        if kind == 0x4E4F534A:
            document = json.loads(body)
        elif kind == 0x004E4942:
            binary = body
        offset += 8 + size
    if document is None:
        raise ValueError("a glb without its JSON chunk")
    return document, binary


def _accessor(document: dict, binary: bytes, index: int) -> np.ndarray:
    acc = document["accessors"][index]
    view = document["bufferViews"][acc["bufferView"]]
    dtype = np.dtype(_COMPONENTS[acc["componentType"]])
    width = _WIDTH[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride") or dtype.itemsize * width
    count = acc["count"]
    raw = np.frombuffer(binary, dtype=np.uint8, count=stride * (count - 1) + dtype.itemsize * width, offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, shape=(count, dtype.itemsize * width), strides=(stride, 1))
    values = np.ascontiguousarray(rows).view(dtype).reshape(count, width)
    return values[:, 0] if width == 1 else values


def read_parts(path: Path) -> list[Part]:
    """Every node with a mesh, in the file's order."""
    document, binary = _chunks(Path(path).read_bytes())
    materials = [m.get("name", "") for m in document.get("materials", [])]
    parts = []
    for node in document.get("nodes", []):
        if "mesh" not in node:
            continue
        mesh = document["meshes"][node["mesh"]]
        part, shared_positions = None, None
        for prim in mesh["primitives"]:
            attrs = prim["attributes"]
            if part is None:
                part = Part(name=node.get("name", mesh.get("name", "")),
                            positions=_accessor(document, binary, attrs["POSITION"]),
                            normals=_accessor(document, binary, attrs["NORMAL"]) if "NORMAL" in attrs else None,
                            uvs=_accessor(document, binary, attrs["TEXCOORD_0"]) if "TEXCOORD_0" in attrs else None,
                            attributes={k: _accessor(document, binary, v) for k, v in attrs.items()
                                        if k.startswith("_")})
                shared_positions = attrs["POSITION"]
            elif attrs["POSITION"] != shared_positions:
                raise ValueError(f"part {part.name}: primitives with vertices of their own are not gamma's layout")
            triangles = _accessor(document, binary, prim["indices"]).astype(np.int64).reshape(-1, 3)
            name = materials[prim["material"]] if "material" in prim else ""
            part.primitives.append(Primitive(triangles, name))
        if part is not None:
            parts.append(part)
    return parts
