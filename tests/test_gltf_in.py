"""Meshes in: glTF 2.0 scenes (node, mesh and material names in --assign,
transforms applied, texture coordinates kept per part) and PLY texture
coordinates."""

import numpy as np
import pytest
import trimesh
from PIL import Image

from conftest import run_gammac
from gamma.frontend.checker import load
from gamma.driver.running.scene import load_scene

EFFECT = """\
ton T { motion straight = 0.5 carry a = 1 }
surface Iron { property rust = 0 }
surface Cement { property rust = 0 }
source s = environment(sphere) emits T count 20000
on settle(t: T, s: *) { s.rust += 0.01 * t.a }
"""


@pytest.fixture(scope="module")
def glb(tmp_path_factory):
    """Two nodes: 'chain' (a box moved to x = 3, scaled 2, with UVs and a red
    base-colour texture, mesh 'ChainMesh', material 'Rusty') and 'steps' (a
    sphere without UVs)."""
    folder = tmp_path_factory.mktemp("gltf")
    box = trimesh.creation.box()
    uv = np.random.default_rng(1).random((len(box.vertices), 2))
    material = trimesh.visual.material.PBRMaterial(name="Rusty",
                                                   baseColorTexture=Image.new("RGB", (4, 4), (200, 40, 40)))
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    scene = trimesh.Scene()
    move = trimesh.transformations.translation_matrix([3, 0, 0]) @ np.diag([2.0, 2.0, 2.0, 1.0])
    scene.add_geometry(box, node_name="chain", geom_name="ChainMesh", transform=move)
    scene.add_geometry(trimesh.creation.icosphere(2), node_name="steps", geom_name="StepsMesh")
    path = folder / "scene.glb"
    scene.export(str(path))
    (folder / "effect.gamma").write_text(EFFECT)
    return path, uv, box


@pytest.mark.parametrize("pattern", ["chain", "ChainMesh", "Rusty", "ch*"])
def test_node_mesh_and_material_names_bind_surfaces(rt, glb, pattern):
    path, _, box = glb
    effect = load(str(path.parent / "effect.gamma"))
    scene = load_scene(rt, str(path), effect, [f"{pattern}=Iron", "Cement"])
    assert scene.triangles_per_surface == {"Iron": len(box.faces), "Cement": 320}
    assert sorted(scene.object_names) == ["chain", "steps"]


def test_transforms_are_applied(rt, glb):
    path, _, _ = glb
    effect = load(str(path.parent / "effect.gamma"))
    scene = load_scene(rt, str(path), effect, ["chain=Iron", "Cement"])
    lo, hi = (np.asarray(b) for b in scene.bounds)
    assert np.allclose(lo, [-1, -1, -1], atol=1e-5) and np.allclose(hi, [4, 1, 1], atol=1e-5)
    iron = scene.triangle_surface == effect.surfaces["Iron"].index
    verts = np.asarray(scene.mesh.vertices())[np.asarray(scene.mesh.triangles())[iron]]
    assert np.allclose(verts[..., 0].min(), 2) and np.allclose(verts[..., 0].max(), 4)


def test_parts_keep_their_uvs(rt, glb):
    path, uv, box = glb
    effect = load(str(path.parent / "effect.gamma"))
    scene = load_scene(rt, str(path), effect, ["chain=Iron", "Cement"])
    assert scene.mesh.has_uvs
    chain = scene.triangle_surface == effect.surfaces["Iron"].index
    got = np.asarray(scene.mesh.triangle_uvs())[chain]
    assert np.allclose(np.sort(got.reshape(-1, 2), axis=0), np.sort(uv[box.faces].reshape(-1, 2), axis=0), atol=1e-6)
    assert scene.triangle_has_uv[chain].all() and not scene.triangle_has_uv[~chain].any()


