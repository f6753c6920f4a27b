"""A corpus of malformed (and a few valid but awkward) mesh and scene files,
made by this script rather than stored: ``python tests/mesh_corpus.py DIR``
writes them to DIR; tests/test_mesh_corpus.py loads every one and asserts the
outcome listed here.

Each case is (file name, bytes, expected) where expected is "ok" (loads) or
the fragment the one-line error must contain.  Systematic damage of valid
files (every header line removed, the body cut at every tenth of its length,
random bytes flipped) is added by ``mutations`` with a fixed seed.
"""

from __future__ import annotations

import random
import struct
import sys
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
        ("ok_two_index_face.ply", ply_ascii(face_lines=["3 0 2 1", "2 0 1", "3 0 1 3"], face_count=3), "ok"),
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
    return c


def mutations(seed: int = 7, count: int = 60) -> list[tuple[str, bytes, str]]:
    """Damaged copies of valid files; expected "any" (a clean outcome either way)."""
    rng = random.Random(seed)
    bases = [("ascii.ply", ply_ascii()), ("le.ply", ply_binary()), ("be.ply", ply_binary(endian=">")),
             ("m.obj", obj())]
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
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, data, expected in cases() + mutations():
        (folder / name).write_bytes(data)
        written.append((folder / name, expected))
    return written


if __name__ == "__main__":
    for path, expected in write(Path(sys.argv[1] if len(sys.argv) > 1 else "mesh-corpus")):
        print(f"{path}\t{expected}")
