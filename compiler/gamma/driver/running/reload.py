"""A saved iteration put back into a simulation: its rows from the map
(``load_iteration``), on the deformed mesh the run saved when its shape
changed (``shaped_simulation``).  Used by ``gammac render``/``export`` of a
saved run (``saved``) and by ``--export all`` at the end of a run
(``writers``); imports neither the run loop nor the writers.
"""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np

from ... import abi
from .common import RunError


def load_iteration(session, folder: str | Path, iteration: int) -> dict:
    """Put the saved rows of ``iteration`` into the simulation; returns the map's columns."""
    from ..outputs.outputs import read_ply

    path = Path(folder) / "maps" / f"iter_{iteration:04d}.ply"
    if not path.is_file():
        raise RunError(f"no map of iteration {iteration} in '{folder}'")
    columns = read_ply(path)
    if session.shapes:
        _shape_of(session, Path(folder), iteration, columns, path)
    sim = session.sim
    positions = np.asarray(sim.surfel_positions())
    saved = np.column_stack([columns[a] for a in "xyz"]) if "x" in columns else None
    if saved is None or saved.shape != positions.shape or not np.array_equal(saved, positions):
        raise RunError(f"the surfels of '{path}' are not those the scene gives now "
                       "(the mesh, the assignment or the gamma version changed)")
    rows = np.zeros((sim.num_surfels, sim.row_width), np.float32)
    for j, name in enumerate(abi.REFLECTANCE_SLOTS):
        rows[:, j] = columns[f"reflectance_{name}"]
    for surface in session.effect.surfaces.values():
        mine = session.surfel_surface == surface.index
        for name, slot in surface.properties.items():
            if name not in columns:
                raise RunError(f"'{path}' has no column '{name}' (the effect changed since the run)")
            rows[mine, slot] = columns[name][mine]
    if session.input_values is not None:        # mask() and attribute(): not in the maps
        from .scene_inputs import write

        write(sim, session.effect, session.input_values, rows)
    sim.set_rows(np.ascontiguousarray(rows))
    return columns


def _shape_of(session, folder: Path, iteration: int, columns: dict, map_path: Path) -> None:
    """Give ``session`` the geometry of ``iteration`` of a shape-changing run:
    the simulation set up from the scene (``reopen``'s) up to the first shape
    step that moved the geometry, afterwards one rebuilt on the saved mesh
    with the saved surfels (``shaped_simulation``)."""
    summary = getattr(session, "saved_summary", None)
    if summary is None:
        summary = session.saved_summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    records = summary.get("iterations") or []
    moved = any((r.get("shape") or {}).get("changed") for r in records[:iteration])
    if not hasattr(session, "scene_simulation"):
        session.scene_simulation = session.sim
    if not moved:
        sim = session.scene_simulation
    else:
        mesh_path = folder / "meshes" / f"iter_{iteration:04d}.ply"
        if not mesh_path.is_file():
            raise RunError(f"no mesh of iteration {iteration} in '{folder}' (meshes/iter_{iteration:04d}.ply): "
                           "the shape of this run changed, and its surfels are on that mesh")
        sim = shaped_simulation(session, mesh_path, columns, map_path)
    if sim is not session.sim:
        session.sim = sim
        session.refresh_surfels()


