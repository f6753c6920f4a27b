"""gamma inside Blender: weather the selected objects with a gamma effect.

- ``bpy.ops.gamma.weather(effect=..., iterations=..., ...)``: from a script or
  ``blender --background`` it runs to completion (Ctrl-C cancels); from the
  interface it runs as a modal operator over the ``gammac`` child, with its
  progress in the status bar and the sidebar, Esc cancelling, the interface
  responsive throughout.
- The sidebar's "gamma" tab (3D view, N): the standard library's recipes
  with their parameters as fields, or an effect file; iterations and quality;
  Run; the last run's numbers.
- The add-on's preferences: where ``gammac`` is (default: on PATH).

The work is in ``job`` (the child process), ``scene_io`` (glb hand-over and
results) and ``glb`` (reading gamma's export).
"""

import contextlib
import shutil
import signal
import tempfile
import threading
from pathlib import Path

import bpy
import numpy as np
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, IntProperty,
                       PointerProperty, StringProperty)

from . import scene_io
from .job import GammaError, GammaJob, RunSettings, find_gammac, list_recipes

#: Quality presets: (surfels, bake size). More surfels, finer weathering; the
#: amounts do not depend on them (SPEC §13.2).
QUALITY = {"DRAFT": (30_000, 512), "STANDARD": (100_000, 1024), "FINAL": (300_000, 2048)}

_recipes_cache: dict = {"gammac": None, "recipes": []}
#: Enum items must outlive the call that made them (Blender keeps pointers to their strings).
_recipe_items: list = []


def _preferences():
    return bpy.context.preferences.addons[__package__].preferences


def recipes(refresh: bool = False) -> list[dict]:
    """``gammac recipes --json``, once per gammac (an empty list if gammac is missing)."""
    try:
        gammac = find_gammac(_preferences().gammac_path)
    except (GammaError, KeyError):
        return []
    if refresh or _recipes_cache["gammac"] != gammac:
        try:
            _recipes_cache.update(gammac=gammac, recipes=list_recipes(gammac))
        except GammaError:              # not asked again on every redraw; Refresh asks again
            _recipes_cache.update(gammac=gammac, recipes=[])
    return _recipes_cache["recipes"]


def resolve_effect(effect: str, gammac: str) -> str:
    """An effect file's absolute path, or the path of the recipe so named ("patina" or "patina.gamma")."""
    path = Path(bpy.path.abspath(effect)) if effect else None
    if path is not None and path.is_file():
        return str(path.resolve())
    name = effect if effect.endswith(".gamma") else effect + ".gamma"
    for recipe in list_recipes(gammac):
        if recipe["name"] == name:
            return recipe["path"]
    raise GammaError(f"no effect file or recipe named '{effect}'")


def _pairs(text: str, what: str) -> list[str]:
    """"a=1, b=2" (or ";"-separated) as ["a=1", "b=2"]."""
    items = [item.strip() for item in text.replace(";", ",").split(",") if item.strip()]
    for item in items:
        if "=" not in item:
            raise GammaError(f"{what} '{item}' is not NAME=VALUE")
    return items


# ---- preferences and scene settings --------------------------------------------------

class GammaPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    gammac_path: StringProperty(name="gammac", default="gammac", subtype="FILE_PATH",
                                description="The gammac program: a path, or a name found on PATH")

    def draw(self, context):
        self.layout.prop(self, "gammac_path")
        try:
            self.layout.label(text=f"Found: {find_gammac(self.gammac_path)}", icon="CHECKMARK")
        except GammaError as e:
            self.layout.label(text=str(e), icon="ERROR")


class GammaParam(bpy.types.PropertyGroup):
    value: FloatProperty(name="Value", precision=4)
    default: StringProperty()
    doc: StringProperty()


def _recipe_enum(self, context):
    _recipe_items.clear()
    for r in recipes():
        _recipe_items.append((r["name"], r["name"].removesuffix(".gamma"), r["summary"]))
    if not _recipe_items:
        _recipe_items.append(("NONE", "(no recipes: is gammac installed?)", ""))
    return _recipe_items