def test_the_warning_names_the_parts_without_uvs(glb, tmp_path):
    path, _, _ = glb
    r = run_gammac("run", path.parent / "effect.gamma", "--scene", path, "--assign", "chain=Iron",
                   "--assign", "Cement", "--surfels", 2000, "--iterations", 1, "--size", 32, "--quiet",
                   "--export", "--bake-size", 64, "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "1 part of" in r.stderr and "without texture coordinates (steps)" in r.stderr
    for part in ("chain", "steps"):
        assert (tmp_path / "out" / "export" / part / f"{part}_BaseColor_0001.png").is_file()
    assert len(list((tmp_path / "out" / "export").glob("*_0001.glb"))) == 1


def test_bad_gltf_is_a_one_line_error(tmp_path):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00garbage")
    (tmp_path / "effect.gamma").write_text(EFFECT)
    r = run_gammac("run", tmp_path / "effect.gamma", "--scene", bad, "--assign", "Iron", "--out", tmp_path / "o")
    assert r.returncode == 1 and "cannot read glTF" in r.stderr and "Traceback" not in r.stderr


def write_ply(path, names=("u", "v")):
    verts = [(0, 0, 0, 0.1, 0.2), (1, 0, 0, 0.9, 0.2), (1, 1, 0, 0.9, 0.8), (0, 1, 0, 0.1, 0.8)]
    lines = ["ply", "format ascii 1.0", "element vertex 4", "property float x", "property float y",
             "property float z", f"property float {names[0]}", f"property float {names[1]}",
             "element face 1", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(map(str, v)) for v in verts] + ["4 0 1 2 3"]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_ply_texture_coordinates_are_read(rt, tmp_path):
    mesh = rt.Mesh.load(str(write_ply(tmp_path / "quad.ply")))
    assert mesh.has_uvs and mesh.num_triangles == 2
    uvs = np.asarray(mesh.triangle_uvs())
    tris = np.asarray(mesh.triangles())
    expected = np.array([[0.1, 0.2], [0.9, 0.2], [0.9, 0.8], [0.1, 0.8]])[tris]
    assert np.allclose(uvs, expected, atol=1e-6)
    plain = tmp_path / "plain.ply"
    plain.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                     "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                     "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert not rt.Mesh.load(str(plain)).has_uvs


LOOK = EFFECT + """
appearance(s: Iron) { if s.rust > 1000 { color = rgb(0, 0, 1) } }
appearance(s: Cement) { color = mix(base_color(), rgb(0, 0, 1), 0.5) }
"""


@pytest.mark.parametrize("chain_surface", ["Iron", "Cement"])
def test_base_colour_textures_are_used(glb, tmp_path, chain_surface):
    """The chain's material (a red base-colour texture) is what `color` starts
    as and what base_color() reads; the steps have no material: neutral grey."""
    import gamma

    path, _, _ = glb
    (tmp_path / "look.gamma").write_text(LOOK)
    effect = gamma.compile(tmp_path / "look.gamma")
    result = gamma.run(effect, path, assign=[f"chain={chain_surface}", "Cement"], iterations=1,
                       surfels=2000, threads=2)
    baked = result.bake(32)
    chain = baked["chain"]["color"].reshape(-1, 3)
    chain = chain[chain.max(1) > 0]                     # texels the chain's triangles cover
    red = np.array([200, 40, 40]) / 255
    want = red if chain_surface == "Iron" else 0.5 * red + 0.5 * np.array([0, 0, 1])
    assert np.allclose(chain, want, atol=2e-3), chain.mean(0)
    steps = baked["steps"]["color"].reshape(-1, 3)
    steps = steps[steps.max(1) > 0]
    assert np.allclose(steps, 0.5 * 0.7 + 0.5 * np.array([0, 0, 1]), atol=2e-3), steps.mean(0)


def test_base_colour_factor_without_texture(tmp_path):
    import gamma

    ball = trimesh.creation.icosphere(2)
    ball.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(name="Green", baseColorFactor=[0.1, 0.8, 0.2, 1.0]))
    scene = trimesh.Scene()
    scene.add_geometry(ball, node_name="ball")
    scene.export(str(tmp_path / "ball.glb"))
    (tmp_path / "e.gamma").write_text(EFFECT + "appearance(s: Iron) { color = color * 1 }\n")
    result = gamma.run(gamma.compile(tmp_path / "e.gamma"), tmp_path / "ball.glb", assign=["Iron"],
                       iterations=1, surfels=1000, threads=2)
    colours = result.bake(16)["ball"]["color"].reshape(-1, 3)
    colours = colours[colours.max(1) > 0]
    assert np.allclose(colours, [0.1, 0.8, 0.2], atol=2e-3), colours.mean(0)
