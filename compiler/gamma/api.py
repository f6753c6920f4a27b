"""The Python API (``import gamma``): compile an effect, run it on a mesh,
read the results as numpy arrays.  ``gammac run`` is this API plus the
standard outputs.

    effect = gamma.compile("patina.gamma", params={"rate": 0.1})
    result = gamma.run(effect, vertices=V, faces=F, iterations=5, surfels=20_000,
                       progress=lambda it, total, record: print(it, total))
    result.properties["patina"]          # per surfel, float32
    result.vertex_properties()["patina"] # per vertex of the mesh
    result.bake(256)                     # {object: {"color": (256, 256, 3), "orm": ..., "patina": (256, 256)}}
    result.summary                       # what summary.json holds

A run keeps its simulation, so per-vertex values, baked textures and renders
are computed from it on request.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .options import keyword_help

__all__ = ["compile", "run", "Result"]


def compile(path: str | Path | None = None, *, source: str | None = None, params: dict | None = None,
            name: str = "<string>.gamma"):
    """Parse and check an effect from a file (``path``) or a string (``source``,
    named ``name`` in messages, imports resolved from the working folder).
    ``params`` overrides parameters: ``{"rate": 0.1, "patina.tons": 1e5}``.
    Raises ``gamma.GammaError`` (every error, file:line:col) or ``UsageError``."""
    from .frontend.checker import check
    from .frontend.parser import parse

    if (path is None) == (source is None):
        raise TypeError("compile() takes a path or source=, not both")
    if path is not None:
        text = Path(path).read_text(encoding="utf-8")
        name = str(path)
    else:
        text = source
    return check(parse(text, name), {k: float(v) for k, v in (params or {}).items()})


def run(effect, scene: str | Path | None = None, *, vertices=None, faces=None, uvs=None,
        out: str | Path | None = None, progress: Callable[[int, int, dict], None] | None = None,
        show_progress: bool = False, **options) -> "Result":
    """Simulate ``effect`` (from ``compile``) on a mesh file or JSON scene
    (``scene``) or on arrays: ``vertices`` (n, 3), ``faces`` (m, 3) and
    optional ``uvs`` per vertex (n, 2) or per corner (m, 3, 2).
    ``progress(iteration, iterations, record)`` is called after every
    iteration; ``show_progress`` draws ``gammac run``'s progress bar.  With
    ``out`` the standard outputs (maps, renders, summary, ``export=True``
    for glTF) are written there as by ``gammac run``; ``init`` takes a run
    folder or a ``Result``.
    SIGINT or SIGTERM (from the main thread) stop it within a fraction of a
    second with ``gamma.RunInterrupted`` (its ``status``: 130 or 143): the
    runtime pass that was running (the set-up, a trace, a render) stops at
    its next check of the run's cancel token.

    The other keyword options (``gamma.options.OPTIONS``, as ``gammac run``'s), with their defaults:
"""
    import tempfile

    from .driver.running.events import CallbackWriter, IterationUpdated, SetupDone
    from .driver.running.runner import RunError, runtime_module
    from .driver.running.runner import run as drive
    from .driver.running.scene import SceneError, arrays_scene
    from .options import RunOptions

    if (scene is None) == (vertices is None):
        raise TypeError("run() takes a scene path or vertices= and faces=, not both")
    if vertices is not None and faces is None:
        raise TypeError("run() needs faces= with vertices=")
    # without `out` the run's folder is a temporary one, and only what is asked for is computed
    scratch = None if out else tempfile.TemporaryDirectory(prefix="gamma-run-")
    if "assign" in options:
        options["assign"] = list(options["assign"])
    if options.get("down") is not None:
        options["down"] = tuple(options["down"])
    opts = RunOptions(scene=str(scene) if scene is not None else "<arrays>",
                      out=str(out) if out else scratch.name, progress=show_progress, **options)
    built = None
    if vertices is not None:
        try:
            built = arrays_scene(runtime_module(), vertices, faces, uvs, effect, opts.assign, opts.down)
        except SceneError as err:
            raise RunError(str(err)) from None
    sessions: list = []
    writers = [CallbackWriter(lambda e: sessions.append(e.run), events=(SetupDone,))]
    if progress is not None:
        writers.append(CallbackWriter(lambda e: progress(e.iteration, opts.iterations, e.record),
                                      events=(IterationUpdated,)))
    history: list[dict] = []
    summary = drive(effect, opts, writers + [_history_writer(history)], scene=built, standard=bool(out))
    result = Result(effect, sessions[0], summary, history)
    result._scratch = scratch
    return result


run.__doc__ += keyword_help() + "\n"


def _history_writer(keep: list):
    """A writer that keeps every iteration's property columns (per surfel) in ``keep``."""
    from .driver.running.events import CallbackWriter, IterationUpdated

    return CallbackWriter(lambda e: keep.append({k: v.copy() for k, v in e.properties.items()}),
                          events=(IterationUpdated,))


@dataclass
class Result:
    """A finished run: the surfels' values, and the simulation to ask for more."""

    effect: object
    session: object                  # driver.runner.Run (holds the simulation)
    summary: dict
    history: list = field(repr=False)   # per iteration: {property: float32 per surfel}

    @property
    def iterations(self) -> int:
        return len(self.history)

    @property
    def properties(self) -> dict:
        """Each property per surfel after the last iteration (float32; 0 where
        a surfel's surface lacks the property)."""
        return self.history[-1] if self.history else {}

    @property
    def surfel_positions(self) -> np.ndarray:
        return np.asarray(self.session.sim.surfel_positions())

    @property
    def surfel_normals(self) -> np.ndarray:
        return np.asarray(self.session.sim.surfel_normals())

    @property
    def surfel_surfaces(self) -> list[str]:
        """The surface name of every surfel."""
        names = list(self.effect.surfaces)
        return [names[i] for i in self.session.surfel_surface]

    def _at_vertices(self):
        from .driver.outputs.export import vertex_normals

        mesh = self.session.scene.mesh
        verts = np.asarray(mesh.vertices(), np.float32)
        tris = np.asarray(mesh.triangles(), np.int64)
        normals = vertex_normals(verts.astype(np.float64), tris)
        owner = np.zeros(len(verts), np.int32)
        owner[tris.reshape(-1)] = np.repeat(np.arange(len(tris), dtype=np.int32), 3)
        uvs = np.zeros((len(verts), 2), np.float32)
        if mesh.has_uvs:
            uvs[tris.reshape(-1)] = np.asarray(mesh.triangle_uvs(), np.float32).reshape(-1, 2)
        sim = self.session.sim
        rows, look = sim.bake_points(verts, normals, owner, uvs, max(1, self.iterations), self.session.threads)
        return np.asarray(rows), np.asarray(look)[:, :3], owner

    def vertex_properties(self) -> dict:
        """Each property at every vertex of the scene's mesh (the surfels'
        values smoothed as in the renders), float32 per vertex."""
        from .driver.running.runner import property_columns

        rows, _, owner = self._at_vertices()
        surfaces = np.asarray(self.session.scene.triangle_surface)[owner]
        return property_columns(self.effect, rows, surfaces)

    def vertex_colours(self) -> np.ndarray:
        """The appearance colour at every vertex, float32 (n, 3) in [0, 1]."""
        return self._at_vertices()[1]

    @property
    def vertices(self) -> np.ndarray:
        """The scene's mesh vertices (the order of ``vertex_properties``)."""
        return np.asarray(self.session.scene.mesh.vertices())

    def bake(self, size: int = 1024) -> dict:
        """Per object of the scene, its texture set at ``size``²: {"color":
        float32 (size, size, 3), "orm": occlusion, roughness, metallic
        (size, size, 3), "normal": tangent-space unit normals (size, size, 3),
        "height": (size, size), PROPERTY: (size, size)} in the object's
        texture coordinates (or its chart atlas), and "uvs": the layout,
        float32 (triangles, 3, 2)."""
        from .driver.outputs.export import bake_texture_set, layout, pieces, property_slots

        session = self.session
        out = {}
        surfaces = np.asarray(session.scene.triangle_surface)
        corner = np.asarray(session.sim.corner_normals())
        for piece in pieces(session.scene):
            lay = layout(piece, corner, size)
            present = set(np.unique(surfaces[piece.triangles]).tolist())
            ts = bake_texture_set(session.sim, lay, max(1, self.iterations), session.threads,
                                  property_slots(self.effect, surfaces, present))
            out[piece.name] = {"color": ts.base_color, "orm": ts.orm, "normal": ts.normal, "height": ts.height,
                               **ts.properties, "uvs": lay.corner_uvs}
        return out
