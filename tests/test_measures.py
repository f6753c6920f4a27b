"""Per-surfel accessibility, curvature and uv (SPEC §12), computed once at
setup by the runtime and read by rules, update rules and appearance blocks.

Analytic scenes: an open plane is fully accessible (exactly 1) and flat
(curvature 0); the floor of a narrow open box is much less accessible, less
the deeper the box; a sphere of radius r has curvature 1/r outside (its
normals out: convex) and -1/r with its normals turned in (concave); the
values are bit-identical at 1 and 2 threads; uv is the mesh's texture
coordinates at the surfel, (0, 0, 0) without them.
"""

import numpy as np
import pytest

import gamma
from meshes import icosphere

MEASURES = """
ton Air { carry a = 1 }
surface Stone { property open = 0, bend = 0, tu = 0, tv = 0, tz = 0, hits = 0 }
source sky = environment(sphere) emits Air count 2000
on settle(t: Air, s: Stone) { s.hits += accessibility }
update(s: Stone) {
    s.open = accessibility
    s.bend = curvature
    s.tu = uv.u
    s.tv = uv.y
    s.tz = uv.z
}
"""


def run(verts, faces, surfels=4000, threads=2, uvs=None, iterations=1):
    effect = gamma.compile(source=MEASURES, name="measures.gamma")
    return gamma.run(effect, vertices=np.asarray(verts, np.float32), faces=np.asarray(faces, np.int32),
                     uvs=uvs, iterations=iterations, surfels=surfels, threads=threads)


def quad(corners, inside):
    """Two triangles over 4 corners in order, wound so the normal faces `inside`."""
    a, b, c, d = (np.asarray(p, float) for p in corners)
    n = np.cross(b - a, c - a)
    tris = [(a, b, c), (a, c, d)]
    if np.dot(n, np.asarray(inside, float) - a) < 0:
        tris = [(a, c, b), (a, d, c)]
    return tris


def mesh_of(triangles):
    verts = np.array([p for tri in triangles for p in tri], np.float32)
    return verts, np.arange(len(verts), dtype=np.int32).reshape(-1, 3)


def plane(size=2.0):
    h = size / 2
    return mesh_of(quad([(-h, 0, -h), (-h, 0, h), (h, 0, h), (h, 0, -h)], (0, 1, 0)))


def open_box(depth, width=1.0):
    """Floor at y = 0 and four walls up to y = depth, no lid; normals face the inside."""
    w, h = width / 2, depth
    centre = (0, depth / 2, 0)
    tris = quad([(-w, 0, -w), (-w, 0, w), (w, 0, w), (w, 0, -w)], centre)
    for sx, sz in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        if sx:
            x = sx * w
            corners = [(x, 0, -w), (x, 0, w), (x, h, w), (x, h, -w)]
        else:
            z = sz * w
            corners = [(-w, 0, z), (w, 0, z), (w, h, z), (-w, h, z)]
        tris += quad(corners, centre)
    return mesh_of(tris)


def test_an_open_plane_is_fully_accessible_and_flat():
    result = run(*plane())
    assert np.all(result.properties["open"] == 1.0)
    assert np.all(np.abs(result.properties["bend"]) < 1e-4)
    # every settled gamma-ton added the accessibility (1) of its surfel: the sum is the count
    settled = result.summary["iterations"][0]["settled"]
    assert float(result.properties["hits"].sum()) == pytest.approx(settled, rel=1e-5)


def test_the_floor_of_a_deep_narrow_box_is_less_accessible_the_deeper_it_is():
    means = []
    for depth in (0.25, 0.5, 1.0, 2.0, 4.0):
        result = run(*open_box(depth), surfels=6000)
        p, n = result.surfel_positions, result.surfel_normals
        floor = (p[:, 1] < 1e-5) & (np.abs(p[:, 0]) < 0.2) & (np.abs(p[:, 2]) < 0.2)
        assert floor.sum() > 20 and np.all(n[floor, 1] > 0.99)
        means.append(float(result.properties["open"][floor].mean()))
    assert all(a > b for a, b in zip(means, means[1:])), means
    # a shallow tray's floor sees most of the sky; the floor of the 4-deep shaft little of it
    # (SPEC §12: rays farther than half the diagonal count as open, a sin^2 of about 0.1 here)
    assert means[0] > 0.75 and means[-1] < 0.2, means