def shaped_simulation(session, mesh_path: Path, columns: dict, map_path: Path):
    """A simulation of ``session``'s effect on the deformed mesh of
    ``mesh_path`` whose surfels are those of the map ``columns`` (positions,
    normals and surfaces, bit for bit), for renders and exports.

    The runtime places surfels only by sampling, or by taking them from a
    setup snapshot of the same mesh, count and seed (``SetupSnapshot``,
    ``Simulation(mesh, config, snapshot=...)``): a simulation is set up on
    the saved mesh, its snapshot's surfels are replaced by the saved ones
    (every other section as the runtime wrote it), and a second simulation
    takes them from that snapshot; it builds its own scene index, splat
    kernel, measures and corner normals from them, as the run's shape step
    did.  Triangle surfaces are not in the mesh file: each triangle holding
    a surfel takes its surfels' surface (a surfel lies on its triangle, with
    that triangle's normal), every other one the surface of the nearest such
    triangle across shared edges (exact where a connected part of the mesh
    has one surface, as every object of a scene assigned whole; along a
    seam between two surfaces inside one part, a triangle holding no surfel
    may take the other side's)."""
    import tempfile

    from ..caches import setup_cache
    from ..outputs.outputs import read_mesh_ply
    from .config import build_config, load_textures, set_materials

    rt, effect, scene, opts = session.rt, session.effect, session.scene, session.opts
    try:
        vertex_columns, faces = read_mesh_ply(mesh_path)
        vertices = np.ascontiguousarray(np.column_stack([vertex_columns[a] for a in "xyz"]), np.float32)
    except (OSError, ValueError, KeyError, IndexError) as err:
        raise RunError(f"cannot read '{mesh_path}': {err}") from None
    faces = np.ascontiguousarray(faces, np.int32)
    mesh = rt.Mesh.from_arrays(vertices, faces)
    if mesh.num_triangles != len(faces) or not np.array_equal(np.asarray(mesh.triangles()), faces):
        raise RunError(f"'{mesh_path}' has triangles the runtime does not keep (degenerate): "
                       "not a mesh a run saved")
    try:
        positions = np.ascontiguousarray(np.column_stack([columns[a] for a in "xyz"]), np.float32)
        normals = np.ascontiguousarray(np.column_stack([columns[a] for a in ("nx", "ny", "nz")]), np.float32)
        surfaces = np.asarray(columns["surface"]).astype(np.int32)
    except KeyError as err:
        raise RunError(f"'{map_path}' has no column {err}") from None
    n = len(positions)
    if n == 0 or np.any(surfaces < 0) or np.any(surfaces >= len(effect.surfaces)):
        raise RunError(f"'{map_path}' holds surfaces the effect does not have (the effect changed since the run)")
    triangle, triangle_surface = place_surfels(positions, normals, surfaces, vertices, faces)
    if triangle is None:
        raise RunError(f"the surfels of '{map_path}' do not lie on the mesh of '{mesh_path}' "
                       "(the files are not of one run)")

    def config(binding):
        cfg = build_config(rt, effect, session.kernels, opts, scene.bounds, scene.down)
        cfg.surfels = n
        cfg.triangle_surface = binding
        return cfg

    try:
        # any surfels of this mesh, count and seed, for a snapshot to put the saved ones in
        donor_cfg = config(np.zeros(len(faces), np.int32))
        donor_cfg.measure_accessibility = donor_cfg.measure_curvature = donor_cfg.measure_uv = False
        data = np.asarray(rt.Simulation(mesh, donor_cfg).setup_snapshot(), np.uint8).tobytes()
        data = snapshot_with_surfels(data, positions, normals, triangle)
        name = rt.setup_cache_name(mesh, n, opts.seed)
        if not name:
            raise RunError("this runtime build has no setup snapshots; cannot place the saved surfels")
        with tempfile.TemporaryDirectory(prefix="gamma-shaped-") as scratch:
            (Path(scratch) / name).write_bytes(data + setup_cache.TRAILER.pack(zlib.crc32(data), setup_cache.MARK))
            snapshot = rt.SetupSnapshot.load_cached(scratch, mesh, n, opts.seed)
        if snapshot is None:
            raise RunError("the runtime refused the saved surfels' setup snapshot")
        sim = rt.Simulation(mesh, config(triangle_surface), None, snapshot)
    except (ValueError, TypeError, RuntimeError) as err:
        raise RunError(f"cannot set up the saved mesh '{mesh_path}': {err}") from None
    if (sim.from_snapshot != "surfels" or not np.array_equal(np.asarray(sim.surfel_positions()), positions)
            or not np.array_equal(np.asarray(sim.surfel_normals()), normals)
            or not np.array_equal(np.asarray(sim.surfel_surfaces()), surfaces)):
        raise RunError(f"cannot place the surfels of '{map_path}' on '{mesh_path}'")
    # the render settings the run's shape step carried over: a triangle is flat, and has
    # a material, when every triangle of its surface in the scene was and had that one
    flat = scene.triangle_flat
    if flat is not None and flat.any():
        flat_surface = np.ones(len(effect.surfaces), np.int32)
        flat_surface[np.asarray(scene.triangle_surface)[~np.asarray(flat, bool)]] = 0
        flat = flat_surface[triangle_surface]
    else:
        flat = None
    sim.set_shading(flat, 0.0 if opts.shading == "flat" else float(opts.crease))
    if scene.materials:
        material = np.full(len(effect.surfaces), -2, np.int64)
        for s, m in zip(np.asarray(scene.triangle_surface), np.asarray(scene.triangle_material)):
            material[s] = m if material[s] in (-2, m) else -1
        material[material == -2] = -1
        set_materials(sim, material[triangle_surface].astype(np.int32), scene.materials)
    if session.looks:
        if not hasattr(session, "textures"):
            session.textures = load_textures(effect)
        sim.set_textures(session.textures)
    return sim


