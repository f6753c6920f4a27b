"""Small analytic meshes for tests, written as OBJ files."""

import numpy as np


def icosphere(subdivisions: int = 3, radius: float = 1.0):
    """A closed sphere, triangles wound so normals point outward."""
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        cache, faces = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = faces
    return np.array(verts) * radius, np.array(f)


def write_obj(path, verts, faces):
    with open(path, "w") as out:
        for p in verts:
            out.write(f"v {p[0]:.9g} {p[1]:.9g} {p[2]:.9g}\n")
        for a, b, c in faces:
            out.write(f"f {a + 1} {b + 1} {c + 1}\n")
    return path


def bumpy_sphere(subdivisions: int = 4, seed: int = 0):
    """A closed sphere with smooth random bumps and dents: convex and concave
    regions, like a small real object, with no file outside the repository."""
    verts, faces = icosphere(subdivisions)
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(12, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    amplitude = rng.uniform(-0.25, 0.25, size=12)
    bump = sum(a * np.exp(-np.sum((verts - c) ** 2, axis=1) / 0.08) for a, c in zip(amplitude, centres))
    return verts * (1 + bump)[:, None], faces
