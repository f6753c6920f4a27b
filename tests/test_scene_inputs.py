"""mask("file") and attribute("NAME") (SPEC §12a): surfels read a painted
image or a vertex attribute at setup, and rules steer the weathering by it.

Uniform rain on a 2 x 2 plane (x, z in [-1, 1], u = (x + 1) / 2): dirt
under a mask's white half against its black half, and under an attribute's
1 against its 0; the mask's values read at full precision; the checks with
positions; resume and threads."""

from __future__ import annotations

import json
import struct

import numpy as np
from PIL import Image

from conftest import run_gammac

from gamma.driver.outputs.outputs import read_ply
from gamma.driver.running.scene_inputs import load_mask, sample

RAIN = """
ton Dirt {{
    motion straight = 1.0
}}
surface Ground {{
    reflectance straight = 0.0
    property dirt = 0.0
}}
source rain = directional((0, -1, 0)) emits Dirt count 200000
on hit(t: Dirt, s: Ground) {{
    s.dirt += 0.01 * {steer}
}}
"""
N = 24      # grid cells per side


def grid(n=N):
    """Vertices (x, 0, z) of an n x n grid over [-1, 1]², its triangles (facing up) and u, v."""
    xs = np.linspace(-1.0, 1.0, n + 1)
    x, z = np.meshgrid(xs, xs, indexing="xy")
    vertices = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    uv = np.stack([(x.ravel() + 1) / 2, (1 - z.ravel()) / 2], axis=1)
    tris = []
    for j in range(n):
        for i in range(n):
            a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i, (j + 1) * (n + 1) + i + 1
            tris += [(a, c, b), (b, c, d)]
    return vertices, np.asarray(tris), uv


def write_obj(path, *, uvs=True, colours=None):
    vertices, tris, uv = grid()
    lines = []
    for k, v in enumerate(vertices):
        extra = "" if colours is None else " " + " ".join(f"{c:.6f}" for c in colours[k])
        lines.append(f"v {v[0]:.6f} {v[1]:.6f} {v[2]:.6f}{extra}")
    if uvs:
        lines += [f"vt {u:.6f} {w:.6f}" for u, w in uv]
        lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in tris]
    else:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in tris]
    path.write_text("\n".join(lines) + "\n")
    return vertices


def write_ply(path, values: dict):
    vertices, tris, uv = grid()
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}",
            "property float x", "property float y", "property float z", "property float u", "property float v"]
    head += [f"property float {name}" for name in values]
    head += [f"element face {len(tris)}", "property list uchar int vertex_indices", "end_header"]
    columns = [vertices[:, 0], vertices[:, 1], vertices[:, 2], uv[:, 0], uv[:, 1], *values.values()]
    body = np.column_stack(columns).astype("<f4").tobytes()
    faces = b"".join(struct.pack("<B3i", 3, *t) for t in tris)
    path.write_bytes(("\n".join(head) + "\n").encode() + body + faces)
    return vertices


def run(tmp_path, effect_text, scene, name="out", *extra):
    effect = tmp_path / "rain.gamma"
    effect.write_text(effect_text)
    out = tmp_path / name
    r = run_gammac("run", effect, "--scene", scene, "--surfels", "6000", "--iterations", "1", "--out", out,
                   "--quiet", "--size", "32", "--samples", "1", "--ao", "0", *extra)
    return r, out


def halves(out):
    m = read_ply(out / "maps" / "iter_0001.ply")
    x, dirt = m["x"], m["dirt"].astype(np.float64)
    return dirt[x > 0.1].mean(), dirt[x < -0.1].mean(), m


def half_mask(path, dtype=np.uint16):
    image = np.zeros((64, 64), dtype)
    image[:, 32:] = np.iinfo(dtype).max
    Image.fromarray(image).save(path)


