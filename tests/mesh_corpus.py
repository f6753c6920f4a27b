"""A corpus of malformed (and a few valid but awkward) mesh and scene files
(OBJ, PLY, glTF: ``.gltf`` and ``.glb``),
made by this script rather than stored: ``python tests/mesh_corpus.py DIR``
writes them to DIR; tests/test_mesh_corpus.py loads every one and asserts the
outcome listed here.

Each case is (file name, bytes, expected) where expected is "ok" (loads),
the fragment the one-line error must contain, or "companion" (a file another
case refers to, such as a glTF's external buffer; written, not loaded).  Systematic damage of valid
files (every header line removed, the body cut at every tenth of its length,
random bytes flipped) is added by ``mutations`` with a fixed seed.
"""

from __future__ import annotations

import base64
import json
import random
import struct
import sys
import zlib
from pathlib import Path

TETRA_V = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
TETRA_F = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def ply_ascii(verts=TETRA_V, faces=TETRA_F, extra_header="", vertex_count=None, face_count=None,
              face_lines=None) -> bytes:
    head = ["ply", "format ascii 1.0", extra_header.rstrip("\n") if extra_header else None,
            f"element vertex {len(verts) if vertex_count is None else vertex_count}",
            "property float x", "property float y", "property float z",
            f"element face {len(faces) if face_count is None else face_count}",
            "property list uchar int vertex_indices", "end_header"]
    body = [" ".join(map(str, v)) for v in verts]
    body += face_lines if face_lines is not None else [f"{len(f)} " + " ".join(map(str, f)) for f in faces]
    return ("\n".join(h for h in head if h is not None) + "\n" + "\n".join(body) + "\n").encode()


def ply_binary(verts=TETRA_V, faces=TETRA_F, endian="<", vertex_count=None, face_count=None,
               index_type=("int", "i")) -> bytes:
    name = "binary_little_endian" if endian == "<" else "binary_big_endian"
    head = ["ply", f"format {name} 1.0",
            f"element vertex {len(verts) if vertex_count is None else vertex_count}",
            "property float x", "property float y", "property float z",
            f"element face {len(faces) if face_count is None else face_count}",
            f"property list uchar {index_type[0]} vertex_indices", "end_header"]
    body = b"".join(struct.pack(endian + "fff", *v) for v in verts)
    body += b"".join(struct.pack(endian + "B" + index_type[1] * len(f), len(f), *f) for f in faces)
    return ("\n".join(head) + "\n").encode() + body


def obj(verts=TETRA_V, faces=TETRA_F, prefix=b"") -> bytes:
    text = "".join(f"v {x} {y} {z}\n" for x, y, z in verts)
    text += "".join("f " + " ".join(str(i + 1) for i in f) + "\n" for f in faces)
    return prefix + text.encode()


