"""The Blender extension (blender/gamma_blender) in Blender itself: the zip
that `make blender-extension` builds is installed through
``bpy.ops.extensions.package_install_files`` into a throw-away user folder,
and ``bpy.ops.gamma.weather`` runs the real ``gammac`` of this venv.

Each test is one Blender child (tests/clients.py), except the cancel test,
which needs to send the child a Ctrl-C half-way through a run.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "blender"))

from clients import BLENDER_PYTHON, blender_script  # noqa: E402

import build_extension  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
GAMMAC = str(Path(sys.executable).parent / "gammac")
PATINA = str(ROOT / "examples" / "patina.gamma")

#: Installs the zip, points the add-on at this venv's gammac; helpers the tests share.
PRELUDE = '''
import hashlib
import numpy as np
installed = bpy.ops.extensions.package_install_files(filepath=args["zip"], repo="user_default",
                                                     enable_on_install=True)
assert installed == {"FINISHED"}, installed
ADDON = "bl_ext.user_default.gamma"
bpy.context.preferences.addons[ADDON].preferences.gammac_path = args["gammac"]


def suzanne(name="Suzanne"):
    bpy.ops.mesh.primitive_monkey_add()
    obj = bpy.context.active_object
    obj.name = name
    obj.modifiers.new("Subdivision", "SUBSURF").levels = 1
    return obj


def digest(obj):
    co = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    return hashlib.sha1(co.tobytes()).hexdigest() + f"/{obj.data.name}/{len(obj.modifiers)}"


def values(obj, name):
    layer = obj.data.attributes[name]
    out = np.empty(len(layer.data), np.float32)
    layer.data.foreach_get("value", out)
    return out


def fed_by_image(socket, seen=0):
    """The image an input socket is fed from, through any nodes between (None: none)."""
    for link in socket.links:
        node = link.from_node
        if node.type == "TEX_IMAGE" and node.image is not None:
            return node.image.name if node.image.packed_file is not None else "unpacked " + node.image.name
        if seen < 4:
            for upstream in node.inputs:
                found = fed_by_image(upstream, seen + 1)
                if found:
                    return found
    return None


def weather(**kw):
    try:
        return sorted(bpy.ops.gamma.weather(**kw)), ""
    except RuntimeError as e:           # an ERROR report, as a script sees it
        return ["ERROR"], str(e)
'''


@pytest.fixture(scope="module")
def extension(tmp_path_factory) -> str:
    return str(build_extension.build(tmp_path_factory.mktemp("dist")))


@pytest.fixture(autouse=True)
def blender_user_folder(tmp_path, monkeypatch):
    """Extensions install into a folder of the test's own, not the user's Blender,
    and the add-on's scratch and kept runs go into the test's folder too."""
    monkeypatch.setenv("BLENDER_USER_RESOURCES", str(tmp_path / "blender-user"))
    (tmp_path / "scratch").mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp_path / "scratch"))


def run(source: str, extension: str, **args) -> dict:
    return blender_script(PRELUDE + source, zip=extension, gammac=GAMMAC, **args)


def test_zip_installs_and_its_sidebar_runs_the_chosen_recipe(extension):
    assert Path(extension).name == f"gamma-blender-{build_extension.project_version()}.zip"
    out = run('''
import addon_utils
result["enabled"] = ADDON in bpy.context.preferences.addons
result["operators"] = [hasattr(bpy.ops.gamma, n) for n in ("weather", "restore", "refresh_recipes")]
result["panel"] = hasattr(bpy.types, "GAMMA_PT_panel")
settings = bpy.context.scene.gamma
settings.recipe = "rust.gamma"          # the sidebar fills a field per parameter with its default
result["params"] = {p.name: [p.default, round(p.value, 6)] for p in settings.params}

# the sidebar as drawn (a stand-in layout records it): a field per parameter, and a Run
# button that hands the operator the panel's settings, only the parameters changed
import types
from bl_ext.user_default.gamma import GAMMA_PT_panel

class Layout:
    def __init__(self, log): self.log = log
    def prop(self, data, name, text=None, **kw): self.log.append(["prop", name, text])
    def operator(self, idname, **kw):
        op = types.SimpleNamespace()
        self.log.append(["operator", idname, op])
        return op
    def label(self, text="", **kw): self.log.append(["label", text])
    def progress(self, **kw): self.log.append(["progress", kw.get("text")])
    def row(self, **kw): return self
    column = box = row

next(p for p in settings.params if p.name == "rate").value = 0.25
settings.iterations, settings.quality = 7, "DRAFT"
log = []
GAMMA_PT_panel.draw(types.SimpleNamespace(layout=Layout(log)), bpy.context)
result["fields"] = [text for kind, *rest in log if kind == "prop" for name, text in [rest] if name == "value"]
run = next(rest[1] for kind, *rest in log if kind == "operator" and rest[0] == "gamma.weather")
result["run"] = {k: v for k, v in vars(run).items()}
''', extension)
    assert out["enabled"] and all(out["operators"]) and out["panel"], out
    assert out["params"]["rate"] == ["0.04", 0.04], out["params"]
    assert "tons" in out["params"]
    assert out["fields"] == list(out["params"]), "a field per parameter"
    button = out["run"]
    assert (button["effect"], button["iterations"], button["surfels"], button["bake_size"]) == ("rust.gamma", 7, 30000, 512)
    assert button["params"] == "rate=0.25", "only what differs from the recipe's defaults is passed"


def test_weathering_suzanne_gives_attributes_a_texture_set_and_no_copies_on_a_rerun(extension, tmp_path):
    picture = tmp_path / "suzanne-patina.png"
    keep = os.environ.get("GAMMA_KEEP_PICTURES")      # where to keep the picture (the README's: 512², 32 samples)
    out = run('''
obj = suzanne()
own = bpy.data.materials.new("Own")               # a material linked to the object, not its mesh
obj.data.materials.append(None)
obj.material_slots[0].link = "OBJECT"
obj.material_slots[0].material = own
bpy.ops.mesh.primitive_plane_add(size=6, location=(0, 0, -1.2))
floor = bpy.context.active_object
floor.name = "Floor"
for o in bpy.data.objects:
    o.select_set(o.name == "Suzanne")
first = weather(effect=args["effect"], iterations=3, surfels=20000, bake_size=256)
obj = bpy.data.objects.get("Suzanne")
result["first"] = first
result["names"] = sorted(o.name for o in bpy.data.objects)
patina = values(obj, "patina")
result["patina"] = [float(patina.min()), float(patina.max()), float(patina.std())]
mat = obj.data.materials[0]
bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
result["fed"] = {name: fed_by_image(bsdf.inputs[name]) for name in ("Base Color", "Roughness", "Metallic", "Normal")}
result["modifiers_off"] = [m.show_viewport for m in obj.modifiers]
result["floor"] = digest(floor)
files = lambda: [i for i in bpy.data.images if i.type == "IMAGE"]      # not Cycles' "Render Result"
counts = lambda: [len(bpy.data.materials), len(files()), len(bpy.data.meshes)]
result["counts_first"] = counts()
second = weather(effect=args["effect"], iterations=3, surfels=20000, bake_size=256)
result["second"] = second
result["counts_second"] = counts()
result["materials"] = sorted(m.name for m in bpy.data.materials)
result["images"] = sorted(i.name for i in files())
result["patina_again"] = values(obj, "patina").tolist() == patina.tolist()
# the picture: the standard library's patina (its appearance turns the copper green), the floor hidden
result["recipe"] = weather(effect="patina", iterations=10, surfels=50000, bake_size=1024)
result["counts_recipe"] = counts()
floor.hide_render = True
obj.rotation_euler = (0, 0, 0.5)
result["render"] = render(args["png"], size=args["size"], samples=args["samples"], view=(0.4, 0.3, 1.0))["png"]
result["restored"] = sorted(bpy.ops.gamma.restore())
result["after_restore"] = [len(obj.data.vertices), obj.data.name, [m.show_viewport for m in obj.modifiers],
                           "patina" in obj.data.attributes, len(bpy.data.materials), len(files())]
result["own_material"] = [obj.material_slots[0].link, obj.material_slots[0].material.name]
''', extension, effect=PATINA, png=str(picture), size=512 if keep else 200, samples=32 if keep else 8)
    assert out["first"] == [["FINISHED"], ""], out["first"]
    assert out["names"] == ["Floor", "Suzanne"], "Suzanne keeps her name; nothing is added"
    low, high, spread = out["patina"]
    assert low >= 0 and high > low and spread > 0.01, f"patina must vary over Suzanne: {out['patina']}"
    for name, image in out["fed"].items():
        assert image and not image.startswith("unpacked"), f"{name} must be fed by a packed image: {out['fed']}"
    assert "BaseColor" in out["fed"]["Base Color"] and "Normal" in out["fed"]["Normal"]
    assert out["modifiers_off"] == [False], "the weathered mesh has the subdivision applied"
    assert out["second"] == [["FINISHED"], ""], out["second"]
    assert out["counts_second"] == out["counts_first"], "a second run replaces the first run's datablocks"
    assert not any("." in name for name in out["materials"] + out["images"]), (out["materials"], out["images"])
    assert "Own" in out["materials"]
    assert out["patina_again"], "the same run again gives the same attribute"
    assert out["recipe"] == [["FINISHED"], ""] and out["counts_recipe"] == out["counts_first"], out["recipe"]
    assert out["restored"] == ["FINISHED"]
    vertices, mesh_name, modifiers, has_patina, materials, images = out["after_restore"]
    assert (vertices, mesh_name, modifiers, has_patina) == (507, "Suzanne", [True], False)
    assert (materials, images) == (1, 0), "restoring removes what the runs made (the user's own stays)"
    assert out["own_material"] == ["OBJECT", "Own"], "the object's own material comes back as it was"
    # Cycles' picture: a weathered Suzanne, with verdigris (green over red) somewhere on her
    rgb = np.asarray(Image.open(out["render"]).convert("RGB"), dtype=np.float64)
    assert rgb.std() > 10, "the render is not blank"
    greenish = (rgb[..., 1] > rgb[..., 0] + 8).mean()
    assert greenish > 0.01, f"no verdigris in the render ({greenish:.4f} of the pixels)"
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        Image.open(out["render"]).save(Path(keep) / "blender-addon-suzanne.png")


def test_a_recipe_by_name_and_parameters(extension):
    out = run('''
obj = suzanne()
child = suzanne("Dé/fect bolt.001")          # a name no file may have, parented and moved
child.parent, child.location = obj, (3, 0, 0)
for o in bpy.data.objects:
    o.select_set(True)
result["run"] = weather(effect="rust", iterations=2, surfels=10000, bake_size=64, params="rate=0.5")
obj, child = bpy.data.objects["Suzanne"], bpy.data.objects["Dé/fect bolt.001"]
result["child"] = [list(child.matrix_world.translation), "rust" in child.data.attributes,
                   child.parent.name, len(child.data.materials)]
result["attributes"] = sorted(a.name for a in obj.data.attributes if not a.name.startswith((".", "_")))
result["rust"] = float(values(obj, "rust").max())
result["bad"] = weather(effect="no-such-recipe")
result["bad_param"] = weather(effect="rust", params="rate")
''', extension)
    assert out["run"] == [["FINISHED"], ""], out["run"]
    assert out["child"] == [[3.0, 0.0, 0.0], True, "Suzanne", 1], out["child"]
    assert "rust" in out["attributes"] and out["rust"] > 0, out
    assert out["bad"][0] == ["ERROR"] and "no effect file or recipe named 'no-such-recipe'" in out["bad"][1]
    assert out["bad_param"][0] == ["ERROR"] and "'rate' is not NAME=VALUE" in out["bad_param"][1]


def test_errors_are_reports_and_leave_the_objects_alone(extension, tmp_path):
    broken = tmp_path / "broken.gamma"
    broken.write_text("// a broken effect\nsurface Stone { property grime = 0.0 }\n"
                      "source rain = directional((0, -1, 0)) emits Drop count 1000\n")
    out = run('''
obj = suzanne()
before = digest(obj)
result["broken"] = weather(effect=args["broken"], iterations=2, surfels=5000, bake_size=64)
result["untouched"] = digest(bpy.data.objects["Suzanne"]) == before and not bpy.data.materials
mesh = bpy.data.meshes.new("Points")
mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [])
points = bpy.data.objects.new("Points", mesh)
bpy.context.scene.collection.objects.link(points)
for o in bpy.data.objects:
    o.select_set(o.name == "Points")
result["faceless"] = weather(effect=args["patina"], iterations=1)
for o in bpy.data.objects:
    o.select_set(False)
result["nothing"] = weather(effect=args["patina"], iterations=1)
bpy.data.objects["Suzanne"].select_set(True)
bpy.context.preferences.addons[ADDON].preferences.gammac_path = "/nowhere/gammac"
result["missing"] = weather(effect=args["patina"], iterations=1)
result["still_untouched"] = digest(bpy.data.objects["Suzanne"]) == before
''', extension, broken=str(broken), patina=PATINA)
    state, message = out["broken"]
    assert state == ["ERROR"] and "broken.gamma:3:" in message, out["broken"]
    assert "Drop" in message, "the error says what is wrong"
    assert "Traceback" not in message
    assert out["untouched"] and out["still_untouched"]
    assert out["faceless"][0] == ["ERROR"] and "'Points' has no faces" in out["faceless"][1]
    assert out["nothing"][0] == ["ERROR"] and "select one or more mesh objects" in out["nothing"][1]
    assert out["missing"][0] == ["ERROR"] and "gammac not found ('/nowhere/gammac')" in out["missing"][1]


def test_a_shape_change_replaces_the_mesh_or_becomes_a_shape_key(extension, tmp_path):
    effect = tmp_path / "wear.gamma"
    effect.write_text('''// wind-blown sand wears the windward side of the stone away
ton Sand {
    motion parabolic = 0.55, flow = 0.3
    bounce 0.25
    step 0.04
}
surface Stone {
    reflectance parabolic = 0.2, flow = 0.1
    property stone = 0.0
    shape stone = 0.02
}
source wind = directional((1, -0.25, 0.1)) emits Sand count 100000
on hit(t: Sand, s: Stone) {
    s.stone -= 0.5 * max(0.0, -(direction.x * normal.x + direction.y * normal.y + direction.z * normal.z))
}
''')
    out = run('''
def shape(obj):
    co = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)

bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4, radius=1)
ball = bpy.context.active_object
ball.name = "Ball"
original = shape(ball)
result["replace"] = weather(effect=args["effect"], iterations=2, surfels=20000, bake_size=64)
ball = bpy.data.objects["Ball"]
from mathutils.bvhtree import BVHTree
bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4, radius=1)
reference = bpy.context.active_object
tree = BVHTree.FromObject(reference, bpy.context.evaluated_depsgraph_get())
moved = [tree.find_nearest(v.co)[3] for v in ball.data.vertices]
result["replaced_moved"] = float(np.max(moved))
result["replaced_keys"] = ball.data.shape_keys is not None
bpy.data.objects.remove(reference)
for o in bpy.data.objects:
    o.select_set(o.name == "Ball")
result["keyed"] = weather(effect=args["effect"], iterations=2, surfels=20000, bake_size=64, shape_key=True)
keys = ball.data.shape_keys.key_blocks
result["keys"] = [k.name for k in keys]
basis = np.array([p.co[:] for p in keys[0].data])
worn = np.array([p.co[:] for p in keys[1].data])
result["basis_radius"] = [float(np.linalg.norm(basis, axis=1).min()), float(np.linalg.norm(basis, axis=1).max())]
result["key_moved"] = float(np.linalg.norm(worn - basis, axis=1).max())
''', extension, effect=str(effect))
    assert out["replace"] == [["FINISHED"], ""], out["replace"]
    assert out["replaced_moved"] > 0.005 and not out["replaced_keys"], "the worn shape replaced the mesh"
    assert out["keyed"] == [["FINISHED"], ""], out["keyed"]
    assert out["keys"] == ["Basis", "gamma wear"]
    low, high = out["basis_radius"]
    # the basis is the shape the user made (an icosphere of radius 1: its faces dip to 0.99 between corners)
    assert 0.98 < low and high < 1.0 + 1e-4, out["basis_radius"]
    assert out["key_moved"] > 0.005, "the shape key holds the wear"


CANCEL = '''
import json, sys
obj = suzanne()
before = digest(obj)
print("READY", flush=True)
outcome = weather(effect=args["patina"], iterations=200, surfels=20000, bake_size=64)
obj = bpy.data.objects["Suzanne"]
print("RESULT " + json.dumps({"outcome": outcome, "untouched": digest(obj) == before,
                              "materials": len(bpy.data.materials), "meshes": len(bpy.data.meshes),
                              "attributes": sorted(a.name for a in obj.data.attributes)}), flush=True)
'''


def test_a_run_cancelled_half_way_leaves_the_mesh_untouched(extension, tmp_path):
    """Ctrl-C in a ``blender --background`` script (the modal operator's Esc
    calls the same ``GammaJob.cancel``)."""
    script = tmp_path / "cancel.py"
    script.write_text("import bpy, json, sys\nargs = json.loads(sys.argv[1])\n"
                      "bpy.ops.wm.read_factory_settings(use_empty=True)\n" + PRELUDE + CANCEL)
    args = json.dumps({"zip": extension, "gammac": GAMMAC, "patina": PATINA})
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    child = subprocess.Popen([str(BLENDER_PYTHON), str(script), args], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, cwd=tmp_path,
                             env=dict(os.environ, TMPDIR=str(scratch), PYTHONUNBUFFERED="1"))
    lines, deadline = [], time.monotonic() + 300
    try:
        for line in child.stdout:
            lines.append(line)
            if "gamma: iteration 3/200" in line:
                child.send_signal(signal.SIGINT)
                break
            assert time.monotonic() < deadline, "".join(lines[-20:])
        rest, _ = child.communicate(timeout=120)
    finally:
        child.kill()
    lines += rest.splitlines(keepends=True)
    results = [json.loads(ln[len("RESULT "):]) for ln in lines if ln.startswith("RESULT ")]
    assert results, "".join(lines[-30:])
    result = results[0]
    assert result["outcome"] == [["CANCELLED"], ""], result
    assert result["untouched"], "a cancelled run leaves the mesh as it was"
    assert (result["materials"], result["meshes"]) == (0, 1) and "patina" not in result["attributes"]
    assert any("run cancelled" in ln for ln in lines), "the cancel is reported"
    assert not any(ln.startswith("Traceback") for ln in lines), "".join(lines)
    assert not list(scratch.glob("gamma-blender-*")), "the run's scratch folder is removed"


def test_the_modal_operator_shows_progress_and_esc_cancels(extension):
    """The interface's path: invoke, then the timer's events until it ends.
    Blender as a module has no window to run a modal handler, so the test
    calls the operator's own invoke/modal with a stand-in for the window
    manager, workspace and screen, and real scene data."""
    out = run('''
import types
from bl_ext.user_default.gamma import GAMMA_OT_weather

class WindowManager:
    def __init__(self): self.progress, self.handlers, self.timers = [], [], 0
    def event_timer_add(self, step, window=None): self.timers += 1; return "timer"
    def event_timer_remove(self, timer): self.timers -= 1
    def modal_handler_add(self, op): self.handlers.append(op)
    def progress_begin(self, low, high): pass
    def progress_update(self, value): self.progress.append(value)
    def progress_end(self): pass

class Workspace:
    def __init__(self): self.texts = []
    def status_text_set(self, text): self.texts.append(text)

class Context:
    def __init__(self):
        self.scene, self.window = bpy.context.scene, None
        self.window_manager, self.workspace = WindowManager(), Workspace()
        self.screen = types.SimpleNamespace(areas=[])
        self.selected_objects = [o for o in bpy.context.scene.objects if o.select_get()]

class Operator:
    """The operator's own methods over plain attributes (its properties)."""
    def __init__(self, **props):
        self.__dict__.update(effect="", iterations=10, surfels=100000, bake_size=1024, seed=1, tons=0,
                             params="", assign="", shape_key=False, continue_run=False)
        self.__dict__.update(props)
        self.reports = []
    def report(self, kind, message): self.reports.append([sorted(kind), message])
    def __getattr__(self, name):
        value = getattr(GAMMA_OT_weather, name)
        return types.MethodType(value, self) if callable(value) else value