def _recipe_changed(self, context):
    """Fill the parameter fields with the chosen recipe's defaults."""
    self.params.clear()
    self.params_of = self.recipe
    for r in recipes():
        if r["name"] == self.recipe:
            for p in r["params"]:
                item = self.params.add()
                item.name, item.default, item.doc = p["name"], p["default"], p["doc"]
                try:
                    item.value = float(p["default"])
                except ValueError:
                    pass


class GammaSettings(bpy.types.PropertyGroup):
    source: EnumProperty(name="Effect", items=[("RECIPE", "Recipe", "a recipe of gamma's standard library"),
                                               ("FILE", "File", "an effect file (.gamma)")])
    recipe: EnumProperty(name="Recipe", items=_recipe_enum, update=_recipe_changed)
    effect_path: StringProperty(name="Effect file", subtype="FILE_PATH")
    params: CollectionProperty(type=GammaParam)
    params_of: StringProperty()         # the recipe whose fields ``params`` holds
    iterations: IntProperty(name="Iterations", default=10, min=1, max=1000)
    quality: EnumProperty(name="Quality", default="STANDARD", items=[
        ("DRAFT", "Draft", "30k surfels, 512² textures"),
        ("STANDARD", "Standard", "100k surfels, 1024² textures"),
        ("FINAL", "Final", "300k surfels, 2048² textures")])
    seed: IntProperty(name="Seed", default=1, min=0)
    assign: StringProperty(name="Assign", description="PATTERN=SURFACE, comma-separated: which objects "
                           "are which of the effect's surfaces (default: the effect's own rule)")
    shape_key: BoolProperty(name="Shape change as shape key",
                            description="A shape-changing effect adds a shape key instead of replacing the shape")
    continue_run: BoolProperty(name="Continue from the last run",
                               description="Start from where the selected objects' last run ended")
    # what the running job shows
    running: BoolProperty()
    progress: FloatProperty(min=0, max=1)
    status: StringProperty()
    last_run: StringProperty()