def test_dirt_under_a_masks_white_half_is_20x_its_black_half(tmp_path):
    write_obj(tmp_path / "plane.obj")
    half_mask(tmp_path / "mask.png")
    r, out = run(tmp_path, RAIN.format(steer='mask("mask.png")'), tmp_path / "plane.obj")
    assert r.returncode == 0, r.stderr
    white, black, _ = halves(out)
    assert white > 0 and white >= 20 * black, (white, black)


def test_dirt_under_an_attributes_1_is_5x_its_0(tmp_path):
    vertices = write_ply(tmp_path / "plane.ply", {"wetness": (grid()[0][:, 0] > 0).astype(np.float32)})
    r, out = run(tmp_path, RAIN.format(steer='attribute("Wetness")'), tmp_path / "plane.ply")
    assert r.returncode == 0, r.stderr
    wet, dry, _ = halves(out)
    assert len(vertices) and wet > 0 and wet >= 5 * max(dry, 1e-12), (wet, dry)


def test_obj_vertex_colours_and_gltf_attributes_read_the_same_values(tmp_path):
    vertices, tris, uv = grid()
    ramp = ((vertices[:, 0] + 1) / 2).astype(np.float32)
    write_obj(tmp_path / "plane.obj", colours=np.stack([ramp, 1 - ramp, np.zeros_like(ramp)], axis=1))
    r, out = run(tmp_path, RAIN.format(steer='attribute("COLOR_0.r")'), tmp_path / "plane.obj", "obj")
    assert r.returncode == 0, r.stderr
    import trimesh

    mesh = trimesh.Trimesh(vertices, tris, process=False)
    mesh.vertex_attributes["_RAMP"] = ramp
    (tmp_path / "plane.glb").write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene({"plane": mesh}),
                                                                           include_normals=False))
    r2, out2 = run(tmp_path, RAIN.format(steer='attribute("ramp")'), tmp_path / "plane.glb", "gltf")
    assert r2.returncode == 0, r2.stderr
    # the ramp is linear in x, so interpolated at a surfel it is (x + 1) / 2, and dirt follows it
    for folder in (out, out2):
        m = read_ply(folder / "maps" / "iter_0001.ply")
        assert np.corrcoef(m["x"], m["dirt"])[0, 1] > 0.9


def test_masks_are_read_at_full_precision_whatever_the_format(tmp_path):
    values = np.linspace(0, 1, 16 * 16).reshape(16, 16)
    grey16 = np.round(values * 65535).astype(np.uint16)
    Image.fromarray(grey16).save(tmp_path / "grey16.png")
    import OpenEXR
    import png

    rgb16 = np.repeat(grey16[..., None], 3, axis=2)
    with open(tmp_path / "rgb16.png", "wb") as f:
        png.Writer(16, 16, greyscale=False, bitdepth=16).write(f, rgb16.reshape(16, -1))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"Y": values.astype(np.float32)}) as f:
        f.write(str(tmp_path / "grey.exr"))
    expected = (grey16 / 65535.0).astype(np.float32)
    assert np.array_equal(load_mask(tmp_path / "grey16.png"), expected)
    lum = load_mask(tmp_path / "rgb16.png")
    assert np.allclose(lum, expected, atol=1e-6)
    assert np.array_equal(load_mask(tmp_path / "grey.exr"), values.astype(np.float32))
    # sampled at a pixel's centre, the pixel's value exactly: 16 bits survive
    uv = np.array([[(3 + 0.5) / 16, 1 - (5 + 0.5) / 16]], np.float32)
    assert sample(expected, uv)[0] == expected[5, 3]