#: A setup snapshot's header and section header (runtime/src/setup_snapshot.cpp):
#: magic, format, byte order, surfels, seed, surfaces, sections; tag, element size, count.
_SNAPSHOT_HEADER = struct.Struct("<8sIIQQiI")
_SNAPSHOT_SECTION = struct.Struct("<IIQ")
_SNAPSHOT_POSITION, _SNAPSHOT_NORMAL, _SNAPSHOT_TRIANGLE = 5, 6, 7


def snapshot_with_surfels(data: bytes, positions: np.ndarray, normals: np.ndarray, triangle: np.ndarray) -> bytes:
    """A setup snapshot's bytes with its surfels (position, normal, triangle)
    replaced by these (as many) and one surface more in its header: a
    simulation of the snapshot's mesh, count and seed then takes its surfels
    and nothing else (another binding), and builds the rest for them."""
    out = bytearray(data)
    magic, fmt, order, n, seed, nsurf, sections = _SNAPSHOT_HEADER.unpack_from(out, 0)
    if magic != b"GAMSETUP" or n != len(positions):
        raise RunError("the runtime's setup snapshot is not one this gammac reads")
    _SNAPSHOT_HEADER.pack_into(out, 0, magic, fmt, order, n, seed, nsurf + 1, sections)
    new = {_SNAPSHOT_POSITION: np.ascontiguousarray(positions, "<f4"),
           _SNAPSHOT_NORMAL: np.ascontiguousarray(normals, "<f4"),
           _SNAPSHOT_TRIANGLE: np.ascontiguousarray(triangle, "<i4")}
    at, done = _SNAPSHOT_HEADER.size, 0
    for _ in range(sections):
        tag, size, count = _SNAPSHOT_SECTION.unpack_from(out, at)
        at += _SNAPSHOT_SECTION.size
        if tag in new:
            values = new[tag].tobytes()
            if size != new[tag].itemsize or len(values) != size * count:
                raise RunError("the runtime's setup snapshot is not one this gammac reads")
            out[at:at + len(values)] = values
            done += 1
        at += size * count
        at += -at % 8
    if done != len(new) or at != len(out):
        raise RunError("the runtime's setup snapshot is not one this gammac reads")
    return bytes(out)