@pytest.mark.parametrize("inward", [False, True])
def test_curvature_of_a_sphere_is_one_over_its_radius(inward):
    radius = 2.0
    verts, faces = icosphere(5, radius=radius)
    if inward:
        faces = faces[:, ::-1]          # normals turned in: seen from them the sphere is concave
    result = run(verts, faces, surfels=20000)
    bend = result.properties["bend"]
    want = -1 / radius if inward else 1 / radius
    assert np.median(bend) == pytest.approx(want, rel=0.05)
    assert np.mean(np.abs(bend - want) < 0.1 / radius) > 0.9
    if not inward:
        # nothing can block a ray leaving a convex closed surface outward
        assert np.all(result.properties["open"] == 1.0)


def test_measures_are_bit_identical_at_one_and_two_threads():
    verts, faces = open_box(1.5)
    a = run(verts, faces, threads=1)
    b = run(verts, faces, threads=2)
    for name in ("open", "bend"):
        assert np.array_equal(a.properties[name], b.properties[name])
    assert 0 < a.properties["open"].min() < a.properties["open"].max() <= 1


def test_uv_is_the_meshs_texture_coordinates_at_the_surfel():
    verts, faces = plane()
    uvs = np.stack([verts[:, 0] * 0.25 + 0.5, verts[:, 2] * 0.5 + 0.5], axis=1).astype(np.float32)
    result = run(verts, faces, uvs=uvs)
    p = result.surfel_positions
    assert np.allclose(result.properties["tu"], p[:, 0] * 0.25 + 0.5, atol=1e-5)
    assert np.allclose(result.properties["tv"], p[:, 2] * 0.5 + 0.5, atol=1e-5)
    assert np.all(result.properties["tz"] == 0)
    bare = run(verts, faces)                 # no texture coordinates: uv is (0, 0, 0)
    assert np.all(bare.properties["tu"] == 0) and np.all(bare.properties["tv"] == 0)


def test_appearance_reads_the_measures_smoothed_at_the_point():
    effect = gamma.compile(source=MEASURES + """
appearance(s: Stone) { color = rgb(accessibility, curvature, 0) }
""", name="look.gamma")
    verts, faces = icosphere(4, radius=2.0)
    result = gamma.run(effect, vertices=verts.astype(np.float32), faces=faces.astype(np.int32), iterations=1,
                       surfels=8000, threads=2)
    rgb = result.vertex_colours()
    assert np.all(rgb[:, 0] == 1.0)
    assert np.median(rgb[:, 1]) == pytest.approx(0.5, rel=0.05)


SIDES = """
ton Dust { carry a = 1 }
surface Floor { property shelter = 0, front = 0 }
source fallout = environment(hemisphere) emits Dust count 20000
on settle(t: Dust, s: Floor) { s.shelter += 1 - accessibility }
update(s: Floor) { s.front = accessibility }
"""


def test_a_gamma_ton_reads_the_accessibility_of_the_side_it_came_from(box_obj):
    """tests/golden/open_box.obj is wound outward (its floor's normal points down, out of
    the box): an update rule reads the normal's side (open below the floor: 1); the dust
    that falls into the box lands on the inner side, which the walls shelter."""
    effect = gamma.compile(source=SIDES, name="sides.gamma")
    result = gamma.run(effect, box_obj, iterations=1, surfels=1500, threads=2)
    n = result.surfel_normals
    floor = n[:, 1] < -0.99
    assert np.all(result.properties["front"][floor] == 1.0)
    shelter = result.properties["shelter"]
    assert shelter[floor].sum() > 0.05 * floor.sum()   # the inner floor is partly sheltered
    assert np.all(shelter >= 0)
