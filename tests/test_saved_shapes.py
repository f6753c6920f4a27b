"""`gammac render DIR` and `gammac export DIR` of a run whose shape changes
(SPEC §13.12): the simulation is rebuilt on the deformed mesh the run saved
(meshes/iter_NNNN.ply) with the saved map's surfels, so the re-render is the
run's own picture and the export holds the eroded mesh, not the input."""

import shutil
import subprocess
import sys

import numpy as np
import pygltflib
import pytest
from PIL import Image

from conftest import ROOT, run_gammac
from gamma.driver.outputs.outputs import read_mesh_ply, read_ply

EROSION = ROOT / "examples" / "erosion.gamma"
VIEW = "-1,0.45,0.9"
PICTURE = ("--view", VIEW, "--size", 64, "--samples", 1, "--ao", 2)


@pytest.fixture(scope="module")
def arch(tmp_path_factory):
    path = tmp_path_factory.mktemp("arch") / "arch.obj"
    subprocess.run([sys.executable, ROOT / "examples" / "scenes" / "make_arch.py", path], check=True,
                   capture_output=True)
    return path


@pytest.fixture(scope="module")
def eroded(tmp_path_factory, arch):
    """3 iterations of erosion on the arch, 3,000 surfels, with the run's own export of the last."""
    out = tmp_path_factory.mktemp("eroded") / "out"
    r = run_gammac("run", EROSION, "--scene", arch, "--assign", "ground=Ground", "--assign", "arch=Sandstone",
                   "--surfels", 3000, "--tons", 20000, "--iterations", 3, *PICTURE, "--export",
                   "--bake-size", 64, "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def saved_vertices(folder, iteration):
    columns, faces = read_mesh_ply(folder / "meshes" / f"iter_{iteration:04d}.ply")
    return np.column_stack([columns[a] for a in "xyz"]).astype(np.float32), faces


def accessor(gltf, index, blob):
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc.type]
    dtype = {5126: np.float32, 5125: np.uint32, 5123: np.uint16}[acc.componentType]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    return np.frombuffer(blob, dtype, acc.count * width, start).reshape(acc.count, width)


def glb_objects(path):
    """name -> (positions, triangles as their corners' positions) of every node's mesh."""
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    objects = {}
    for node in gltf.nodes:
        assert node.matrix is None and node.translation is None     # positions are scene positions
        corners, positions = [], []
        for prim in gltf.meshes[node.mesh].primitives:
            p = accessor(gltf, prim.attributes.POSITION, blob)
            positions.append(p)
            corners.append(p[accessor(gltf, prim.indices, blob).reshape(-1, 3).astype(np.int64)])
        objects[node.name] = (np.concatenate(positions), np.concatenate(corners))
    return objects


def as_set(points):
    return {tuple(p) for p in np.asarray(points, np.float32).reshape(-1, 3).tolist()}


def test_the_run_changed_its_shape(eroded):
    import json

    summary = json.loads((eroded / "summary.json").read_text())
    assert all(it["shape"]["changed"] for it in summary["iterations"])
    assert summary["iterations"][0]["shape"]["retiled"]      # the first step re-tiles: new surfels


@pytest.mark.parametrize("iteration", [3, 1])
def test_render_of_a_shape_run_is_the_runs_own_picture(eroded, tmp_path, iteration):
    """The last iteration (its surfels carried along by the moving mesh) and the
    first (re-tiled, re-sampled): bit for bit the picture the run drew."""
    target = tmp_path / f"again_{iteration}.png"
    args = ("--iteration", iteration) if iteration != 3 else ()
    r = run_gammac("render", eroded, *args, *PICTURE, "-o", target)
    assert r.returncode == 0, r.stderr
    again = np.asarray(Image.open(target))
    original = np.asarray(Image.open(eroded / "renders" / f"iter_{iteration:04d}.png"))
    assert again.shape == original.shape
    assert np.array_equal(again, original)
    r = run_gammac("render", eroded, "--show", "stone", "--size", 48, "-o", tmp_path / "stone.png")
    assert r.returncode == 0, r.stderr