def cases() -> list[tuple[str, bytes, str]]:
    big = 10 ** 11
    c = [
        # --- valid, awkward ---
        ("ok_ascii.ply", ply_ascii(), "ok"),
        ("ok_le.ply", ply_binary(), "ok"),
        ("ok_be.ply", ply_binary(endian=">"), "ok"),
        ("ok_crlf.ply", ply_ascii().replace(b"\n", b"\r\n"), "ok"),
        ("ok_uint_index.ply", ply_binary(index_type=("uint", "I")), "ok"),
        ("ok_quad.ply", ply_ascii(verts=[(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1)],
                                  faces=[(0, 1, 2, 3), (0, 1, 4)]), "ok"),
        ("ok_degenerate_face.ply", ply_ascii(faces=TETRA_F + [(0, 0, 1)]), "ok"),
        ("ok_nonmanifold.ply", ply_ascii(verts=TETRA_V + [(0, -1, 0)],
                                         faces=TETRA_F + [(0, 1, 4), (0, 1, 2)]), "ok"),
        ("ok_extra_element.ply", ply_ascii(extra_header="comment hello\nobj_info x"), "ok"),
        ("ok_latin1_comment.obj", obj(prefix=b"# caf\xe9\n"), "ok"),
        # --- PLY headers ---
        ("empty.ply", b"", "does not start with 'ply'"),
        ("not_ply.ply", b"hello\n", "does not start with 'ply'"),
        ("header_truncated.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", "end_header"),
        ("header_no_newline.ply", b"ply\nformat ascii 1.0\nelement vertex 3", "end_header"),
        ("header_endless.ply", b"ply\n" + b"comment " + b"x" * (2 << 20) + b"\n", "end_header"),
        ("no_format.ply", b"ply\nelement vertex 0\nend_header\n", "format"),
        ("bad_format.ply", b"ply\nformat utf16 1.0\nend_header\n", "unknown format"),
        ("negative_count.ply", ply_ascii(vertex_count=-4), "element NAME COUNT"),
        ("count_not_number.ply", ply_ascii(vertex_count="lots"), "element NAME COUNT"),
        ("count_overflow.ply", ply_ascii(vertex_count="99999999999999999999999"), "element NAME COUNT"),
        ("bad_type.ply", ply_ascii().replace(b"property float x", b"property quad x"), "unknown property type"),
        ("bad_list.ply", ply_ascii().replace(b"list uchar int", b"list float int"), "property list"),
        ("unknown_keyword.ply", ply_ascii().replace(b"end_header", b"hello\nend_header"), "unknown keyword"),
        ("property_first.ply", b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", "before any element"),
        # --- declared sizes against the file ---
        ("huge_vertices_ascii.ply", ply_ascii(vertex_count=big), "more than its"),
        ("huge_vertices_binary.ply", ply_binary(vertex_count=big), "more than its"),
        ("huge_faces_binary.ply", ply_binary(face_count=big), "more than its"),
        ("huge_faces_ascii.ply", ply_ascii(face_count=big), "more than its"),
        ("long_list.ply", ply_ascii(face_lines=["255 0 1 2"] * 4), "face 0 has vertex index 255"),
        ("long_list_end.ply", ply_ascii(face_lines=["3 0 1 2"] * 3 + ["200 0 1 2"]), "ends early"),
        # --- bodies ---
        ("body_truncated_binary.ply", ply_binary()[:-7], "ends early"),
        ("body_truncated_ascii.ply", ply_ascii(faces=TETRA_F, face_lines=["3 0 2 1", "3 0 1"]),
         "ends early"),
        ("index_out_of_range.ply", ply_ascii(faces=[(0, 1, 7)]), "out of range"),
        ("index_negative.ply", ply_ascii(faces=[(0, 1, -2)]), "out of range"),
        ("index_fraction.ply", ply_ascii(face_lines=["3 0 1 2.5"], face_count=1), "not a whole number"),
        ("nan_vertex.ply", ply_ascii(verts=[(0, 0, 0), (1, 0, 0), ("nan", 1, 0), (0, 0, 1)]), "non-finite"),
        ("inf_vertex_binary.ply", ply_binary(verts=[(0, 0, 0), (1, 0, 0), (float("inf"), 1, 0), (0, 0, 1)]),
         "non-finite"),
        ("huge_vertex.ply", ply_ascii(verts=[(0, 0, 0), (1, 0, 0), ("1e300", 1, 0), (0, 0, 1)]), "non-finite"),
        ("word_in_body.ply", ply_ascii(verts=[(0, 0, 0), (1, 0, 0), ("abc", 1, 0), (0, 0, 1)]),
         "cannot read 'abc'"),
        ("no_xyz.ply", ply_ascii().replace(b"property float z", b"property float w"), "without x, y and z"),
        ("no_faces_element.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                                 b"property float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n",
         "no triangles"),
        ("only_degenerate.ply", ply_ascii(faces=[(0, 0, 1), (2, 2, 2)]), "only degenerate"),
        ("two_corner_face.ply", ply_ascii(face_lines=["3 0 1 2", "2 1 3"], face_count=2),
         "face 1 has fewer than 3 vertices (2)"),
        ("flat.ply", ply_ascii(verts=[(0, 0, 0), (1, 0, 0), (2, 0, 0)], faces=[(0, 1, 2)]), "degenerate"),
        # --- OBJ ---
        ("empty.obj", b"", "no triangles"),
        ("latin1_group.obj", obj(prefix=b"g caf\xe9\n"), "not UTF-8"),
        ("latin1_object.obj", obj(prefix=b"o \xff\xfe\n"), "not UTF-8"),
        ("latin1_material.obj", obj(prefix=b"usemtl m\xe9tal\n"), "not UTF-8"),
        ("obj_bad_vertex.obj", b"v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "cannot read vertex"),
        ("obj_nan.obj", obj(verts=[(0, 0, 0), (1, 0, 0), ("nan", 1, 0), (0, 0, 1)]), "non-finite"),
        ("obj_zero_index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "out of range"),
        ("obj_huge_index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999\n", "out of range"),
        ("obj_two_corners.obj", b"v 0 0 0\nv 1 0 0\nf 1 2\n", "fewer than 3"),
        ("obj_garbage_face.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 x 3\n", "cannot read"),
        ("obj_nul.obj", obj() + b"\0\0\0", "ok"),
        ("obj_binary.obj", bytes(range(256)) * 4, "no triangles"),
        ("obj_huge_scale.obj", obj(verts=[(0, 0, 0), (1e38, 0, 0), (0, 1e38, 0), (0, 0, 1e38)]),
         "extent"),
    ]
    return c + gltf_cases()


# ---- glTF ---------------------------------------------------------------------------

def png(width: int, height: int, rgb=(200, 40, 40), bit_depth: int = 8, idat: bytes | None = None) -> bytes:
    """A PNG of one colour (8-bit RGB) or, at bit depth 1, a black bilevel
    image (each row one filter byte and zeros: a huge image in a few KB)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    colour_type = 2 if bit_depth == 8 else 0
    if idat is None:
        row = b"\0" + (bytes(rgb) * width if bit_depth == 8 else bytes((width + 7) // 8))
        idat = zlib.compress(row * height, 9)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0))
            + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def gltf_parts(verts=TETRA_V, faces=TETRA_F, texture: bytes | None = None) -> tuple[dict, bytes]:
    """(glTF JSON, binary buffer) of one node drawing one triangle mesh; with
    ``texture`` (PNG bytes) also texture coordinates and a base-colour texture
    stored in the buffer."""
    positions = b"".join(struct.pack("<3f", *map(float, v)) for v in verts)
    indices = b"".join(struct.pack("<3I", *f) for f in faces)
    finite = [v for v in verts if all(abs(float(c)) < float("inf") for c in v)] or [(0, 0, 0)]
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "tetra"}],
        "meshes": [{"name": "TetraMesh", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(verts), "type": "VEC3",
             "min": [min(float(v[k]) for v in finite) for k in range(3)],
             "max": [max(float(v[k]) for v in finite) for k in range(3)]},
            {"bufferView": 1, "componentType": 5125, "count": 3 * len(faces), "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(positions)},
                        {"buffer": 0, "byteOffset": len(positions), "byteLength": len(indices)}],
    }
    data = positions + indices
    if texture is not None:
        uvs = b"".join(struct.pack("<2f", (i % 2) * 1.0, (i // 2) * 1.0) for i in range(len(verts)))
        doc["accessors"].append({"bufferView": 2, "componentType": 5126, "count": len(verts), "type": "VEC2"})
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(data), "byteLength": len(uvs)})
        data += uvs
        data += b"\0" * (-len(data) % 4)
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(data), "byteLength": len(texture)})
        data += texture
        doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 2
        doc["meshes"][0]["primitives"][0]["material"] = 0
        doc["materials"] = [{"name": "Painted", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        doc["textures"] = [{"source": 0}]
        doc["images"] = [{"bufferView": 3, "mimeType": "image/png"}]
    doc["buffers"] = [{"byteLength": len(data)}]
    return doc, data


def glb(doc: dict, data: bytes | None) -> bytes:
    """A binary glTF: 12-byte header, a JSON chunk and (with data) a BIN chunk."""
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text
    if data is not None:
        data += b"\0" * (-len(data) % 4)
        body += struct.pack("<I4s", len(data), b"BIN\0") + data
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def gltf_embedded(doc: dict, data: bytes, uri: str | None = None) -> bytes:
    """A text glTF whose buffer is a data: URI (or ``uri`` as given)."""
    doc = json.loads(json.dumps(doc))
    doc["buffers"][0]["uri"] = (uri if uri is not None
                                else "data:application/octet-stream;base64," + base64.b64encode(data).decode())
    return json.dumps(doc).encode()


def edited(doc: dict, path: str, value) -> dict:
    """A deep copy of doc with the item at the dotted path (list indices as
    numbers) set to value, or deleted when value is DELETE."""
    doc = json.loads(json.dumps(doc))
    *parents, last = path.split(".")
    node = doc
    for key in parents:
        node = node[int(key)] if isinstance(node, list) else node[key]
    key = int(last) if isinstance(node, list) else last
    if value is DELETE:
        del node[key]
    else:
        node[key] = value
    return doc


DELETE = object()


#: The one-line error each malformed glTF of ``gltf_cases`` must end in (a fragment).
GLTF_ERRORS = {
    "glb_empty.glb": "not a binary glTF",
    "glb_header_only.glb": "the header declares 692 bytes but the file has 12",
    "glb_cut_in_json.glb": "but the file has 40",
    "glb_cut_in_bin.glb": "but the file has 672",
    "glb_bad_magic.glb": "not a binary glTF",
    "glb_version_1.glb": "version 1; only version 2",
    "glb_huge_length.glb": "declares 4294967280 bytes",
    "glb_huge_json_chunk.glb": "chunk 0 declares 2147483632 bytes",
    "glb_no_bin_chunk.glb": "no binary chunk",
    "glb_json_not_utf8.glb": "not UTF-8",
    "empty.gltf": "JSON is malformed",
    "bad_json.gltf": "JSON is malformed",
    "json_array.gltf": "must be an object, not list",
    "json_deep.gltf": "nested too deeply",
    "json_latin1.gltf": "not UTF-8",
    "no_meshes.gltf": "nodes[0].mesh is 0, not one of the 0 meshes",
    "node_cycle.gltf": "node graph must be a tree",
    "nan_matrix.gltf": "non-finite",
    "points_only.gltf": "has no triangle mesh",
    "no_buffers.gltf": "not one of the 0 buffers",
    "buffer_index_out_of_range.gltf": "bufferViews[1].buffer is 5",
    "buffer_longer_than_data.gltf": "byteLength is 1000000000000 but its data has 96 bytes",
    "view_out_of_range.gltf": "bufferViews[1] covers bytes 1000000000",
    "view_too_long.gltf": "bufferViews[0] covers bytes 0 to 1000000000000",
    "view_negative.gltf": "byteOffset must be a whole number",
    "view_index_out_of_range.gltf": "accessors[0].bufferView is 9",
    "accessor_huge_count.gltf": "declares 1000000000000 elements",
    "accessor_huge_index_count.glb": "declares 300000000000 elements",
    "accessor_count_not_number.gltf": "count must be a whole number",
    "accessor_offset_out_of_range.gltf": "(88 bytes from byte 40)",
    "accessor_bad_type.gltf": '"VEC7"',
    "accessor_bad_component.gltf": "componentType 9999",
    "accessor_index_out_of_range.gltf": "POSITION is 7",
    "indices_out_of_range.glb": "vertex index 9 out of range",
    "indices_huge.glb": "out of range",
    "nan_position.glb": "vertex 2 has a non-finite",
    "inf_position.gltf": "vertex 2 has a non-finite",
    "data_uri_not_base64.gltf": "not valid base64",
    "data_uri_plain.gltf": "not base64",
    "data_uri_short.gltf": "byteLength is 96 but its data has 20",
    "missing_bin.gltf": "nowhere.bin': file not found",
    "bin_is_directory.gltf": "is a directory",
    "uri_nul.gltf": "NUL byte",
    "uri_remote.gltf": "not a file relative to the glTF",
    "texture_bomb.glb": "12000x12000 pixels; at most 8192x8192",
    "texture_huge_header.glb": "at most 8192x8192",
    "texture_not_png.glb": "images[0] is not an image",
}


def gltf_cases() -> list[tuple[str, bytes, str]]:
    doc, data = gltf_parts()
    good_glb = glb(doc, data)
    tex_doc, tex_data = gltf_parts(texture=png(4, 4))
    c = [
        ("ok_tetra.gltf", gltf_embedded(doc, data), "ok"),
        ("ok_tetra.glb", good_glb, "ok"),
        ("ok_external.gltf", gltf_embedded(doc, data, uri="ok_external.bin"), "ok"),
        ("ok_external.bin", data, "companion"),
        ("ok_textured.glb", glb(tex_doc, tex_data), "ok"),
        ("ok_degenerate_face.glb", glb(*gltf_parts(faces=TETRA_F + [(0, 0, 1)])), "ok"),
        # --- GLB containers ---
        ("glb_empty.glb", b"", "?"),
        ("glb_header_only.glb", good_glb[:12], "?"),
        ("glb_cut_in_json.glb", good_glb[:40], "?"),
        ("glb_cut_in_bin.glb", good_glb[:-20], "?"),
        ("glb_bad_magic.glb", b"gltf" + good_glb[4:], "?"),
        ("glb_version_1.glb", good_glb[:4] + struct.pack("<I", 1) + good_glb[8:], "?"),
        ("glb_huge_length.glb", good_glb[:8] + struct.pack("<I", 0xFFFFFFF0) + good_glb[12:], "?"),
        ("glb_huge_json_chunk.glb", good_glb[:12] + struct.pack("<I", 0x7FFFFFF0) + good_glb[16:], "?"),
        ("glb_no_bin_chunk.glb", glb(doc, None), "?"),
        ("glb_json_not_utf8.glb", glb(edited(doc, "nodes.0.name", "x"), data).replace(b'"x"', b'"\xff"'), "?"),
        # --- the JSON ---
        ("empty.gltf", b"", "?"),
        ("bad_json.gltf", b'{"asset": {"version": "2.0"}, "meshes": [', "?"),
        ("json_array.gltf", b"[1, 2, 3]", "?"),
        ("json_deep.gltf", b'{"asset": ' + b"[" * 100000 + b"]" * 100000 + b"}", "?"),
        ("json_latin1.gltf", gltf_embedded(edited(doc, "nodes.0.name", "x"), data).replace(b'"x"', b'"caf\xe9"'),
         "?"),
        ("no_meshes.gltf", gltf_embedded(edited(doc, "meshes", DELETE), data), "?"),
        ("node_cycle.gltf", gltf_embedded(edited(doc, "nodes.0.children", [0]), data), "?"),
        ("nan_matrix.gltf", gltf_embedded(edited(doc, "nodes.0.scale", [1e39, 1, 1]), data), "?"),
        ("points_only.gltf", gltf_embedded(edited(doc, "meshes.0.primitives.0.mode", 0), data), "?"),
        # --- buffers, views, accessors ---
        ("no_buffers.gltf", gltf_embedded(doc, data).replace(b'"buffers"', b'"buffers_"'), "?"),
        ("buffer_index_out_of_range.gltf", gltf_embedded(edited(doc, "bufferViews.1.buffer", 5), data), "?"),
        ("buffer_longer_than_data.gltf", gltf_embedded(edited(doc, "buffers.0.byteLength", 10 ** 12), data), "?"),
        ("view_out_of_range.gltf", gltf_embedded(edited(doc, "bufferViews.1.byteOffset", 10 ** 9), data), "?"),
        ("view_too_long.gltf", gltf_embedded(edited(doc, "bufferViews.0.byteLength", 10 ** 12), data), "?"),
        ("view_negative.gltf", gltf_embedded(edited(doc, "bufferViews.0.byteOffset", -48), data), "?"),
        ("view_index_out_of_range.gltf", gltf_embedded(edited(doc, "accessors.0.bufferView", 9), data), "?"),
        ("accessor_huge_count.gltf", gltf_embedded(edited(doc, "accessors.0.count", 10 ** 12), data), "?"),
        ("accessor_huge_index_count.glb", glb(edited(doc, "accessors.1.count", 3 * 10 ** 11), data), "?"),
        ("accessor_count_not_number.gltf", gltf_embedded(edited(doc, "accessors.0.count", "many"), data), "?"),
        ("accessor_offset_out_of_range.gltf", gltf_embedded(edited(doc, "accessors.0.byteOffset", 40), data),
         "?"),
        ("accessor_bad_type.gltf", gltf_embedded(edited(doc, "accessors.0.type", "VEC7"), data), "?"),
        ("accessor_bad_component.gltf", gltf_embedded(edited(doc, "accessors.0.componentType", 9999), data),
         "?"),
        ("accessor_index_out_of_range.gltf",
         gltf_embedded(edited(doc, "meshes.0.primitives.0.attributes.POSITION", 7), data), "?"),
        ("indices_out_of_range.glb", glb(*gltf_parts(faces=[(0, 1, 2), (0, 1, 9)])), "?"),
        ("indices_huge.glb", glb(*gltf_parts(faces=[(0, 1, 2), (0, 1, 0xFFFFFFFF)])), "?"),
        ("nan_position.glb", glb(*gltf_parts(verts=[(0, 0, 0), (1, 0, 0), (float("nan"), 1, 0), (0, 0, 1)])),
         "?"),
        ("inf_position.gltf", gltf_embedded(*gltf_parts(verts=[(0, 0, 0), (1, 0, 0), (0, float("inf"), 0),
                                                               (0, 0, 1)])), "?"),
        # --- URIs ---
        ("data_uri_not_base64.gltf", gltf_embedded(doc, data, uri="data:application/octet-stream;base64,@@@@"),
         "?"),
        ("data_uri_plain.gltf", gltf_embedded(doc, data, uri="data:,hello"), "?"),
        ("data_uri_short.gltf", gltf_embedded(doc, data[:20]), "?"),
        ("missing_bin.gltf", gltf_embedded(doc, data, uri="nowhere.bin"), "?"),
        ("bin_is_directory.gltf", gltf_embedded(doc, data, uri="."), "?"),
        ("uri_nul.gltf", gltf_embedded(doc, data, uri="a\0b.bin"), "?"),
        ("uri_remote.gltf", gltf_embedded(doc, data, uri="http://127.0.0.1:9/x.bin"), "?"),
        # --- textures ---
        ("texture_bomb.glb", glb(*gltf_parts(texture=png(12000, 12000, bit_depth=1))), "?"),
        ("texture_huge_header.glb", glb(*gltf_parts(texture=png(60000, 60000, idat=b"x"))), "?"),
        ("texture_not_png.glb", glb(*gltf_parts(texture=b"\x89PNG\r\n\x1a\nnot really")), "?"),
    ]
    return [(name, data, GLTF_ERRORS[name] if expected == "?" else expected) for name, data, expected in c]


def mutations(seed: int = 7, count: int = 60) -> list[tuple[str, bytes, str]]:
    """Damaged copies of valid files; expected "any" (a clean outcome either way)."""
    rng = random.Random(seed)
    bases = [("ascii.ply", ply_ascii()), ("le.ply", ply_binary()), ("be.ply", ply_binary(endian=">")),
             ("m.obj", obj()), ("m.glb", glb(*gltf_parts(texture=png(2, 2)))),
             ("m.gltf", gltf_embedded(*gltf_parts()))]
    out = []
    for name, data in bases:
        lines = data.split(b"\n")
        for i in range(min(len(lines), 12)):   # each header line dropped
            out.append((f"drop{i}_{name}", b"\n".join(lines[:i] + lines[i + 1:]), "any"))
        for k in range(1, 10):                  # cut at every tenth
            out.append((f"cut{k}_{name}", data[: len(data) * k // 10], "any"))
    for n in range(count):
        name, data = rng.choice(bases)
        data = bytearray(data)
        for _ in range(rng.randint(1, 6)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        out.append((f"flip{n}_{name}", bytes(data), "any"))
    return out


def write(folder: Path) -> list[tuple[Path, str]]:
    """Writes the corpus; returns the files to load and what each must give."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, data, expected in cases() + mutations():
        (folder / name).write_bytes(data)
        if expected != "companion":
            written.append((folder / name, expected))
    return written


def load(path: Path) -> tuple:
    """("ok", triangles) or ("error", message) for one file, read as
    ``gammac run --scene`` reads it (glTF through the driver's reader); any
    other exception propagates (a failure)."""
    import gamma._runtime as rt
    from gamma.driver.running.scene import SceneError, _file_parts

    try:
        parts = _file_parts(rt, Path(path))
    except (SceneError, ValueError) as err:
        return ("error", str(err))
    return ("ok", sum(p.mesh.num_triangles for p in parts))


if __name__ == "__main__":
    for path, expected in write(Path(sys.argv[1] if len(sys.argv) > 1 else "mesh-corpus")):
        print(f"{path}\t{expected}")