@contextlib.contextmanager
def _interruptible():
    """Ctrl-C cancels a run from a script: Blender installs a SIGINT handler
    of its own at start-up (it only flags its jobs to stop), which Python's
    is put in front of while the child runs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


# ---- the operator --------------------------------------------------------------------

def _numbers(job: GammaJob, done: dict) -> str:
    summary = job.summary()
    iterations = summary.get("iterations", [])
    hitting = sum(r.get("emitted", 0) - r.get("missed", 0) for r in iterations)
    props = sorted({p for d in done.values() for p in d["properties"]})
    return (f"{len(iterations)} iterations, {summary.get('surfels', 0):,} surfels, "
            f"{hitting:,} γ-tons hitting, {job.seconds:.1f} s; properties: {', '.join(props) or 'none'}")


class GAMMA_OT_weather(bpy.types.Operator):
    """Weather the selected mesh objects with a gamma effect (a recipe or an effect file)"""
    bl_idname = "gamma.weather"
    bl_label = "Weather"
    bl_options = {"REGISTER", "UNDO"}

    effect: StringProperty(name="Effect", description="An effect file, or a recipe's name (patina, rust, ...)")
    iterations: IntProperty(name="Iterations", default=10, min=1, max=1000)
    surfels: IntProperty(name="Surfels", default=100_000, min=1000, max=10_000_000)
    bake_size: IntProperty(name="Bake size", default=1024, min=8, max=16384)
    seed: IntProperty(name="Seed", default=1, min=0)
    tons: IntProperty(name="γ-tons", default=0, min=0, description="γ-tons per iteration (0: the effect's own)")
    params: StringProperty(name="Parameters", description="NAME=VALUE, comma-separated")
    assign: StringProperty(name="Assign", description="PATTERN=SURFACE, comma-separated")
    shape_key: BoolProperty(name="Shape change as shape key")
    continue_run: BoolProperty(name="Continue from the last run",
                               description="Start from where the selected objects' last run ended "
                                           "(gammac run --init): same objects, quality and seed")

    _job = None
    _timer = None

    @classmethod
    def poll(cls, context):
        return context.mode == "OBJECT"

    # -- shared by both paths

    def _prepare(self, context) -> None:
        gammac = find_gammac(_preferences().gammac_path)
        if not self.effect:
            raise GammaError("no effect given: a recipe's name or an effect file")
        settings = RunSettings(effect=resolve_effect(self.effect, gammac), iterations=self.iterations,
                               surfels=self.surfels, bake_size=self.bake_size, seed=self.seed, tons=self.tons,
                               params=dict(p.split("=", 1) for p in _pairs(self.params, "parameter")),
                               assign=_pairs(self.assign, "assignment"))
        objects = [o for o in context.selected_objects if o.type == "MESH"] or context.selected_objects
        if self.continue_run:
            settings.init = scene_io.last_run(objects)
        self._folder = Path(tempfile.mkdtemp(prefix="gamma-blender-"))
        scene = self._folder / "scene.glb"
        with scene_io.AsMade(objects):          # a second run starts from the objects as made, too
            self._objects = scene_io.mesh_objects(objects)
            self._originals = {o.name: scene_io.world_triangles(o) for o in objects} if self.shape_key else {}
            scene_io.write_handover(self._objects, scene)
        self._names = [o.name for o in self._objects]
        self._job = GammaJob(gammac, settings, scene, self._folder / "run")
        self._job.start()

    def _finish(self, context) -> set:
        job, state = self._job, context.scene.gamma
        state.running = False
        try:
            if job.state == "cancelled":
                self.report({"WARNING"}, "gamma: run cancelled; the objects are as they were")
                return {"CANCELLED"}
            if job.state != "done":
                self.report({"ERROR"}, f"gamma: {job.message}")
                state.status = job.message.splitlines()[0] if job.message else "failed"
                return {"CANCELLED"}
            objects = [bpy.data.objects[n] for n in self._names if n in bpy.data.objects]
            kept = scene_io.keep_run(job.out)
            done = scene_io.apply_results(objects, job.out, job.settings.effect, shape_key=self.shape_key,
                                          originals=self._originals, kept=kept)
            state.last_run = _numbers(job, done)
            state.status = "done"
            self.report({"INFO"}, f"gamma: weathered {', '.join(done)}: {state.last_run}")
            return {"FINISHED"}
        except GammaError as e:
            self.report({"ERROR"}, f"gamma: {e}")
            return {"CANCELLED"}
        finally:
            self._cleanup()

    def _cleanup(self) -> None:
        folder = getattr(self, "_folder", None)
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
            self._folder = None

    # -- a script or --background: to completion

    def _started(self, context) -> bool:
        """The hand-over written and gammac started, or an error reported."""
        try:
            self._prepare(context)
        except GammaError as e:
            self._cleanup()
            self.report({"ERROR"}, f"gamma: {e}")
            return False
        return True

    def execute(self, context):
        if not self._started(context):
            return {"CANCELLED"}
        shown = [-1]

        def show(job):
            if job.iteration != shown[0]:
                shown[0] = job.iteration
                print(f"gamma: {job.message}", flush=True)

        with _interruptible():
            try:
                self._job.wait(on_progress=show)
            except KeyboardInterrupt:
                pass                    # wait() cancelled the child; _finish reports it
        return self._finish(context)

    # -- the interface: modal over the child, Esc cancels

    def invoke(self, context, event):
        if not self._started(context):
            return {"CANCELLED"}
        state = context.scene.gamma
        state.running, state.progress, state.status = True, 0.0, "starting"
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        return {"RUNNING_MODAL"}

    def _end_modal(self, context) -> None:
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        for area in context.screen.areas:
            area.tag_redraw()

    def modal(self, context, event):
        state = context.scene.gamma
        if event.type == "ESC":
            self._job.cancel()
        elif event.type != "TIMER":
            return {"PASS_THROUGH"}
        ended = self._job.poll()
        state.progress, state.status = self._job.progress, self._job.message
        context.window_manager.progress_update(int(100 * self._job.progress))
        context.workspace.status_text_set(f"gamma: {self._job.message} ({100 * self._job.progress:.0f} %), "
                                          "Esc to cancel")
        for area in context.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()
        if not ended:
            return {"RUNNING_MODAL"}
        self._end_modal(context)
        return self._finish(context)


class GAMMA_OT_restore(bpy.types.Operator):
    """Put the selected weathered objects back as they were before gamma (their own mesh and modifiers)"""
    bl_idname = "gamma.restore"
    bl_label = "Remove weathering"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        restored = [o.name for o in context.selected_objects if scene_io.restore(o)]
        if not restored:
            self.report({"WARNING"}, "gamma: no weathered object selected")
            return {"CANCELLED"}
        self.report({"INFO"}, f"gamma: restored {', '.join(restored)}")
        return {"FINISHED"}


class GAMMA_OT_refresh_recipes(bpy.types.Operator):
    """Read the recipe list from gammac again"""
    bl_idname = "gamma.refresh_recipes"
    bl_label = "Refresh recipes"

    def execute(self, context):
        if not recipes(refresh=True):
            self.report({"ERROR"}, "gamma: no recipes: check the path to gammac in the add-on's preferences")
            return {"CANCELLED"}
        _recipe_changed(context.scene.gamma, context)
        return {"FINISHED"}


def _as_written(value: float) -> str:
    """A field's value as its shortest text (fields hold 32-bit floats: 0.1, not 0.10000000149)."""
    return np.format_float_positional(np.float32(value), unique=True, trim="-")