def drive(op, ctx, escape_at=None):
    state = sorted(op.invoke(ctx, types.SimpleNamespace(type="NONE")))
    seen, passed = [], sorted(op.modal(ctx, types.SimpleNamespace(type="MOUSEMOVE")))
    while state == ["RUNNING_MODAL"]:
        time.sleep(0.1)
        kind = "ESC" if escape_at is not None and op._job.iteration >= escape_at else "TIMER"
        state = sorted(op.modal(ctx, types.SimpleNamespace(type=kind)))
        seen.append(round(bpy.context.scene.gamma.progress, 4))
    return state, seen, passed

import time
obj = suzanne()
before = digest(obj)
ctx = Context()
op = Operator(effect=args["patina"], iterations=4, surfels=20000, bake_size=128)
state, seen, passed = drive(op, ctx)
result["done"] = [state, op.reports, passed, ctx.window_manager.timers, len(ctx.window_manager.handlers)]
result["progress"] = seen
result["texts"] = ctx.workspace.texts[-3:]
result["panel"] = [bpy.context.scene.gamma.running, bpy.context.scene.gamma.last_run]
result["weathered"] = "patina" in bpy.data.objects["Suzanne"].data.attributes
bpy.ops.gamma.restore()
ctx = Context()
op = Operator(effect=args["patina"], iterations=200, surfels=20000, bake_size=64)
state, seen, _ = drive(op, ctx, escape_at=2)
result["cancelled"] = [state, op.reports, ctx.window_manager.timers]
result["untouched"] = digest(bpy.data.objects["Suzanne"]) == before
''', extension, patina=PATINA)
    state, reports, passed, timers, handlers = out["done"]
    assert state == ["FINISHED"] and passed == ["PASS_THROUGH"], out["done"]
    assert timers == 0 and handlers == 1, "the timer is removed when the run ends"
    assert reports and reports[-1][0] == ["INFO"] and "weathered Suzanne" in reports[-1][1]
    progress = out["progress"]
    assert progress == sorted(progress) and progress[-1] == 1.0, progress
    assert any(0 < p < 1 for p in progress), f"progress shown on the way: {progress}"
    assert any("Esc to cancel" in (t or "") for t in out["texts"]) and out["texts"][-1] is None
    running, numbers = out["panel"]
    assert not running and "4 iterations" in numbers and "γ-tons hitting" in numbers, out["panel"]
    assert out["weathered"]
    state, reports, timers = out["cancelled"]
    assert state == ["CANCELLED"] and timers == 0, out["cancelled"]
    assert reports[-1][0] == ["WARNING"] and "cancelled" in reports[-1][1]
    assert out["untouched"]


def test_the_add_ons_glb_reader_agrees_with_pygltflib(tmp_path):
    """glb.py (the add-on reads gamma's export without Blender's importer)
    gives pygltflib's arrays on a real export with a property, and its
    diagnostics parser reads gammac's error positions."""
    import importlib.util

    import pygltflib

    def module(name):                   # outside Blender: the package's __init__ needs bpy
        spec = importlib.util.spec_from_file_location(f"gamma_blender_{name}", ROOT / "blender" / "gamma_blender" / f"{name}.py")
        loaded = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = loaded         # dataclasses look their module up there
        spec.loader.exec_module(loaded)
        return loaded

    read_parts, diagnostics = module("glb").read_parts, module("job").diagnostics

    scene = ROOT / "examples" / "scenes" / "teapot.obj"
    r = subprocess.run([GAMMAC, "run", PATINA, "--scene", str(scene), "--iterations", "1", "--surfels", "3000",
                        "--out", str(tmp_path / "run"), "--export", "--bake-size", "32", "--quiet"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    path = next((tmp_path / "run" / "export").glob("*.glb"))
    parts = read_parts(path)
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()

    def array(index, dtype, width):
        acc = gltf.accessors[index]
        view = gltf.bufferViews[acc.bufferView]
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        return np.frombuffer(blob, dtype, acc.count * width, start).reshape(acc.count, width)

    assert [p.name for p in parts] == [n.name for n in gltf.nodes if n.mesh is not None]
    for part, node in zip(parts, [n for n in gltf.nodes if n.mesh is not None]):
        prim = gltf.meshes[node.mesh].primitives[0]
        assert np.array_equal(part.positions, array(prim.attributes.POSITION, np.float32, 3))
        assert np.array_equal(part.uvs, array(prim.attributes.TEXCOORD_0, np.float32, 2))
        assert np.array_equal(part.attributes["_PATINA"], array(prim.attributes._PATINA, np.float32, 1)[:, 0])
        index_type = {5125: np.uint32, 5123: np.uint16}[gltf.accessors[prim.indices].componentType]
        assert np.array_equal(part.primitives[0].triangles.reshape(-1), array(prim.indices, index_type, 1)[:, 0])
        assert part.primitives[0].material == gltf.materials[prim.material].name
    broken = tmp_path / "broken.gamma"
    broken.write_text("surface S { property p = 0.0 }\nsource s = directional((0, -1, 0)) emits Nope count 10\n")
    r = subprocess.run([GAMMAC, "check", str(broken)], capture_output=True, text=True)
    found = diagnostics(r.stderr)
    assert found and found[0]["line"] == 2 and found[0]["kind"] == "error", r.stderr


def test_continue_from_the_last_run_starts_where_it_ended(extension):
    """"Continue from the last run" is gammac run --init of the objects' last run."""
    out = run('''
obj = suzanne()
result["first"] = weather(effect="dust", iterations=2, surfels=10000, bake_size=64)
obj = bpy.data.objects["Suzanne"]
first = float(values(obj, "dust").sum())
result["next"] = weather(effect="dust", iterations=2, surfels=10000, bake_size=64, continue_run=True)
result["ratio"] = float(values(obj, "dust").sum()) / first
result["other_count"] = weather(effect="dust", iterations=1, surfels=12000, bake_size=64, continue_run=True)
bpy.ops.gamma.restore()
result["never_run"] = weather(effect="dust", iterations=1, surfels=10000, bake_size=64, continue_run=True)
''', extension)
    assert out["first"] == [["FINISHED"], ""] and out["next"] == [["FINISHED"], ""], out
    # the same two iterations again, on top of the first two: dust settles as it did, so about twice
    assert 1.9 < out["ratio"] < 2.1, out["ratio"]
    state, message = out["other_count"]
    assert state == ["ERROR"] and "--surfels: A had 10000, this run 12000" in message, message
    state, message = out["never_run"]
    assert state == ["ERROR"] and "not all weathered by one earlier run" in message, message
