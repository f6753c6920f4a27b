"""Chart atlases: texture coordinates for meshes that have none.

- ``chart_atlas``: cuts a triangle mesh into charts of neighbouring
  triangles, flattens each and packs them into a square texture with a
  gutter of ``padding`` texels between charts (xatlas, through its Python
  binding).  Vertices are shared inside a chart, so shading is smooth and
  colour continuous everywhere but on the chart seams.
- ``chart_of_texels``: which chart each texel centre lies in (``texel_hits``:
  every texel centre inside every triangle, with barycentrics, for baking).
- ``dilate``: fills the gutter ring by ring, each texel from the texels of
  one chart only, so filtering at a chart's edge never sees another chart.
- ``seam_jumps`` and ``flat_fraction``: what a texture layout costs the
  picture (colour jumps across edges, faceted triangles), for the tests and
  benchmarks; ``sample_bilinear`` reads a texture as a viewer does.

Texture coordinates follow the OBJ/glTF-on-import convention of the rest of
the export: texel (i, j) of a ``size``² image (row 0 at the top) has its
centre at u = (j + 0.5)/size, v = 1 - (i + 0.5)/size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Largest chart, in triangles of the mesh's mean area.  xatlas grows charts
#: one triangle at a time and re-flattens and re-checks the whole chart each
#: time, so its time grows with the chart size: unlimited charts take
#: minutes on the bunny; this bound keeps charts large enough for few seams
#: (the figures: bench/RESULTS.md, "Figures behind choices in the code").
CHART_AREA = 250.0
#: Triangles per piece handed to xatlas on its own: xatlas scans every
#: triangle of a piece for each chart it starts (quadratic in the piece), and
#: runs the pieces on all cores.  A piece border is a chart border.
PIECE_TRIANGLES = 8000
#: Packing attempts before the charts are scaled to fit with a thinner gutter.
PACK_ATTEMPTS = 8
#: Largest texture xatlas packs at (each attempt's time grows with the
#: texture); larger ones get that packing scaled up, gutters with it (the
#: charts then sit on a coarser grid: a little less of the texture is used).
PACK_LIMIT = 2048


@dataclass
class Atlas:
    """A mesh's triangles re-indexed into per-chart vertices with texture coordinates."""

    source: np.ndarray           # int64 (k,): the input vertex each atlas vertex comes from
    uvs: np.ndarray              # float32 (k, 2) in [0, 1], v up (v = 1 is the top image row)
    faces: np.ndarray            # int64 (m, 3) into the atlas vertices, the input's triangle and corner order
    chart: np.ndarray            # int32 (m,) chart number per triangle
    normals: np.ndarray | None   # float32 (k, 3), the corner normals, when given