def test_export_of_a_shape_run_holds_the_eroded_mesh(eroded, arch):
    export = eroded / "export"
    during = {p.relative_to(export): p.read_bytes() for p in export.rglob("*") if p.is_file()}
    assert sorted(p.name for p in export.glob("*.glb")) == ["arch_0003.glb"]
    r = run_gammac("export", eroded, "--all", "--bake-size", 64)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in export.glob("*.glb")) == ["arch_0001.glb", "arch_0002.glb", "arch_0003.glb"]
    after = {p.relative_to(export): p.read_bytes() for p in export.rglob("*") if p.is_file()}
    assert {k: after[k] for k in during} == during      # the last iteration: the run's own export, byte for byte

    import gamma._runtime as rt

    source = rt.Mesh.load(str(arch))
    start = np.asarray(source.vertices(), np.float32)
    labels = np.asarray(source.triangle_labels()[0])
    names = source.part_names()
    arch_start = as_set(start[np.asarray(source.triangles())[labels == names.index("arch")]])
    for it in (1, 2, 3):
        objects = glb_objects(export / f"arch_{it:04d}.glb")
        assert list(objects) == ["arch", "ground"]          # one node per object of the scene
        vertices, faces = saved_vertices(eroded, it)
        saved_triangles = {tuple(sorted(map(tuple, t))) for t in vertices[faces].tolist()}
        exported = [{tuple(sorted(map(tuple, t))) for t in corners.tolist()} for _, corners in objects.values()]
        # every exported triangle is one of the saved mesh's, each once: the two objects split it
        assert exported[0] | exported[1] == saved_triangles and not exported[0] & exported[1]
        arch_positions, ground_positions = as_set(objects["arch"][0]), as_set(objects["ground"][0])
        assert arch_positions | ground_positions == as_set(vertices)
        assert not arch_positions & ground_positions
        # the eroded arch: re-tiled and moved, hardly a vertex where the input had one
        assert len(arch_positions & arch_start) < 0.05 * len(arch_positions)
        heights = np.array(sorted(arch_positions))[:, 1]
        assert 1.5 < heights.max() < 1.7                  # still the 1.6 m arch
    first, last = (as_set(glb_objects(export / f"arch_{it:04d}.glb")["arch"][0]) for it in (1, 3))
    assert first != last                                 # every iteration its own mesh


def test_saved_surfels_sit_on_the_runs_triangles(eroded):
    """The placement behind the rebuild: every surfel of a map on a triangle
    of the saved mesh holding it, with its normal and surface, and each
    triangle's surface that of the run (the arch and the ground are separate
    parts, each of one surface: exact)."""
    from gamma.driver.running.reload import place_surfels

    for it in (1, 3):
        vertices, faces = saved_vertices(eroded, it)
        m = read_ply(eroded / "maps" / f"iter_{it:04d}.ply")
        positions = np.column_stack([m[a] for a in "xyz"])
        normals = np.column_stack([m[a] for a in ("nx", "ny", "nz")])
        surfaces = m["surface"].astype(np.int32)
        triangle, triangle_surface = place_surfels(positions, normals, surfaces, vertices, faces.astype(np.int32))
        assert triangle is not None and np.array_equal(triangle_surface[triangle], surfaces)
        corners = vertices[faces[triangle]].astype(np.float64)
        unit = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        unit /= np.linalg.norm(unit, axis=1)[:, None]
        assert np.all(np.sum(unit * normals, axis=1) > 0.9999)
        # the top of the arch is Sandstone (0), the ground plate's far corner Ground (1)
        centroids = corners.mean(1)
        assert set(surfaces[centroids[:, 1] > 1.2]) == {0}
        assert set(triangle_surface[vertices[faces].mean(1)[:, 1] > 1.2]) == {0}
        assert set(triangle_surface[np.abs(vertices[faces].mean(1)[:, 0]) > 1.5]) == {1}


def test_a_shape_run_without_its_mesh_is_refused(eroded, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(eroded, copy)
    (copy / "meshes" / "iter_0002.ply").unlink()
    r = run_gammac("render", copy, "--iteration", 2, "--size", 32, "-o", tmp_path / "x.png")
    assert r.returncode == 1 and "no mesh of iteration 2" in r.stderr, r.stderr
    # iterations whose mesh is there still render
    r = run_gammac("render", copy, "--iteration", 3, "--size", 32, "-o", tmp_path / "y.png")
    assert r.returncode == 0, r.stderr
