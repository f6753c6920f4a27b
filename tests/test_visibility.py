"""Environment source, k_s = 0 (every gamma-ton settles at its first impact),
on a closed cup with a deep cavity: the deposit per unit area at each surfel
must follow the cosine-weighted visibility of the environment, computed here
independently of the runtime with a plain numpy ray caster (Moller-Trumbore
against every triangle).

Each surfel collects the hits of its own cell (the points nearer to it than
to any other surfel), and blue-noise cells differ in area by about 10 %, so
the deposit is divided by the cell's area, estimated by Monte Carlo.  The
runtime then spreads each surfel's deposit over its neighbourhood (SPEC
§13.2, the splat kernel); the expected deposit is spread here the same way,
from SPEC's definition, written independently of the runtime."""

import json

import numpy as np

from conftest import run_gammac
from gamma.driver.outputs.outputs import read_ply

EFFECT = """
ton Dust { motion straight = 0.0  carry d = 1.0 }
surface Box { property dust = 0.0 }
source sky = environment(sphere) emits Dust count 2000000
on settle(t: Dust, s: Box) { s.dust += t.d }
"""


def load_obj(path):
    verts, faces = [], []
    for line in open(path):
        parts = line.split()
        if parts and parts[0] == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif parts and parts[0] == "f":
            faces.append([int(x.split("/")[0]) - 1 for x in parts[1:4]])
    v = np.array(verts)
    return v[np.array(faces)]          # (m, 3, 3)


def escapes(origins, dirs, tris, eps=1e-6):
    """True where the ray hits no triangle (t > eps)."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    e1, e2 = b - a, c - a
    free = np.ones(len(origins), bool)
    for start in range(0, len(origins), 2048):
        o, d = origins[start:start + 2048, None, :], dirs[start:start + 2048, None, :]
        p = np.cross(d, e2)
        det = np.sum(e1 * p, -1)
        inv = 1.0 / np.where(np.abs(det) < 1e-12, np.nan, det)
        s = o - a
        u = np.sum(s * p, -1) * inv
        q = np.cross(s, e1)
        v = np.sum(d * q, -1) * inv
        t = np.sum(e2 * q, -1) * inv
        hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > eps)
        free[start:start + 2048] = ~np.any(hit, axis=1)
    return free


def cosine_visibility(points, normals, tris, n_dirs, rng):
    """Fraction of cosine-weighted directions about each normal that escape."""
    u1, u2 = rng.random((2, len(points), n_dirs))
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], -1)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    dirs = (local[..., :1] * t1[:, None] + local[..., 1:2] * t2[:, None] + local[..., 2:] * normals[:, None])
    origins = np.repeat(points + normals * 1e-4, n_dirs, axis=0)
    return escapes(origins, dirs.reshape(-1, 3), tris).reshape(len(points), n_dirs).mean(1)


def cup():
    """A closed cup: a 2 x 2 x 2 block with a 1.2 x 1.6 x 1.2 cavity open at
    the top.  Big faces, so the test's ray caster stays fast; the cavity's
    floor sees little sky, its rim all of it.  Triangles face the air."""
    def inside(p):  # the solid: the block minus the cavity
        block = np.all(np.abs(p[[0, 2]]) < 1) and 0 < p[1] < 2
        cavity = np.all(np.abs(p[[0, 2]]) < 0.6) and p[1] > 0.4
        return block and not cavity

    quads = []
    for s_ in (-1, 1):
        quads += [[(s_, 0, -1), (s_, 0, 1), (s_, 2, 1), (s_, 2, -1)],          # outer walls
                  [(-1, 0, s_), (1, 0, s_), (1, 2, s_), (-1, 2, s_)],
                  [(0.6 * s_, 0.4, -0.6), (0.6 * s_, 0.4, 0.6), (0.6 * s_, 2, 0.6), (0.6 * s_, 2, -0.6)],
                  [(-0.6, 0.4, 0.6 * s_), (0.6, 0.4, 0.6 * s_), (0.6, 2, 0.6 * s_), (-0.6, 2, 0.6 * s_)],
                  [(-1, 2, 0.6 * s_), (1, 2, 0.6 * s_), (1, 2, s_), (-1, 2, s_)],  # rim
                  [(0.6 * s_, 2, -0.6), (s_, 2, -0.6), (s_, 2, 0.6), (0.6 * s_, 2, 0.6)]]
    quads += [[(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)],                  # bottom
              [(-0.6, 0.4, -0.6), (0.6, 0.4, -0.6), (0.6, 0.4, 0.6), (-0.6, 0.4, 0.6)]]  # cavity floor
    verts, faces = [], []
    for q in quads:
        q = np.array(q, float)
        for tri in ((0, 1, 2), (0, 2, 3)):
            a, b, c = q[list(tri)]
            n = np.cross(b - a, c - a)
            if inside((a + b + c) / 3 + 1e-3 * n / np.linalg.norm(n)):
                b, c = c, b
            faces.append([len(verts), len(verts) + 1, len(verts) + 2])
            verts += [a, b, c]
    return np.array(verts), np.array(faces)


def cells(points, tris, n_samples, rng):
    """Uniform samples on the surface, with their triangle's normal and the
    surfel whose cell (nearest surfel) they fall in."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    pick = rng.choice(len(tris), n_samples, p=area / area.sum())
    u, v = rng.random((2, n_samples))
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    samples = a[pick] + u[:, None] * (b - a)[pick] + v[:, None] * (c - a)[pick]
    normals = cross[pick] / (2 * area[pick])[:, None]
    owner = np.concatenate([np.argmin(((chunk[:, None, :] - points[None]) ** 2).sum(-1), axis=1)
                            for chunk in np.array_split(samples, 64)])
    return samples, normals, owner, area.sum()