def test_the_checks_name_positions_parts_and_what_is_missing(tmp_path):
    write_obj(tmp_path / "bare.obj", uvs=False)
    half_mask(tmp_path / "mask.png")
    r, _ = run(tmp_path, RAIN.format(steer='mask("mask.png")'), tmp_path / "bare.obj")
    assert r.returncode == 1
    assert "rain.gamma:11:22: error: mask() reads texture coordinates, and part 'bare' (surface Ground) has none" \
        in r.stderr, r.stderr
    r, _ = run(tmp_path, RAIN.format(steer='mask("nowhere.png")'), tmp_path / "bare.obj")
    assert r.returncode == 1 and "rain.gamma:11:27: error: cannot find mask 'nowhere.png' next to rain.gamma" \
        in r.stderr, r.stderr
    write_ply(tmp_path / "plane.ply", {"wetness": np.zeros((N + 1) ** 2, np.float32)})
    r, out = run(tmp_path, RAIN.format(steer='attribute("salt")'), tmp_path / "plane.ply")
    assert r.returncode == 1 and not out.exists()
    assert "rain.gamma:11:22: error: no part of the scene has a vertex attribute 'salt' (they have: wetness)" \
        in r.stderr, r.stderr
    r, _ = run(tmp_path, RAIN.format(steer="mask(0.5)"), tmp_path / "plane.ply")
    assert r.returncode == 1 and 'mask() takes a file name in quotes: mask("moss-mask.png")' in r.stderr
    # a part without the attribute reads 0 there, with a warning naming it
    write_obj(tmp_path / "other.obj")
    scene = tmp_path / "two.json"
    scene.write_text(json.dumps({"meshes": [{"file": "plane.ply"},
                                            {"file": "other.obj", "translate": [3, 0, 0]}]}))
    r, out = run(tmp_path, RAIN.format(steer='attribute("wetness") + 1'), scene)
    assert r.returncode == 0, r.stderr
    assert "warning: attribute(\"wetness\"): part 'other' (surface Ground) has no vertex attribute " \
           "'wetness': it reads 0 there" in r.stderr, r.stderr


def test_resumed_and_threaded_runs_with_a_mask_are_bit_identical(tmp_path):
    write_obj(tmp_path / "plane.obj")
    image = (np.random.default_rng(3).random((32, 32)) * 255).astype(np.uint8)
    Image.fromarray(image).save(tmp_path / "mask.png")
    text = RAIN.format(steer='mask("mask.png")')
    runs = {}
    for name, extra in (("one", ["--threads", "1", "--iterations", "3"]),
                        ("two", ["--threads", "2", "--iterations", "3"]),
                        ("resumed", ["--iterations", "2"])):
        r, runs[name] = run(tmp_path, text, tmp_path / "plane.obj", name, *extra)
        assert r.returncode == 0, r.stderr
    r, _ = run(tmp_path, text, tmp_path / "plane.obj", "resumed", "--iterations", "3", "--resume")
    assert r.returncode == 0, r.stderr
    maps = {k: (v / "maps" / "iter_0003.ply").read_bytes() for k, v in runs.items()}
    assert maps["one"] == maps["two"] == maps["resumed"]


def test_a_mask_in_an_appearance_block_is_sampled_at_the_point(tmp_path):
    write_obj(tmp_path / "plane.obj")
    half_mask(tmp_path / "mask.png", np.uint8)
    text = RAIN.format(steer="0") + """
appearance(s: Ground) {
    color = mix(rgb(0.9, 0.9, 0.9), rgb(0.1, 0.1, 0.1), mask("mask.png"))
}
"""
    r, out = run(tmp_path, text, tmp_path / "plane.obj", "out", "--view", "0,1,0.001", "--size", "64")
    assert r.returncode == 0, r.stderr
    picture = np.asarray(Image.open(out / "renders" / "iter_0001.png").convert("L"), np.float64)
    # seen from above, +x is to the right: the white half of the mask (u > 0.5) renders dark
    left, right = picture[24:40, 8:24].mean(), picture[24:40, 40:56].mean()
    assert left > right + 60, (left, right)