def chart_atlas(vertices, faces, size: int, corner_normals=None, padding: int = 2) -> Atlas:
    """A chart atlas of the mesh for a ``size``² texture with ``padding`` texels
    of gutter between charts (and at the texture's border).

    Triangles xatlas cannot chart (repeated or non-finite corners, zero area)
    each get a chart of their own, folded onto one point (no texels).  With
    ``corner_normals`` (m, 3, 3), a vertex is also split where its corners'
    normals differ, so per-vertex normals give back the corner normals."""
    import xatlas

    size, padding = int(size), max(0, int(padding))
    if size < 1:
        raise ValueError(f"atlas size must be positive, not {size}")
    verts = np.asarray(vertices, np.float32).reshape(-1, 3)
    tris = np.asarray(faces, np.int64).reshape(-1, 3)
    m = len(tris)
    if m and (tris.min() < 0 or tris.max() >= len(verts)):
        raise ValueError("triangle corner index out of range")
    normals = None if corner_normals is None else np.asarray(corner_normals, np.float32).reshape(m, 3, 3)

    # Corners that must stay apart: one xatlas vertex per (vertex, normal).
    if normals is None:
        point_of_corner = tris.reshape(-1)
        point_vertex = np.arange(len(verts), dtype=np.int64)
        point_normal = None
    else:
        bits = (normals.reshape(-1, 3) + np.float32(0)).view(np.int32).astype(np.int64)  # -0 == +0
        unique, inverse = _unique_rows(np.column_stack([tris.reshape(-1), bits]))
        point_of_corner = inverse
        point_vertex = unique[:, 0]
        point_normal = unique[:, 1:].astype(np.int32).view(np.float32)
    corner_points = point_of_corner.reshape(-1, 3)

    # xatlas's tolerances are absolute (FLT_EPSILON on areas and distances):
    # centred and scaled to triangles of mean area 1, every mesh looks alike,
    # and CHART_AREA counts triangles.
    pos = verts.astype(np.float64)
    corner = pos[tris]
    finite = np.isfinite(corner).all(axis=(1, 2))
    area = np.full(m, np.nan)
    area[finite] = 0.5 * np.linalg.norm(np.cross(corner[finite, 1] - corner[finite, 0],
                                                 corner[finite, 2] - corner[finite, 0]), axis=1)
    positive = finite & (area > 0)
    if positive.any():
        used = tris[positive].reshape(-1)
        centre = 0.5 * (pos[used].min(axis=0) + pos[used].max(axis=0))
        scale = 1.0 / np.sqrt(area[positive].mean())
    else:
        centre, scale = np.zeros(3), 1.0
    norm_pos = ((pos - centre) * scale).astype(np.float32)
    distinct = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    chartable = positive & distinct & (area * scale * scale > 1e-6)

    face_chart = np.full(m, -1, np.int64)
    corner_vertex = np.full((m, 3), -1, np.int64)     # atlas vertex per corner, before compaction
    vertex_point = np.zeros(0, np.int64)
    vertex_uv = np.zeros((0, 2), np.float32)
    ids = np.flatnonzero(chartable)
    if len(ids):
        pieces = _split(norm_pos[tris[ids]].mean(axis=1), ids, -(-len(ids) // PIECE_TRIANGLES))
        atlas = xatlas.Atlas()
        for piece in pieces:
            points, local = np.unique(corner_points[piece], return_inverse=True)
            piece_normals = None
            if point_normal is not None:
                piece_normals = np.nan_to_num(point_normal[points]).astype(np.float32)
            atlas.add_mesh(norm_pos[point_vertex[points]], local.reshape(-1, 3).astype(np.uint32),
                           piece_normals)
        chart_options = xatlas.ChartOptions()
        chart_options.max_chart_area = CHART_AREA
        chart_options.max_iterations = 1
        # The packing that matters is done below on the charts (``_pack``); this
        # one only has to be quick: charts at about a texel per unit, no gutter.
        pack_options = xatlas.PackOptions()
        pack_options.texels_per_unit = 1.0
        pack_options.padding = 0
        pack_options.bilinear = False
        pack_options.blockAlign = True
        atlas.generate(chart_options, pack_options)
        tpu = atlas.texels_per_unit
        scale_uv = np.array([atlas.width, atlas.height], np.float64) / tpu
        points_list, uv_list, offset = [], [], 0
        for i, piece in enumerate(pieces):
            xref, out_faces, uv = atlas.get_mesh(i)
            _, charts = atlas.get_mesh_vertex_assignment(i)
            points, _ = np.unique(corner_points[piece], return_inverse=True)
            out_faces = out_faces.astype(np.int64)
            charts = charts.view(np.int32).astype(np.int64)
            ok = (charts[out_faces] >= 0).all(axis=1)   # xatlas's own rejects stay -1
            face_chart[piece[ok]] = charts[out_faces[ok, 0]]
            corner_vertex[piece[ok]] = out_faces[ok] + offset
            points_list.append(points[xref.astype(np.int64)])
            uv_list.append(uv.astype(np.float64) * scale_uv)   # in mesh units (mean triangle area 1)
            offset += len(xref)
        vertex_point = np.concatenate(points_list)
        vertex_uv = np.concatenate(uv_list)

    charted = face_chart >= 0
    # Keep only the atlas vertices the charted triangles use, in xatlas's order.
    used, inverse = np.unique(corner_vertex[charted], return_inverse=True)
    corner_vertex[charted] = inverse.reshape(-1, 3)
    vertex_point, vertex_uv = vertex_point[used], vertex_uv[used]
    # Charts numbered 0.. in xatlas's order.
    chart_ids, chart_inverse = np.unique(face_chart[charted], return_inverse=True)
    face_chart[charted] = chart_inverse
    charts = len(chart_ids)

    texel_uv = _pack(vertex_uv, corner_vertex[charted], face_chart[charted], charts, size, padding)

    # Leftovers: a chart each, all corners on one point, near a neighbour's
    # texels when a corner's vertex is charted.
    left = np.flatnonzero(~charted)
    if len(left):
        spot_of_vertex = np.full(len(verts), -1, np.int64)
        spot_of_vertex[point_vertex[vertex_point][::-1]] = np.arange(len(vertex_point))[::-1]
        points = corner_points[left]
        spots = spot_of_vertex[point_vertex[points]]
        first = np.where(spots[:, 0] >= 0, spots[:, 0], np.where(spots[:, 1] >= 0, spots[:, 1], spots[:, 2]))
        corner_texel = min(padding, size - 1) + 0.5                # a gutter texel when there is one
        spot_uv = np.full((len(left), 2), corner_texel)
        spot_uv[first >= 0] = texel_uv[first[first >= 0]]
        unique, inverse = _unique_rows(np.column_stack([np.repeat(np.arange(len(left)), 3), points.reshape(-1)]))
        corner_vertex[left] = len(vertex_point) + inverse.reshape(-1, 3)
        vertex_point = np.concatenate([vertex_point, unique[:, 1]])
        texel_uv = np.concatenate([texel_uv, spot_uv[unique[:, 0]]])
        face_chart[left] = charts + np.arange(len(left))

    u = texel_uv[:, 0] / size
    v = 1.0 - texel_uv[:, 1] / size
    return Atlas(
        source=point_vertex[vertex_point].astype(np.int64),
        uvs=np.clip(np.column_stack([u, v]), 0, 1).astype(np.float32),
        faces=corner_vertex.astype(np.int64),
        chart=face_chart.astype(np.int32),
        normals=None if point_normal is None else point_normal[vertex_point].astype(np.float32),
    )


def _unique_rows(keys: np.ndarray):
    """The distinct rows of an integer array (sorted, first column first) and
    the row number of each input row; np.unique(axis=0) is ten times slower."""
    order = np.lexsort(keys.T[::-1])
    ordered = keys[order]
    starts = np.ones(len(keys), bool)
    starts[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    inverse = np.empty(len(keys), np.int64)
    inverse[order] = np.cumsum(starts) - 1
    return ordered[starts], inverse


def _split(centroids: np.ndarray, ids: np.ndarray, count: int) -> list[np.ndarray]:
    """``ids`` in ``count`` compact pieces of about equal size: halved across
    the longest side of their centroids' box, again and again."""
    if count <= 1:
        return [ids]
    extent = centroids.max(axis=0) - centroids.min(axis=0)
    order = np.argsort(centroids[:, int(np.argmax(extent))], kind="stable")
    low = count // 2
    cut = len(ids) * low // count
    a, b = order[:cut], order[cut:]
    return _split(centroids[a], ids[a], low) + _split(centroids[b], ids[b], count - low)


def _pack(uv: np.ndarray, faces: np.ndarray, chart: np.ndarray, charts: int, size: int, padding: int):
    """Chart texture coordinates in mesh units -> texel coordinates (x right, y
    down) in a ``size``² image: one xatlas packing of the charts as they are,
    at the largest scale that leaves ``padding`` texels between charts and
    around the image."""
    import xatlas

    if not len(faces):
        return np.zeros((len(uv), 2))
    # xatlas packs on a bitmap of the texture: its time grows with the texel
    # count.  Above PACK_LIMIT² the packing is done at PACK_LIMIT and scaled
    # up, gutters with it (wider than asked, never narrower).
    limit = min(size, PACK_LIMIT)
    grow = size / limit
    border = padding
    padding = -(-padding * limit // size)
    room = limit - 2 * padding
    if room < 1:
        room, border = limit, 0
    # First guess: the charts' padded boxes fill 75 % of the room.
    lo = np.full((charts, 2), np.inf)
    hi = np.full((charts, 2), -np.inf)
    corner_uv = uv[faces]                       # (f, 3, 2)
    np.minimum.at(lo, chart, corner_uv.min(axis=1))
    np.maximum.at(hi, chart, corner_uv.max(axis=1))
    box = hi - lo

    def boxes(t):
        return ((box[:, 0] * t + 2 * padding + 1) * (box[:, 1] * t + 2 * padding + 1)).sum()

    low_t, high_t = 0.0, 1.0
    while boxes(high_t) < 0.75 * room * room and high_t < 1e12:
        high_t *= 2
    for _ in range(50):
        mid = 0.5 * (low_t + high_t)
        low_t, high_t = (mid, high_t) if boxes(mid) < 0.75 * room * room else (low_t, mid)
    scale = max(low_t, 1e-12)

    uv32 = uv.astype(np.float32)
    faces32 = faces.astype(np.uint32)
    materials = chart.astype(np.uint32).reshape(-1, 1)
    best = None
    for attempt in range(PACK_ATTEMPTS):
        atlas = xatlas.Atlas()
        atlas.add_uv_mesh(uv32, faces32, materials)
        options = xatlas.PackOptions()
        options.padding = padding
        options.texels_per_unit = float(scale)
        options.bilinear = True
        atlas.generate(pack_options=options)
        extent = max(atlas.width, atlas.height)
        _, _, out = atlas.get_mesh(0)
        _, vertex_chart = atlas.get_mesh_vertex_assignment(0)
        texels = out.astype(np.float64) * np.array([atlas.width, atlas.height])
        if extent <= room:
            best = (texels, vertex_chart)
            if extent >= 0.9 * room:
                break
            scale *= 0.99 * room / max(extent, 1)        # room to spare: grow once more
        elif best is not None:
            break
        else:
            scale *= 0.99 * room / extent
    if best is None:
        # Too many charts for the room even at a texel each: shrink the last
        # packing to fit (the gutters get thinner than asked).
        texels = texels * (room / extent)
        best = (texels, vertex_chart)
    texels, vertex_chart = best
    texels = _place_loose_vertices(uv, texels, vertex_chart.view(np.int32), faces, chart)
    return texels * grow + border


def _place_loose_vertices(uv, texels, vertex_chart, faces, chart):
    """Vertices that only zero-area triangles use are not moved by the packer:
    move them with their chart (the affine map its other vertices took)."""
    loose = np.zeros(len(uv), bool)
    loose[faces.reshape(-1)] = True
    loose &= vertex_chart < 0
    if not loose.any():
        return texels
    vertex_of_chart = np.full(len(uv), -1, np.int64)
    vertex_of_chart[faces.reshape(-1)] = np.repeat(chart, 3)
    texels = texels.copy()
    placed = vertex_chart >= 0
    for c in np.unique(vertex_of_chart[loose]):
        member = vertex_of_chart == c
        known = member & placed
        todo = member & loose
        src = np.column_stack([uv[known], np.ones(known.sum())])
        if len(src) >= 3 and np.linalg.matrix_rank(src) == 3:
            fit, *_ = np.linalg.lstsq(src, texels[known], rcond=None)
            texels[todo] = np.column_stack([uv[todo], np.ones(todo.sum())]) @ fit
        elif known.any():
            texels[todo] = texels[known].mean(axis=0)
        else:
            texels[todo] = 0.0
    return texels


def chart_of_texels(atlas: Atlas, size: int) -> np.ndarray:
    """int32 (size, size): the chart whose triangles hold each texel centre
    (the lowest chart where several do), -1 for gutter and empty texels."""
    texels, tris, _ = texel_hits(atlas.uvs[atlas.faces], size)
    chart = atlas.chart[tris]
    out = np.full(size * size, -1, np.int32)
    out[texels] = chart
    clash = out[texels] != chart                 # several charts (a broken atlas): the lowest
    if clash.any():
        shared = np.isin(texels, texels[clash])
        low = np.full(size * size, np.iinfo(np.int32).max, np.int32)
        np.minimum.at(low, texels[shared], chart[shared])
        out[texels[shared]] = low[texels[shared]]
    return out.reshape(size, size)


def texel_hits(corner_uvs: np.ndarray, size: int, chunk: int = 1 << 22):
    """Every (texel, triangle) pair of a ``size``² image with the texel centre
    inside the triangle (edges included) of ``corner_uvs`` (m, 3, 2): flat
    texel indices (row * size + column), triangle numbers and barycentric
    coordinates (k, 3).  Vectorised over the triangles' bounding boxes, about
    ``chunk`` candidates at a time."""
    uvs = np.asarray(corner_uvs, np.float64).reshape(-1, 3, 2)
    x = uvs[:, :, 0] * size - 0.5
    y = (1 - uvs[:, :, 1]) * size - 0.5
    with np.errstate(invalid="ignore"):
        j0 = np.clip(np.ceil(np.nan_to_num(x.min(axis=1)) - 1e-9), 0, size - 1).astype(np.int64)
        j1 = np.clip(np.floor(np.nan_to_num(x.max(axis=1)) + 1e-9), -1, size - 1).astype(np.int64)
        i0 = np.clip(np.ceil(np.nan_to_num(y.min(axis=1)) - 1e-9), 0, size - 1).astype(np.int64)
        i1 = np.clip(np.floor(np.nan_to_num(y.max(axis=1)) + 1e-9), -1, size - 1).astype(np.int64)
    (xa, xb, xc), (ya, yb, yc) = x.T, y.T
    det = (yb - yc) * (xa - xc) + (xc - xb) * (ya - yc)
    width, height = np.maximum(j1 - j0 + 1, 0), np.maximum(i1 - i0 + 1, 0)
    count = np.where(np.abs(det) < 1e-18, 0, width * height)
    found_texels, found_tris, found_bary = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 3))]
    ends = np.cumsum(count)
    first = 0
    while first < len(count):
        start = ends[first] - count[first]
        last = max(int(np.searchsorted(ends, start + chunk, side="right")), first + 1)
        tris = np.arange(first, last)
        n = count[tris]
        t = np.repeat(tris, n)
        k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        jj = j0[t] + k % np.maximum(width[t], 1)
        ii = i0[t] + k // np.maximum(width[t], 1)
        l1 = ((yb[t] - yc[t]) * (jj - xc[t]) + (xc[t] - xb[t]) * (ii - yc[t])) / det[t]
        l2 = ((yc[t] - ya[t]) * (jj - xc[t]) + (xa[t] - xc[t]) * (ii - yc[t])) / det[t]
        inside = (l1 >= -1e-9) & (l2 >= -1e-9) & (1 - l1 - l2 >= -1e-9)
        found_texels.append((ii * size + jj)[inside])
        found_tris.append(t[inside])
        found_bary.append(np.column_stack([l1, l2, 1 - l1 - l2])[inside])
        first = last
    return np.concatenate(found_texels), np.concatenate(found_tris), np.concatenate(found_bary)


def dilate(image: np.ndarray, chart_of_texel: np.ndarray, passes: int = 8, threads: int = 0) -> np.ndarray:
    """``image`` with its empty texels (chart -1) filled ``passes`` rings deep.

    A texel of a ring takes the mean of its filled 8-neighbours of one chart:
    the chart most of them belong to, the lowest-numbered on a tie; it then
    belongs to that chart for the next ring.  Colours of two charts are never
    mixed, so bilinear filtering and mip-maps at a chart's edge see only that
    chart's colours.  The runtime's loop (``dilate_charts``, gamma/uv_raster.h)
    on ``threads`` threads (0: all); ``image`` itself is left as it is."""
    from ..running.common import runtime_module

    out = np.array(image, np.float32)
    h, w = out.shape[:2]
    runtime_module().dilate_charts(out.reshape(h, w, -1), np.asarray(chart_of_texel, np.int32).reshape(h, w),
                                   passes, threads)
    return out


def sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``image`` (H, W, C) at texture coordinates ``uv`` (n, 2), bilinear,
    clamped at the border."""
    h, w = image.shape[:2]
    x = np.asarray(uv[:, 0], np.float64) * w - 0.5
    y = (1 - np.asarray(uv[:, 1], np.float64)) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    xs0, xs1 = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
    ys0, ys1 = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    img = image.reshape(h, w, -1).astype(np.float64)
    top = img[ys0, xs0] * (1 - fx) + img[ys0, xs1] * fx
    bottom = img[ys1, xs0] * (1 - fx) + img[ys1, xs1] * fx
    return top * (1 - fy) + bottom * fy


def seam_jumps(atlas: Atlas, image: np.ndarray, size: int, threshold: float = 10 / 255,
               positions: np.ndarray | None = None) -> float:
    """The fraction of interior edges (edges of exactly two triangles) where
    the colour sampled bilinearly from ``image`` at the edge's midpoint
    differs between the two triangles' texture coordinates by more than
    ``threshold`` (largest over the channels).  Edges are matched by
    ``positions`` (input vertices, (n, 3)) when given, else by input vertex."""
    image = np.asarray(image)
    if image.shape[0] != size or image.shape[1] != size:
        raise ValueError(f"image is {image.shape[:2]}, not {size}²")
    vertex = atlas.source
    if positions is not None:
        bits = (np.asarray(positions, np.float32).reshape(-1, 3) + np.float32(0)).view(np.int32)
        vertex = _unique_rows(bits.astype(np.int64))[1][atlas.source]
    tri = vertex[atlas.faces]                                      # (m, 3) welded corners
    a, b = tri.T.reshape(-1), tri[:, [1, 2, 0]].T.reshape(-1)      # edge k of every triangle, k = 0, 1, 2
    ca, cb = atlas.faces.T.reshape(-1), atlas.faces[:, [1, 2, 0]].T.reshape(-1)
    keep = a != b
    key = np.minimum(a, b)[keep] * (int(vertex.max()) + 1) + np.maximum(a, b)[keep]
    ca, cb = ca[keep], cb[keep]
    _, edge, counts = np.unique(key, return_inverse=True, return_counts=True)
    sides = np.flatnonzero(counts[edge] == 2)
    sides = sides[np.argsort(edge[sides], kind="stable")]         # the two sides of an edge in a row
    first, second = sides[0::2], sides[1::2]
    if not len(first):
        return 0.0
    uv = atlas.uvs.astype(np.float64)
    diff = np.abs(sample_bilinear(image, 0.5 * (uv[ca[first]] + uv[cb[first]]))
                  - sample_bilinear(image, 0.5 * (uv[ca[second]] + uv[cb[second]])))
    return float((diff.max(axis=1) > threshold).mean())


def flat_fraction(faces: np.ndarray, normals: np.ndarray, tolerance: float = 1e-6) -> float:
    """The fraction of triangles whose three vertex normals are equal (within
    ``tolerance``): faceted, whatever the surface's curvature."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if not len(faces):
        return 0.0
    n = np.asarray(normals, np.float64)[faces]
    same = ((np.abs(n[:, 0] - n[:, 1]).max(axis=1) <= tolerance)
            & (np.abs(n[:, 1] - n[:, 2]).max(axis=1) <= tolerance))
    return float(same.mean())
