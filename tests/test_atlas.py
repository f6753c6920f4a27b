"""Chart atlases for meshes without texture coordinates (gamma/driver/outputs/atlas.py):
on the Stanford bunny the atlas shares vertices inside charts (few extra
vertices, smooth normals), its charts never share a texel and keep a gutter,
the same mesh gives the same atlas in any process, a colour continuous on
the surface stays continuous across the seams once baked and dilated, and
dilation never mixes two charts; odd meshes (degenerate, non-manifold, one
triangle, none) still get coordinates for every triangle."""

import hashlib
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from gamma.driver.outputs.atlas import (Atlas, chart_atlas, chart_of_texels, dilate, flat_fraction, seam_jumps,
                                texel_hits)

BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"
SIZE = 1024
PADDING = 2


def read_obj(path):
    """Positions and triangles of a plain OBJ (v and f lines; f may be v/vt/vn)."""
    verts, faces = [], []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                verts.append(line.split()[1:4])
            elif line.startswith("f "):
                corners = [int(c.split("/")[0]) for c in line.split()[1:]]
                faces += [[corners[0], corners[k], corners[k + 1]] for k in range(1, len(corners) - 1)]
    faces = np.array(faces, np.int64)
    return np.array(verts, np.float32), np.where(faces > 0, faces - 1, faces + len(verts))