def splat(amount, points, normals, sigma):
    """SPEC §13.2: each surfel's amount spread over the surfels within 2 sigma,
    normals within 60 degrees, within sigma/2 of its tangent plane, with
    Gaussian weights of width sigma normalised to 1."""
    d = points[None, :, :] - points[:, None, :]            # [i, j] = p_j - p_i
    dist2 = (d ** 2).sum(-1)
    near = (dist2 <= (2 * sigma) ** 2) & (normals @ normals.T >= 0.5) \
        & (np.abs((d * normals[:, None, :]).sum(-1)) <= sigma / 2)
    w = np.where(near, np.exp(-dist2 / (2 * sigma ** 2)), 0.0)
    w /= w.sum(1, keepdims=True)
    return w.T @ amount


def test_deposit_follows_cosine_weighted_visibility(tmp_path):
    from meshes import write_obj

    mesh = write_obj(tmp_path / "cup.obj", *cup())
    (tmp_path / "dust.gamma").write_text(EFFECT.replace("2000000", "8000000"))
    r = run_gammac("run", tmp_path / "dust.gamma", "--scene", mesh, "--surfels", 300,
                   "--iterations", 1, "--size", 32, "--quiet", "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    it = json.loads((tmp_path / "out" / "summary.json").read_text())["iterations"][0]
    assert it["settled"] + it["escaped"] == it["emitted"] and it["interactions"] == it["settled"]
    cols = read_ply(tmp_path / "out" / "maps" / "iter_0001.ply")
    points = np.stack([cols["x"], cols["y"], cols["z"]], 1).astype(float)
    tris = load_obj(mesh)
    rng = np.random.default_rng(5)
    samples, normals, owner, total_area = cells(points, tris, 500_000, rng)
    cell_area = np.bincount(owner, minlength=len(points)) / len(samples) * total_area
    # the cell-averaged visibility: 32 points of each cell, 128 directions each
    chosen = np.concatenate([rng.permutation(np.flatnonzero(owner == k))[:32] for k in range(len(points))])
    visible = cosine_visibility(samples[chosen], normals[chosen], tris, 128, rng)
    visibility = np.bincount(owner[chosen], visible, len(points)) / np.bincount(owner[chosen], None, len(points))
    density = cols["dust"] / cell_area
    assert visibility.min() < 0.3 * visibility.max()      # the cavity really occludes
    normals_s = np.stack([cols["nx"], cols["ny"], cols["nz"]], 1).astype(float)
    expected = splat(visibility * cell_area, points, normals_s, np.sqrt(total_area / 300)) / cell_area
    pearson = np.corrcoef(expected, density)[0, 1]
    assert pearson >= 0.99, pearson