def _differs(param) -> bool:
    try:
        return np.float32(param.default) != np.float32(param.value)
    except ValueError:
        return True


class GAMMA_PT_panel(bpy.types.Panel):
    bl_label = "gamma weathering"
    bl_idname = "GAMMA_PT_panel"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "gamma"

    def draw(self, context):
        s, layout = context.scene.gamma, self.layout
        layout.prop(s, "source", expand=True)
        if s.source == "RECIPE":
            if s.params_of != s.recipe:         # first shown, or a file from another session: fill the fields
                scene = context.scene          # (not from draw(), which may not write data)
                bpy.app.timers.register(lambda: _recipe_changed(scene.gamma, None), first_interval=0)
            row = layout.row(align=True)
            row.prop(s, "recipe", text="")
            row.operator("gamma.refresh_recipes", text="", icon="FILE_REFRESH")
            for p in s.params:
                layout.prop(p, "value", text=p.name)
        else:
            layout.prop(s, "effect_path")
        col = layout.column(align=True)
        col.prop(s, "iterations")
        col.prop(s, "quality")
        col.prop(s, "seed")
        layout.prop(s, "assign")
        layout.prop(s, "shape_key")
        if any((o.get("gamma") or {}).get("run") for o in context.selected_objects):
            layout.prop(s, "continue_run")
        if s.running:
            layout.progress(factor=s.progress, text=s.status)
            layout.label(text="Esc cancels", icon="INFO")
        else:
            surfels, bake = QUALITY[s.quality]
            op = layout.operator("gamma.weather", text="Run", icon="PLAY")
            op.effect = s.effect_path if s.source == "FILE" else s.recipe
            op.iterations, op.surfels, op.bake_size, op.seed = s.iterations, surfels, bake, s.seed
            op.params = ",".join(f"{p.name}={_as_written(p.value)}" for p in s.params if s.source == "RECIPE" and _differs(p))
            op.assign, op.shape_key = s.assign, s.shape_key
            op.continue_run = s.continue_run and any((o.get("gamma") or {}).get("run")
                                                     for o in context.selected_objects)
            layout.operator("gamma.restore", icon="LOOP_BACK")
            if s.status and s.status != "done":
                layout.label(text=s.status, icon="ERROR")
        if s.last_run:
            box = layout.box()
            for line in s.last_run.split("; "):
                box.label(text=line)


CLASSES = (GammaPreferences, GammaParam, GammaSettings, GAMMA_OT_weather, GAMMA_OT_restore, GAMMA_OT_refresh_recipes,
           GAMMA_PT_panel)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.gamma = PointerProperty(type=GammaSettings)


def unregister():
    del bpy.types.Scene.gamma
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