def _atlas_scene(tmp_path):
    """The bare plane as the run assembles it, with an effect that reads mask.png."""
    from gamma.driver.running.runner import runtime_module
    from gamma.driver.running.scene import load_scene
    from gamma.frontend.checker import check
    from gamma.frontend.parser import parse

    effect_path = tmp_path / "rain.gamma"
    effect_path.write_text(RAIN.format(steer='mask("mask.png")'))
    missing = []
    effect = check(parse(effect_path.read_text(), str(effect_path)), missing_masks=missing)
    assert missing == [str((tmp_path / "mask.png").resolve())]
    return effect, load_scene(runtime_module(), str(tmp_path / "bare.obj"), effect, [])


def test_a_mask_painted_in_the_atlas_of_a_mesh_without_uvs_steers_where_it_was_painted(tmp_path):
    """A mesh without UVs: the mask the watch makes is laid out in the scene's
    chart atlas; painted white wherever its texels lie at x > 0 (as the
    page's brush paints, by the texels' scene points), dirt falls 20x more
    there than at x < 0, and the painted file keeps its atlas record."""
    from gamma.driver.running import mask_atlas

    write_obj(tmp_path / "bare.obj", uvs=False)
    effect, scene = _atlas_scene(tmp_path)
    assert not scene.mesh.has_uvs
    mask_atlas.create(tmp_path / "mask.png", scene.mesh.vertices(), scene.mesh.triangles(), scene.triangle_has_uv,
                      size=128)
    assert mask_atlas.layout(tmp_path / "mask.png")["size"] == 128
    # the run's scene now reads the mask's atlas: the same coordinates each time
    from gamma.driver.running.runner import runtime_module
    from gamma.driver.running.scene import load_scene

    scene = load_scene(runtime_module(), str(tmp_path / "bare.obj"), effect, [])
    again = load_scene(runtime_module(), str(tmp_path / "bare.obj"), effect, [])
    assert scene.mesh.has_uvs and not scene.triangle_has_uv.any()
    uvs = np.asarray(scene.mesh.triangle_uvs())
    assert np.array_equal(uvs, np.asarray(again.mesh.triangle_uvs()))
    assert 0.3 < np.ptp(uvs[..., 0]) <= 1 and 0.3 < np.ptp(uvs[..., 1]) <= 1
    points, per_texel = mask_atlas.texel_points(scene.mesh, scene.triangle_has_uv, 128)
    assert points.shape == (128, 128, 3) and np.isfinite(points[..., 0]).mean() > 0.3
    assert 2.0 / 128 < per_texel < 2.0 / 20        # a 2 x 2 plane over part of a 128² image
    painted = np.where(np.nan_to_num(points[..., 0], nan=-1) > 0, 255, 0).astype(np.uint8)
    from io import BytesIO

    body = BytesIO()
    Image.fromarray(painted).save(body, format="PNG")        # as a browser sends it: no text chunk
    (tmp_path / "mask.png").write_bytes(mask_atlas.keep_record(body.getvalue(), tmp_path / "mask.png"))
    assert mask_atlas.layout(tmp_path / "mask.png")["size"] == 128
    r, out = run(tmp_path, RAIN.format(steer='mask("mask.png")'), tmp_path / "bare.obj")
    assert r.returncode == 0, r.stderr
    white, black, _ = halves(out)
    assert white > 0 and white >= 20 * black, (white, black)


def test_an_atlas_mask_of_another_mesh_is_refused(tmp_path):
    write_obj(tmp_path / "bare.obj", uvs=False)
    effect, scene = _atlas_scene(tmp_path)
    from gamma.driver.running import mask_atlas

    vertices = np.asarray(scene.mesh.vertices()) * 2          # the mesh as it was before an edit
    mask_atlas.create(tmp_path / "mask.png", vertices, scene.mesh.triangles(), scene.triangle_has_uv, 64)
    r, out = run(tmp_path, RAIN.format(steer='mask("mask.png")'), tmp_path / "bare.obj")
    assert r.returncode == 1 and not out.exists()
    assert "mask 'mask.png' was painted on another mesh's atlas" in r.stderr, r.stderr