def smooth_corner_normals(verts, faces):
    """Area-weighted vertex normals, one per distinct position, at each corner."""
    _, weld = np.unique(verts, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    p = verts.astype(np.float64)[faces]
    face = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normals = np.zeros((weld.max() + 1, 3))
    for k in range(3):
        np.add.at(normals, weld[faces[:, k]], face)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    return normals[weld[faces]].astype(np.float32)


def uv_areas(atlas):
    uv = atlas.uvs[atlas.faces].astype(np.float64)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def digest(atlas):
    h = hashlib.sha256()
    for a in (atlas.source, atlas.uvs, atlas.faces, atlas.chart, atlas.normals):
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def bunny():
    verts, faces = read_obj(BUNNY)
    normals = smooth_corner_normals(verts, faces)
    atlas = chart_atlas(verts, faces, SIZE, corner_normals=normals, padding=PADDING)
    return verts, faces, normals, atlas, None     # its time is bench/bench_export.py's


def test_bunny_atlas_shares_vertices_inside_large_charts(bunny):
    verts, faces, _, atlas, seconds = bunny
    assert atlas.source.dtype == np.int64 and atlas.faces.dtype == np.int64
    assert atlas.uvs.dtype == np.float32 and atlas.chart.dtype == np.int32
    assert atlas.faces.shape == faces.shape and atlas.uvs.shape == (len(atlas.source), 2)
    assert (atlas.source[atlas.faces] == faces).all()          # same triangles, same corner order
    positions = len(np.unique(verts[np.unique(faces)], axis=0))
    assert len(atlas.source) <= 1.5 * positions
    charts = atlas.chart.max() + 1
    assert 1 < charts <= len(faces) / 50                        # charts of many triangles
    vertex_chart = np.zeros(len(atlas.source), np.int64)
    vertex_chart[atlas.faces.reshape(-1)] = np.repeat(atlas.chart, 3)
    for k in range(3):                                          # a vertex lies in one chart
        assert (vertex_chart[atlas.faces[:, k]] == atlas.chart).all()
    assert np.isfinite(atlas.uvs).all() and atlas.uvs.min() >= 0 and atlas.uvs.max() <= 1
    area = uv_areas(atlas)
    assert (np.abs(area) * SIZE * SIZE > 1e-3).all()            # no triangle folded to a line
    signs = np.zeros((charts, 2), np.int64)                     # and no chart folded over itself
    np.add.at(signs, (atlas.chart, (area > 0).astype(int)), 1)
    assert (signs.min(axis=1) == 0).all()


def test_bunny_normals_are_the_corner_normals_and_smooth(bunny):
    _, faces, normals, atlas, _ = bunny
    assert atlas.normals is not None and atlas.normals.dtype == np.float32
    assert np.array_equal(atlas.normals[atlas.faces], normals)
    assert flat_fraction(atlas.faces, atlas.normals) <= 0.10
    # the measure itself: face normals at every corner are all flat
    assert flat_fraction(np.arange(3 * len(faces)).reshape(-1, 3), np.repeat(normals.mean(axis=1), 3, axis=0)) == 1.0


def test_bunny_charts_never_share_a_texel_and_keep_a_gutter(bunny):
    atlas = bunny[3]
    texels, tris, _ = texel_hits(atlas.uvs[atlas.faces], SIZE)
    pairs = np.unique(np.column_stack([texels, atlas.chart[tris]]), axis=0)
    assert len(np.unique(pairs[:, 0])) == len(pairs)            # one chart per texel centre
    chart = chart_of_texels(atlas, SIZE)
    assert chart.shape == (SIZE, SIZE) and chart.dtype == np.int32
    assert (chart >= 0).mean() > 0.2                            # the charts use the texture
    assert set(np.unique(chart)) - {-1} == set(np.unique(atlas.chart))
    # no texel of another chart within `padding` texels (8-neighbourhood rings)
    padded = np.pad(chart, PADDING, constant_values=-1)
    for dy in range(-PADDING, PADDING + 1):
        for dx in range(-PADDING, PADDING + 1):
            other = padded[PADDING + dy:PADDING + dy + SIZE, PADDING + dx:PADDING + dx + SIZE]
            assert not ((chart >= 0) & (other >= 0) & (other != chart)).any(), (dy, dx)


def bake_positions(atlas, verts, size):
    """The surface position as an RGB colour (the bunny's box mapped to [0, 1]),
    interpolated over each triangle into the texture: (size, size, 3)."""
    low, high = verts.min(axis=0), verts.max(axis=0)
    colour = (verts - low) / (high - low)
    texels, tris, bary = texel_hits(atlas.uvs[atlas.faces], size)
    image = np.zeros((size * size, 3), np.float32)
    image[texels] = np.einsum("kc,kcd->kd", bary, colour[atlas.source[atlas.faces[tris]]])
    return image.reshape(size, size, 3)


def test_a_continuous_colour_stays_continuous_across_the_seams(bunny):
    verts, _, _, atlas, _ = bunny
    image = bake_positions(atlas, verts, SIZE)
    raw = seam_jumps(atlas, image, SIZE, positions=verts)
    smooth = seam_jumps(atlas, dilate(image, chart_of_texels(atlas, SIZE)), SIZE, positions=verts)
    assert smooth <= 0.01, smooth
    assert raw > smooth                     # the measure sees the black gutter before dilation


def test_the_same_mesh_gives_the_same_atlas_in_any_process():
    verts, faces = read_obj(BUNNY)
    faces = faces[:20000]                   # three pieces: xatlas charts them on several threads
    first = digest(chart_atlas(verts, faces, 512))
    assert digest(chart_atlas(verts, faces, 512)) == first
    script = ("import sys; sys.path.insert(0, sys.argv[1]); import test_atlas as t; from gamma.driver.outputs.atlas import chart_atlas; "
              "v, f = t.read_obj(t.BUNNY); print(t.digest(chart_atlas(v, f[:20000], 512)))")
    r = subprocess.run([sys.executable, "-c", script, str(ROOT / "tests")], capture_output=True, text=True,
                       timeout=300, cwd=ROOT / "tests")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == first


def test_odd_meshes_get_coordinates_for_every_triangle():
    tri = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    cases = {
        "one triangle": (tri, [[0, 1, 2]]),
        "repeated corner": (tri, [[0, 1, 2], [0, 0, 1]]),
        "zero area": (tri + [[2, 0, 0]], [[0, 1, 2], [0, 1, 3]]),
        "only degenerate": (tri, [[0, 0, 1], [1, 1, 2]]),
        "nan corner": (tri + [[np.nan, 0, 0]], [[0, 1, 2], [0, 1, 3]]),
        "edge of four triangles": (tri + [[0, 0, 1], [0, 0, -1], [0, -1, 0.5]],
                                   [[0, 1, 2], [0, 1, 3], [0, 1, 4], [1, 0, 5]]),
        "the same triangle thrice": (tri, [[0, 1, 2], [0, 1, 2], [2, 1, 0]]),
        "tiny": (np.array(tri) * 1e-20, [[0, 1, 2]]),
        "far away": (np.array(tri) * 1e6 + 1e7, [[0, 1, 2]]),
        "nothing": (tri, np.zeros((0, 3))),
    }
    for name, (verts, faces) in cases.items():
        verts = np.array(verts, np.float32)
        faces = np.array(faces, np.int64).reshape(-1, 3)
        atlas = chart_atlas(verts, faces, 64)
        assert atlas.faces.shape == faces.shape, name
        assert (atlas.source[atlas.faces] == faces).all(), name
        assert np.isfinite(atlas.uvs).all() and (atlas.uvs >= 0).all() and (atlas.uvs <= 1).all(), name
        p = verts.astype(np.float64)[faces]
        area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        solid = np.isfinite(area) & (area > 0) & (faces[:, [0, 1, 2]] != faces[:, [1, 2, 0]]).all(axis=1)
        assert (np.abs(uv_areas(atlas))[solid] > 0).all(), name
        if len(faces):
            texels, tris, _ = texel_hits(atlas.uvs[atlas.faces], 64)
            pairs = np.unique(np.column_stack([texels, atlas.chart[tris]]), axis=0)
            assert len(np.unique(pairs[:, 0])) == len(pairs), name
    # one triangle fills most of its texture; a degenerate one is a chart of its own
    atlas = chart_atlas(np.array(tri, np.float32), np.array([[0, 1, 2], [0, 0, 1]]), 64)
    assert atlas.chart[0] != atlas.chart[1] and abs(uv_areas(atlas)[0]) > 0.3


def test_texel_rows_run_down_from_v_one():
    # a triangle in the top-left corner of the texture (v near 1) covers row 0, column 0
    atlas = Atlas(source=np.arange(3), uvs=np.array([[0, 1], [0.5, 1], [0, 0.5]], np.float32),
                  faces=np.array([[0, 1, 2]]), chart=np.array([4], np.int32), normals=None)
    chart = chart_of_texels(atlas, 8)
    assert chart[0, 0] == 4 and chart[0, 3] == 4 and chart[3, 0] == 4
    assert chart[7, 7] == -1 and chart[0, 4] == -1 and chart[4, 0] == -1
    # and a texel's centre at (j + 0.5) / size, 1 - (i + 0.5) / size
    texels, _, bary = texel_hits(atlas.uvs[atlas.faces], 8)
    i, j = np.divmod(texels, 8)
    centre = np.column_stack([(j + 0.5) / 8, 1 - (i + 0.5) / 8])
    assert np.allclose(bary @ atlas.uvs, centre)


def test_more_charts_than_the_texture_holds_still_fit():
    rng = np.random.default_rng(1)
    verts = rng.random((1500, 3)).astype(np.float32)            # 500 separate triangles
    atlas = chart_atlas(verts, np.arange(1500).reshape(-1, 3), 32)
    assert len(np.unique(atlas.chart)) == 500
    assert atlas.uvs.min() >= 0 and atlas.uvs.max() <= 1


def two_charts(gap):
    """A 16 x 32 image: chart 0 (red) on the left, chart 1 (blue) from column
    10 + gap, the gutter between; empty elsewhere."""
    chart = np.full((16, 32), -1, np.int32)
    chart[2:14, 0:10] = 0
    chart[2:14, 10 + gap:] = 1
    image = np.zeros((16, 32, 3), np.float32)
    image[chart == 0] = (1, 0, 0)
    image[chart == 1] = (0, 0, 1)
    return image, chart


def test_dilation_takes_each_texel_from_one_chart():
    red, blue = np.array([1, 0, 0], np.float32), np.array([0, 0, 1], np.float32)
    image, chart = two_charts(gap=4)
    out = dilate(image, chart)
    assert (out[chart >= 0] == image[chart >= 0]).all()          # charts untouched
    assert (out[2:14, 10:12] == red).all() and (out[2:14, 12:14] == blue).all()
    assert (out[0:2, 0:12] == red).all() and (out[14:16, 12:] == blue).all()
    # a gutter one texel wide touches both charts equally: the lower chart, unmixed
    image, chart = two_charts(gap=1)
    out = dilate(image, chart)
    assert (out[2:14, 10] == red).all()
    # next to chart A in a gap of 2, A's colour exactly
    image, chart = two_charts(gap=2)
    out = dilate(image, chart)
    assert (out[2:14, 10] == red).all() and (out[2:14, 11] == blue).all()


def test_dilation_never_mixes_charts_and_stops_after_its_rings():
    rng = np.random.default_rng(7)
    size = 96
    chart = np.full((size, size), -1, np.int32)
    for c in range(12):                                          # random boxes, later ones on top
        y, x = rng.integers(0, size - 12, 2)
        h, w = rng.integers(3, 12, 2)
        chart[y:y + h, x:x + w] = c
    colours = rng.random((12, 4)).astype(np.float32)
    image = np.where(chart[..., None] >= 0, colours[chart], 0).astype(np.float32)
    out = dilate(image, chart, passes=3)
    filled = out.reshape(-1, 4)[(chart < 0).reshape(-1) & (np.abs(out).sum(axis=2) > 0).reshape(-1)]
    assert len(filled)
    # every filled texel holds exactly one chart's colour (means of equal values)
    matches = (np.abs(filled[:, None, :] - colours[None]) < 1e-6).all(axis=2)
    assert matches.any(axis=1).all()
    # and only within 3 rings of a chart
    near = chart >= 0
    for _ in range(3):
        p = np.pad(near, 1)
        near = near | p[:-2, :-2] | p[:-2, 1:-1] | p[:-2, 2:] | p[1:-1, :-2] | p[1:-1, 2:] | p[2:, :-2] | p[2:, 1:-1] | p[2:, 2:]
    assert (out[~near] == 0).all() and (np.abs(out[near]).sum(axis=1) > 0).all()


def numpy_dilate(image, chart_of_texel, passes=8):
    """The dilation as numpy wrote it before the runtime did (the reference
    the runtime's dilate_charts must match bit for bit)."""
    out = np.array(image, np.float32)
    h, w = out.shape[:2]
    values = out.reshape(h * w, -1)
    label = np.array(chart_of_texel, np.int32).reshape(-1)
    filled = (label >= 0).reshape(h, w)
    steps = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))
    none = np.iinfo(np.int32).max
    for _ in range(passes):
        near = filled.copy()
        near[1:] |= filled[:-1]
        near[:-1] |= filled[1:]
        ring = near.copy()
        ring[:, 1:] |= near[:, :-1]
        ring[:, :-1] |= near[:, 1:]
        ring = np.flatnonzero(ring & ~filled)
        if not len(ring):
            break
        row, col = np.divmod(ring, w)
        edge = np.flatnonzero((row == 0) | (row == h - 1) | (col == 0) | (col == w - 1))
        sources, around = [], []
        for dy, dx in steps:
            source = ring + (dy * w + dx)
            if len(edge):
                r, c = row[edge] + dy, col[edge] + dx
                off = edge[(r < 0) | (r >= h) | (c < 0) | (c >= w)]
                source[off] = ring[off]
            sources.append(source)
            around.append(np.take(label, source))
        best = np.maximum.reduce(around)
        low = np.minimum.reduce([np.where(a >= 0, a, none) for a in around])
        mixed = np.flatnonzero(low != best)
        if len(mixed):
            sub = np.stack([a[mixed] for a in around], axis=1)
            votes = (sub[:, :, None] == sub[:, None, :]).sum(axis=2).astype(np.int64)
            score = np.where(sub >= 0, votes * (np.int64(1) << 32) - sub, np.iinfo(np.int64).min)
            best[mixed] = sub[np.arange(len(mixed)), np.argmax(score, axis=1)]
        into, source = [], []
        for src, chart in zip(sources, around):
            mine = np.flatnonzero(chart == best)
            into.append(mine)
            source.append(src[mine])
        into, source = np.concatenate(into), np.concatenate(source)
        count = np.bincount(into, minlength=len(ring))
        gathered = np.take(values, source, axis=0)
        mean = np.empty((len(ring), values.shape[1]), np.float32)
        for k in range(values.shape[1]):
            mean[:, k] = np.bincount(into, weights=gathered[:, k], minlength=len(ring)) / count
        values[ring] = mean
        label[ring] = best
        filled.reshape(-1)[ring] = True
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dilation_is_the_numpy_reference_bit_for_bit(seed):
    """The runtime's dilation gives the numpy reference's images exactly: ties
    between charts, the image's edges, 1 to 9 channels, 1 and 2 threads."""
    rng = np.random.default_rng(seed)
    h, w = rng.integers(20, 90, 2)
    chart = np.full((h, w), -1, np.int32)
    for c in range(rng.integers(5, 30)):
        y, x = rng.integers(-3, h - 2), rng.integers(-3, w - 2)
        ch, cw = rng.integers(1, 10, 2)
        chart[max(y, 0):y + ch, max(x, 0):x + cw] = c
    chart[rng.random((h, w)) < 0.05] = -1                            # holes inside charts
    for channels in (1, 3, 9):
        image = np.where(chart[..., None] >= 0, rng.random((h, w, channels)) * 10 - 3, 0).astype(np.float32)
        want = numpy_dilate(image, chart, passes=8)
        for threads in (1, 2):
            got = dilate(image, chart, threads=threads)
            assert got.dtype == np.float32 and np.array_equal(got, want), (channels, threads)
    assert np.array_equal(dilate(image[..., 0], chart, passes=2), numpy_dilate(image[..., 0], chart, passes=2))