def place_surfels(positions: np.ndarray, normals: np.ndarray, surfaces: np.ndarray, vertices: np.ndarray,
                  faces: np.ndarray) -> tuple:
    """(the triangle of each surfel, the surface of each triangle), or
    (None, None) if some surfel lies on no triangle.  A surfel's triangle
    contains it (barycentric coordinates ≥ −1e-4, plane distance ≤ 1e-4 of
    the cell size) with the surfel's normal (the triangle's unit normal, as
    the runtime gives it; the nearest normal wins, then the triangle the
    point is deepest in); the surfaces as ``shaped_simulation`` says."""
    P = positions.astype(np.float64)
    a, b, c = (vertices[faces[:, k]].astype(np.float64) for k in range(3))
    m = len(faces)
    # a uniform grid of cells about a triangle wide; each triangle listed in the cells its box meets
    lo_t, hi_t = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    lo = np.minimum(lo_t.min(0), P.min(0))
    hi = np.maximum(hi_t.max(0), P.max(0))
    span = float(np.max(hi - lo)) or 1.0
    cell = max(float(np.median(np.max(hi_t - lo_t, axis=1))), span / 1024)
    pad = 1e-4 * cell
    while True:
        c0 = np.floor((lo_t - pad - lo) / cell).astype(np.int64)
        c1 = np.floor((hi_t + pad - lo) / cell).astype(np.int64)
        extent = c1 - c0 + 1
        per = np.prod(extent, axis=1)
        if per.sum() <= 20 * m + 1_000_000:
            break
        cell *= 2
    dims = np.floor((hi - lo) / cell).astype(np.int64) + 3

    def key(cx, cy, cz):
        return ((cx + 1) * dims[1] + (cy + 1)) * dims[2] + (cz + 1)

    owner = np.repeat(np.arange(m), per)
    local = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per)
    ex, ey = extent[owner, 0], extent[owner, 1]
    keys = key(c0[owner, 0] + local % ex, c0[owner, 1] + (local // ex) % ey, c0[owner, 2] + local // (ex * ey))
    order = np.argsort(keys, kind="stable")
    keys, owner = keys[order], owner[order]
    pc = np.floor((P - lo) / cell).astype(np.int64)
    pkey = key(pc[:, 0], pc[:, 1], pc[:, 2])
    first, last = np.searchsorted(keys, pkey, "left"), np.searchsorted(keys, pkey, "right")
    count = last - first
    surfel = np.repeat(np.arange(len(P)), count)
    tri = owner[np.repeat(first, count) + np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)]
    # the triangles' planes first (most candidates are off them), then barycentric
    # coordinates as the runtime's carry_surfels computes them, and the normals
    e1, e2 = b - a, c - a
    cross = np.cross(e1, e2)
    length = np.linalg.norm(cross, axis=1)
    unit = cross / np.where(length > 0, length, 1.0)[:, None]
    near = np.abs(((P[surfel] - a[tri]) * unit[tri]).sum(1)) <= pad
    surfel, tri = surfel[near], tri[near]
    e1, e2, d = e1[tri], e2[tri], P[surfel] - a[tri]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    dp1, dp2 = (d * e1).sum(1), (d * e2).sum(1)
    den = d11 * d22 - d12 * d12
    ok = (den > 0) & (length[tri] > 0)
    den = np.where(ok, den, 1.0)
    v, w = (d22 * dp1 - d12 * dp2) / den, (d11 * dp2 - d12 * dp1) / den
    depth = np.minimum(np.minimum(1.0 - v - w, v), w)
    fit = ok & (depth >= -1e-4)
    surfel, tri, depth = surfel[fit], tri[fit], depth[fit]
    facing = np.round((unit[tri] * normals.astype(np.float64)[surfel]).sum(1), 6)

    def choose(allowed):
        """The best allowed candidate per surfel (-1: none)."""
        rank = np.flatnonzero(allowed)
        rank = rank[np.lexsort((-depth[rank], -facing[rank], surfel[rank]))]   # by surfel, best first
        held, first = np.unique(surfel[rank], return_index=True)
        best = np.full(len(P), -1, np.int64)
        best[held] = tri[rank[first]]
        return best

    placed = choose(np.ones(len(tri), bool))
    if np.any(placed < 0):
        return None, None
    triangle_surface = _triangle_surfaces(faces, placed, surfaces, (a + b + c) / 3, P)
    wrong = triangle_surface[placed] != surfaces
    if wrong.any():     # a surfel on an edge between surfaces: the triangle on its own surface's side
        again = choose(triangle_surface[tri] == surfaces[surfel])
        placed = np.where(wrong, again, placed)
        if np.any(placed < 0):
            return None, None
    return placed.astype(np.int32), triangle_surface.astype(np.int32)


def _triangle_surfaces(faces: np.ndarray, placed: np.ndarray, surfaces: np.ndarray, centroids: np.ndarray,
                       positions: np.ndarray) -> np.ndarray:
    """The surface of each triangle: its surfels' (the most of them; ties: the
    lower surface), else that of the nearest triangle holding surfels across
    shared edges (ties: the lower triangle number), else (a part of the mesh
    without surfels) that of the surfel nearest to its centroid."""
    m = len(faces)
    label = np.full(m, -1, np.int64)
    nsurf = int(surfaces.max()) + 1
    votes = np.zeros((m, nsurf), np.int64)
    np.add.at(votes, (placed, surfaces), 1)
    held = votes.sum(1) > 0
    label[held] = np.argmax(votes[held], axis=1)
    # triangles across each edge (consecutive triangles of a non-manifold edge)
    edges = np.sort(np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], 1).reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(m), 3)
    order = np.lexsort((owner, edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    same = np.all(edges[1:] == edges[:-1], axis=1)
    one, two = owner[:-1][same], owner[1:][same]
    src, dst = np.r_[one, two], np.r_[two, one]
    while True:
        reach = (label[src] >= 0) & (label[dst] < 0)
        if not reach.any():
            break
        nearest = np.full(m, m, np.int64)
        np.minimum.at(nearest, dst[reach], src[reach])
        grow = nearest < m
        label[grow] = label[nearest[grow]]
    lonely = np.flatnonzero(label < 0)
    for part in np.array_split(lonely, max(1, len(lonely) // 256)) if len(lonely) else ():
        # a part of the mesh holding no surfel: the surface of the surfel nearest to each centroid
        far = ((centroids[part][:, None, :] - positions[None, :, :]) ** 2).sum(2)
        label[part] = surfaces[np.argmin(far, axis=1)]
    return label