def test_dilation_fills_the_gutters_of_a_4096_texture():
    size = 4096
    chart = np.full((size, size), -1, np.int32)
    step = 64                                                    # 4096 square charts, a gutter of 8
    idx = np.arange(size)
    inside = (idx % step) < step - 8
    cell = (idx // step)[:, None] * (size // step) + (idx // step)[None, :]
    chart[np.ix_(inside, inside)] = cell[np.ix_(inside, inside)]
    image = np.where(chart[..., None] >= 0, (chart[..., None] % 255 + 1) / 256, 0).astype(np.float32)
    image = np.repeat(image, 3, axis=2)
    out = dilate(image, chart)
    assert (out[chart < 0] > 0).all()                            # gutters of 8: 4 rings from each side


def test_seam_jumps_sees_a_discontinuous_texture(bunny):
    verts, _, _, atlas, _ = bunny
    # a different constant colour per chart jumps across every seam and nowhere else
    ids = np.arange(atlas.chart.max() + 1)
    colours = (np.stack([ids % 16, ids // 16 % 16, ids // 256 % 16], axis=1) / 15).astype(np.float32)
    chart = chart_of_texels(atlas, SIZE)
    image = dilate(np.where(chart[..., None] >= 0, colours[chart], 0).astype(np.float32), chart)
    jumps = seam_jumps(atlas, image, SIZE, positions=verts)
    vertex = np.unique(verts, axis=0, return_inverse=True)[1].reshape(-1)[atlas.source]
    ends = np.sort(np.stack([vertex[atlas.faces], vertex[atlas.faces[:, [1, 2, 0]]]], axis=2), axis=2)
    _, edge, counts = np.unique(ends.reshape(-1, 2), axis=0, return_inverse=True, return_counts=True)
    edge = edge.reshape(-1)
    interior = np.flatnonzero(counts[edge] == 2)
    pairs = interior[np.argsort(edge[interior], kind="stable")].reshape(-1, 2)
    side_chart = np.repeat(atlas.chart, 3)
    expected = (side_chart[pairs[:, 0]] != side_chart[pairs[:, 1]]).mean()
    assert expected > 0.02 and abs(jumps - expected) <= 0.002, (jumps, expected)
