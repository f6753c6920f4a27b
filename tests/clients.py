"""Our exports as the real clients see them: Blender (the ``bpy`` module, Blender 4.5
LTS) and Pixar's USD (``usd-core``'s ``pxr``).  A helper module for tests, not a test.

Every check runs the client in a child process of this interpreter
(``python tests/clients.py TASK ARGS.json RESULT.json``), so bpy's heavy global state
never enters the pytest process, and answers with plain JSON-able dicts:

    blender_import(path)                 -> dict   what Blender's glTF importer made
    blender_import_many(paths)           -> list   the same for several files, one child
    blender_render(path, png_out, ...)   -> dict   a Cycles (CPU) picture of the import
    blender_script(source, **args)       -> dict   run Python in a bpy child (builds test scenes)
    usd_check(path)                      -> list   ComplianceChecker errors and failed checks
    usd_check_report(path)               -> dict   the same with warnings and the engine used
    usd_summary(path)                    -> dict   prims, UsdPreviewSurface inputs, time samples

A child that fails raises ``ClientError`` (``BlenderImportError`` for an import)
carrying the child's error and its stderr.  ``has_bpy()`` / ``has_usd()`` tell
whether the clients are installed (without importing them here).

Only the standard library is imported at module level: the same file is the
child's program.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Direction from the scene's centre toward the camera, in glTF axes (+Y up),
#: like ``gammac --view`` (gamma.driver.running.camera.DEFAULT_VIEW).
DEFAULT_VIEW = (-0.6, 0.35, 1.0)

#: Principled BSDF inputs whose links a report traces back to image textures.
BSDF_INPUTS = ("Base Color", "Roughness", "Metallic", "Normal", "Alpha", "Emission Color")

#: Principled BSDF inputs reported by value (and whether linked) only.
BSDF_SCALARS = ("Emission Strength", "IOR", "Coat Weight", "Specular IOR Level", "Transmission Weight")

#: UsdPreviewSurface inputs whose connections usd_summary traces to a UsdUVTexture.
PREVIEW_INPUTS = ("diffuseColor", "roughness", "metallic", "normal", "occlusion", "emissiveColor", "opacity")


class ClientError(RuntimeError):
    """A client child process that failed: ``error`` is what the child said
    (its traceback), ``stderr`` the child's whole stderr."""

    def __init__(self, message: str, *, error: str = "", stderr: str = "", stdout: str = "",
                 returncode: int | None = None, log: str = ""):
        self.error, self.stderr, self.stdout, self.returncode, self.log = error, stderr, stdout, returncode, log
        parts = [message]
        if error:
            parts.append("child error:\n" + error.rstrip())
        if log.strip():
            parts.append("client output:\n" + _tail(log))
        if stderr.strip():
            parts.append("child stderr:\n" + _tail(stderr))
        super().__init__("\n".join(parts))


class BlenderImportError(ClientError):
    """Blender's glTF importer refused a file (or crashed on it)."""


def _tail(text: str, lines: int = 60) -> str:
    rows = text.rstrip().splitlines()
    return "\n".join((["..."] if len(rows) > lines else []) + rows[-lines:])


def _last_error_line(error: str) -> str:
    """The exception line of a traceback (the innermost "SomeError: ..." line)."""
    lines = [ln.strip() for ln in error.splitlines() if ln.strip()]
    found = [ln for ln in lines if not ln.startswith(("File ", "Traceback", "^", "Location:"))
             and ":" in ln and ln.split(":", 1)[0].replace(".", "").isidentifier()
             and ln.split(":", 1)[0].split(".")[-1].endswith(("Error", "Exception"))]
    return found[-1] if found else (lines[-1] if lines else "")


#: Blender as a module needs Python 3.11 and numpy < 2, so it lives in a venv
#: of its own (make test makes it), not in the project's: the Blender tasks'
#: children run its interpreter, the others this one.
BLENDER_PYTHON = Path(os.environ.get("GAMMA_BLENDER_PYTHON",
                                     Path(__file__).resolve().parent.parent / ".venv-blender" / "bin" / "python"))


def _python(task: str) -> str:
    return str(BLENDER_PYTHON) if task.startswith("blender") else sys.executable


def has_bpy() -> bool:
    if not BLENDER_PYTHON.is_file():
        return False
    r = subprocess.run([str(BLENDER_PYTHON), "-c", "import importlib.util, sys; "
                        "sys.exit(importlib.util.find_spec('bpy') is None)"], capture_output=True)
    return r.returncode == 0


def has_usd() -> bool:
    return importlib.util.find_spec("pxr") is not None


# --------------------------------------------------------------------------- parent side

def _child(task: str, args: dict, *, timeout: float, error_class=ClientError) -> dict:
    """Run ``task`` in a child of this interpreter; its JSON result (with
    ``seconds``: the child's wall time as seen from here)."""
    with tempfile.TemporaryDirectory(prefix="gamma-client-") as tmp:
        result_path, args_path = Path(tmp) / "result.json", Path(tmp) / "args.json"
        args_path.write_text(json.dumps(args))
        env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONDONTWRITEBYTECODE="1")
        start = time.perf_counter()
        try:
            r = subprocess.run([_python(task), str(Path(__file__).resolve()), task, str(args_path),
                                str(result_path)], capture_output=True, text=True, timeout=timeout,
                               env=env, cwd=tmp, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired as e:
            raise error_class(f"{task}: the client did not finish within {timeout:g} s",
                              stderr=(e.stderr or b"").decode(errors="replace") if isinstance(e.stderr, bytes)
                              else (e.stderr or "")) from None
        seconds = time.perf_counter() - start
        result = json.loads(result_path.read_text()) if result_path.exists() else None
    if result is None or r.returncode != 0:
        error = (result or {}).get("error", "")
        raise error_class(f"{task} {args.get('path') or args.get('paths') or ''} failed "
                          f"(child exit code {r.returncode})", error=error, stderr=r.stderr,
                          stdout=r.stdout, returncode=r.returncode, log=(result or {}).get("log", ""))
    result["seconds"] = round(seconds, 3)
    result["stderr"] = r.stderr
    return result


def blender_import_many(paths, *, shading: str = "NORMALS", errors: str = "raise",
                        timeout: float = 600) -> list[dict]:
    """Import each .glb/.gltf into a factory-reset Blender, all in one child.

    Each report (see ``blender_import``) also has ``seconds`` (that import's
    time in the child).  ``errors="raise"`` raises ``BlenderImportError`` for the
    first file the importer refused; ``"return"`` puts ``{"path", "error", "log"}``
    in its place instead."""
    paths = [str(Path(p).resolve()) for p in paths]
    for p in paths:
        if not Path(p).is_file():
            raise FileNotFoundError(p)
    out = _child("blender_import", {"paths": paths, "shading": shading}, timeout=timeout,
                 error_class=BlenderImportError)
    reports = out["reports"]
    for report in reports:
        report["import_bpy_seconds"] = out["import_bpy_seconds"]
        if "error" in report and errors == "raise":
            raise BlenderImportError(f"Blender's glTF importer failed on {report['path']}: "
                                     f"{_last_error_line(report['error'])}",
                                     error=report["error"], log=report.get("log", ""), stderr=out["stderr"])
    return reports


def blender_import(path, *, shading: str = "NORMALS", timeout: float = 600) -> dict:
    """What Blender's glTF importer makes of one .glb/.gltf.

    Returns ``{"path", "objects", "meshes", "materials", "images", "scene_extras",
    "messages", "log", "seconds", "import_bpy_seconds"}``:

    * objects: ``{name, type, data, parent, materials, custom_properties,
      bounds: [[min xyz], [max xyz]] in Blender's world (Z up)}``
    * meshes (by mesh name): ``{name, vertices, polygons, loops,
      smooth_fraction (faces not ``sharp_face``: the Smooth/Flat flag a user
      sees), shaded_smooth_fraction (faces whose corner normals, custom ones
      included, leave the face normal: what the shading shows),
      has_sharp_face, has_custom_normals, uv_layers, color_attributes,
      render_color, attributes: [{name, domain, data_type, min, max, mean}]}``
      (min/max/mean per component, for float and colour attributes; Blender's
      internal ``.attributes`` are left out)
    * materials (by name): ``{name, nodes: [bl_idname...], bsdf: {input: {linked,
      default, sources: [{path, image, colorspace, channel}]}} (for BSDF_INPUTS,
      None when there is no Principled BSDF), textures: [{node, image, colorspace,
      to: [downstream path...]}]}``; a source ``path`` is the chain of
      ``"NodeType.output"`` steps from the BSDF input back to the image, and
      ``channel`` the image output used ("Color"/"Alpha") with any Separate
      Color output ("Red"/"Green"/"Blue") in the path
    * images: ``[{name, size, colorspace, filepath, packed, channels, alpha_mode}]``
    * messages: ``[{level, message}]`` the importer logged at warning or above,
      plus Python warnings; log: everything the import printed.
    """
    return blender_import_many([path], shading=shading, timeout=timeout)[0]


def blender_render(path, png_out, *, size: int = 512, samples: int = 32, view=DEFAULT_VIEW,
                   fov_deg: float = 30.0, sky=(0.55, 0.65, 0.8), sky_strength: float = 1.0,
                   sun_strength: float = 3.0, view_transform: str = "Standard",
                   timeout: float = 900) -> dict:
    """Import the glb into a factory-reset Blender and render it with Cycles on
    the CPU: a camera on ``view`` (from the bounds' centre toward the camera, in
    glTF axes, +Y up) framing every mesh's bounds, a sun from over the camera's
    shoulder, a uniform sky colour as the world.  Denoising is on when this
    Blender has OpenImageDenoise.  Writes ``png_out`` (size x size, RGBA PNG);
    returns ``{png, seconds, render_seconds, camera, bounds, denoised, report}``."""
    if not Path(path).is_file():
        raise FileNotFoundError(path)
    png_out = Path(png_out).resolve()
    png_out.parent.mkdir(parents=True, exist_ok=True)
    return _child("blender_render", {"path": str(Path(path).resolve()), "png": str(png_out), "size": int(size),
                                     "samples": int(samples), "view": list(map(float, view)), "fov": float(fov_deg),
                                     "sky": list(map(float, sky)), "sky_strength": float(sky_strength),
                                     "sun_strength": float(sun_strength), "view_transform": view_transform},
                  timeout=timeout, error_class=BlenderImportError)


def blender_script(source: str, *, timeout: float = 600, **args) -> dict:
    """Run ``source`` in a child with bpy imported (factory-reset, empty scene).
    The code sees ``bpy``, ``args`` (the keyword arguments, JSON-able), a
    dict ``result`` to fill with JSON-able values, which is returned (with
    ``seconds`` and ``stderr``), and ``render(png, size=..., samples=...)``:
    ``blender_render``'s Cycles picture of the scene the code made."""
    return _child("blender_script", {"source": source, "args": args}, timeout=timeout)


def usd_check(path, *, engine: str = "auto", timeout: float = 300) -> list[str]:
    """usd-core's ``UsdUtils.ComplianceChecker`` (arkit=False, default rules) on a
    .usd/.usda/.usdc/.usdz: its errors and failed checks; empty means it passes.

    ``engine="validation"`` runs ``UsdValidation`` (every registered validator,
    what ``usdchecker`` runs since usd-core 26.8, which no longer ships
    ComplianceChecker) instead, its errors as ``"ERRORTYPE name: message"``;
    ``"auto"`` takes ComplianceChecker where this usd-core has it."""
    return usd_check_report(path, engine=engine, timeout=timeout)["problems"]


def usd_check_report(path, *, engine: str = "auto", timeout: float = 300) -> dict:
    """``usd_check`` in full: ``{engine, errors, failed_checks, warnings, problems}``."""
    if engine not in ("auto", "compliance", "validation"):
        raise ValueError(f"engine must be auto, compliance or validation, not {engine!r}")
    if not Path(path).exists():
        raise FileNotFoundError(path)
    out = _child("usd_check", {"path": str(Path(path).resolve()), "engine": engine}, timeout=timeout)
    out["problems"] = out["errors"] + out["failed_checks"]
    return out


def usd_summary(path, *, timeout: float = 300) -> dict:
    """``{default_prim, up_axis, meters_per_unit, prims: [[path, type]...],
    materials: {path: {surface, inputs: {input: {connected, texture, file,
    output, value}}}}, start_time_code, end_time_code, has_time_code_range,
    points_time_samples: {mesh path: count}, animated_points}``: for each
    UsdPreviewSurface, which of PREVIEW_INPUTS are connected to a UsdUVTexture
    (``texture`` its prim path, ``file`` its asset path as authored, ``output``
    the texture output used: rgb, r, g...)."""
    return _child("usd_summary", {"path": str(Path(path).resolve())}, timeout=timeout)


# --------------------------------------------------------------------------- child side
# Everything below runs only in the child (bpy / pxr imported there).

class _Captured:
    """Everything written to fds 1 and 2 (C and Python) and every Python
    warning and importer log record at WARNING or above, while active."""

    def __enter__(self):
        import ctypes
        import logging
        import warnings

        self._libc = ctypes.CDLL(None)
        self.records, self.text = [], ""
        sys.stdout.flush(), sys.stderr.flush()
        self._libc.fflush(None)
        self._file = tempfile.TemporaryFile()
        self._saved = os.dup(1), os.dup(2)
        os.dup2(self._file.fileno(), 1)
        os.dup2(self._file.fileno(), 2)

        records = self.records

        class Handler(logging.Handler):
            def emit(self, record):
                records.append({"level": record.levelname, "message": record.getMessage(),
                                "logger": record.name})

        self._handler = Handler(logging.WARNING)
        self._loggers = [logging.getLogger(n) for n in ("", "glTFImporter", "glTFImporter_errors")]
        for logger in self._loggers:
            logger.addHandler(self._handler)
        self._warnings = warnings.catch_warnings(record=True)
        self.warnings = self._warnings.__enter__()
        warnings.simplefilter("always")
        return self

    def __exit__(self, *exc):
        sys.stdout.flush(), sys.stderr.flush()
        self._libc.fflush(None)
        self._warnings.__exit__(*exc)
        for logger in self._loggers:
            logger.removeHandler(self._handler)
        os.dup2(self._saved[0], 1)
        os.dup2(self._saved[1], 2)
        for fd in self._saved:
            os.close(fd)
        self._file.seek(0)
        self.text = self._file.read().decode(errors="replace")
        self._file.close()
        for w in self.warnings:
            self.records.append({"level": "PYWARNING", "message": f"{w.category.__name__}: {w.message}",
                                 "logger": f"{w.filename}:{w.lineno}"})
        # Blender's own operator reports (printed in background mode).
        for line in self.text.splitlines():
            low = line.lower()
            if (low.startswith(("warning:", "error:")) or "| warning:" in low or "| error:" in low) \
                    and not any(line.endswith(r["message"]) for r in self.records):
                self.records.append({"level": "PRINTED", "message": line.strip(), "logger": "stdout"})
        return False


def _reset(bpy):
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _stats(values, width):
    import numpy as np

    if len(values) == 0:
        return None, None, None
    a = np.asarray(values, np.float64).reshape(-1, width)
    r = lambda v: [round(float(x), 6) for x in v]  # noqa: E731
    return r(a.min(0)), r(a.max(0)), r(a.mean(0))


_ATTRIBUTE_WIDTH = {"FLOAT": (1, "value"), "INT": (1, "value"), "FLOAT2": (2, "vector"),
                    "FLOAT_VECTOR": (3, "vector"), "FLOAT_COLOR": (4, "color"), "BYTE_COLOR": (4, "color"),
                    "INT8": (1, "value"), "BOOLEAN": (1, "value")}


def _json_value(v):
    try:
        return [round(float(x), 6) for x in v]
    except TypeError:
        pass
    if isinstance(v, (bool, int, float, str)) or v is None:
        return round(v, 6) if isinstance(v, float) else v
    return repr(v)


def _custom_properties(idblock) -> dict:
    out = {}
    for k in idblock.keys():
        v = idblock[k]
        if hasattr(v, "to_dict"):
            v = v.to_dict()
        elif hasattr(v, "to_list"):
            v = v.to_list()
        try:
            json.dumps(v)
        except TypeError:
            v = repr(v)
        out[k] = v
    return out


def _mesh_report(mesh) -> dict:
    import numpy as np

    n = len(mesh.polygons)
    smooth = np.zeros(n, bool)
    shaded = None
    if n:
        mesh.polygons.foreach_get("use_smooth", smooth)     # reads sharp_face in Blender 4.1+
        # What the shading shows: a face whose corner normals (custom normals
        # included) all stay within ~0.8 degrees of its face normal looks flat.
        corner = np.zeros(len(mesh.loops) * 3, np.float32)
        mesh.corner_normals.foreach_get("vector", corner)
        face = np.zeros(n * 3, np.float32)
        mesh.polygons.foreach_get("normal", face)
        loop_face = np.repeat(np.arange(n), np.diff([*(p.loop_start for p in mesh.polygons), len(mesh.loops)]))
        dots = np.einsum("ij,ij->i", corner.reshape(-1, 3), face.reshape(-1, 3)[loop_face])
        bent = np.zeros(n, bool)
        np.logical_or.at(bent, loop_face, dots < 0.9999)
        shaded = float(bent.mean())
    attributes = []
    for a in mesh.attributes:
        if a.name.startswith("."):
            continue
        entry = {"name": a.name, "domain": a.domain, "data_type": a.data_type}
        width, prop = _ATTRIBUTE_WIDTH.get(a.data_type, (None, None))
        if width and len(a.data):
            values = np.zeros(len(a.data) * width, np.float64 if prop != "value" or a.data_type == "FLOAT"
                              else np.int64)
            if a.data_type == "BOOLEAN":
                values = np.zeros(len(a.data), bool)
            a.data.foreach_get(prop, values)
            entry["min"], entry["max"], entry["mean"] = _stats(values, width)
        attributes.append(entry)
    return {
        "name": mesh.name, "vertices": len(mesh.vertices), "polygons": n, "loops": len(mesh.loops),
        "smooth_fraction": float(smooth.mean()) if n else None,
        "shaded_smooth_fraction": shaded,
        "has_sharp_face": "sharp_face" in mesh.attributes,
        "has_custom_normals": bool(mesh.has_custom_normals),
        "uv_layers": [uv.name for uv in mesh.uv_layers],
        "color_attributes": [c.name for c in mesh.color_attributes],
        "render_color": (mesh.color_attributes[mesh.color_attributes.render_color_index].name
                         if len(mesh.color_attributes) and mesh.color_attributes.render_color_index >= 0 else None),
        "attributes": attributes,
        "materials": [m.name if m else None for m in mesh.materials],
        "custom_properties": _custom_properties(mesh),
    }


def _step(link) -> str:
    return f"{link.from_node.bl_idname}.{link.from_socket.name}"


def _sources(socket, path=(), seen=None, attributes=None) -> list[dict]:
    """Image textures upstream of an input socket, with the chain of nodes;
    vertex colour / attribute nodes met on the way go to ``attributes``."""
    seen = set() if seen is None else seen
    found = []
    for link in socket.links:
        if link.is_muted:
            continue
        node, step = link.from_node, _step(link)
        chain = [*path, step]
        if node.type == "TEX_IMAGE":
            image = node.image
            channels = [s.split(".")[-1] for s in chain if s.startswith("ShaderNodeSeparate")]
            found.append({"path": chain, "node": node.name, "image": image.name if image else None,
                          "colorspace": image.colorspace_settings.name if image else None,
                          "channel": ".".join([link.from_socket.name, *channels[::-1]])})
            continue
        if node.type in ("VERTEX_COLOR", "ATTRIBUTE") and attributes is not None:
            attributes.append({"path": chain, "node": node.bl_idname,
                               "name": getattr(node, "layer_name", None) or getattr(node, "attribute_name", None)})
        if node.as_pointer() in seen:
            continue
        seen.add(node.as_pointer())
        for inp in node.inputs:
            if inp.is_linked:
                found += _sources(inp, chain, seen, attributes)
    return found


def _downstream(socket, path=(), depth=0) -> list[list[str]]:
    """Where an output socket leads: every chain to a node that has no linked
    outputs (the BSDF, the material output, glTF's own group...)."""
    chains = []
    for link in socket.links:
        if link.is_muted:
            continue
        node = link.to_node
        step = f"{node.bl_idname}{'(' + node.node_tree.name + ')' if node.type == 'GROUP' and node.node_tree else ''}" \
               f".{link.to_socket.name}"
        outs = [o for o in node.outputs if o.is_linked]
        if not outs or node.type in ("BSDF_PRINCIPLED", "OUTPUT_MATERIAL", "GROUP") or depth > 20:
            chains.append([*path, step])
        else:
            for o in outs:      # "ShaderNodeSeparateColor.Color->Red": in by Color, out by Red
                chains += _downstream(o, [*path, f"{step}->{o.name}"], depth + 1)
    return chains


def _material_report(mat) -> dict:
    report = {"name": mat.name, "use_nodes": mat.use_nodes, "nodes": [], "bsdf": None, "textures": [],
              "blend_method": getattr(mat, "blend_method", None), "custom_properties": _custom_properties(mat)}
    tree = mat.node_tree if mat.use_nodes else None
    if tree is None:
        return report
    report["nodes"] = sorted(n.bl_idname + (f"({n.node_tree.name})" if n.type == "GROUP" and n.node_tree else "")
                             for n in tree.nodes)
    bsdf = next((n for n in tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is not None:
        report["bsdf"] = {}
        for name in BSDF_INPUTS:
            sock = bsdf.inputs.get(name)
            if sock is None:
                continue
            attributes = []
            entry = {"linked": sock.is_linked,
                     "sources": _sources(sock, attributes=attributes) if sock.is_linked else [],
                     "attributes": attributes, "from": [_step(link) for link in sock.links]}
            if hasattr(sock, "default_value"):
                entry["default"] = _json_value(sock.default_value)
            report["bsdf"][name] = entry
        for name in BSDF_SCALARS:
            sock = bsdf.inputs.get(name)
            if sock is not None:
                report["bsdf"][name] = {"linked": sock.is_linked, "default": _json_value(sock.default_value)}
    for node in tree.nodes:
        if node.type == "TEX_IMAGE":
            report["textures"].append({
                "node": node.name, "image": node.image.name if node.image else None,
                "colorspace": node.image.colorspace_settings.name if node.image else None,
                "interpolation": node.interpolation, "extension": node.extension,
                "to": [chain for o in node.outputs for chain in _downstream(o, [f"{o.name}"])]})
    return report


def _scene_report(bpy, path) -> dict:
    import numpy as np

    objects = []
    for obj in bpy.data.objects:
        entry = {"name": obj.name, "type": obj.type, "data": obj.data.name if obj.data else None,
                 "parent": obj.parent.name if obj.parent else None,
                 "materials": [s.material.name if s.material else None for s in obj.material_slots],
                 "custom_properties": _custom_properties(obj)}
        if obj.type == "MESH" and len(obj.data.vertices):
            co = np.zeros(len(obj.data.vertices) * 3)
            obj.data.vertices.foreach_get("co", co)
            co = co.reshape(-1, 3)
            m = np.array(obj.matrix_world)
            world = co @ m[:3, :3].T + m[:3, 3]
            entry["bounds"] = [world.min(0).round(6).tolist(), world.max(0).round(6).tolist()]
        objects.append(entry)
    images = [{"name": im.name, "size": list(im.size), "colorspace": im.colorspace_settings.name,
               "filepath": im.filepath, "packed": im.packed_file is not None, "channels": im.channels,
               "alpha_mode": im.alpha_mode, "source": im.source}
              for im in bpy.data.images if im.type == "IMAGE"]
    scene = bpy.context.scene
    return {"path": path, "objects": objects,
            "meshes": {m.name: _mesh_report(m) for m in bpy.data.meshes},
            "materials": {m.name: _material_report(m) for m in bpy.data.materials},
            "images": images, "scene_extras": _custom_properties(scene)}


def _import_gltf(bpy, path, shading) -> tuple[dict | None, "_Captured"]:
    _reset(bpy)
    with _Captured() as cap:
        try:
            bpy.ops.import_scene.gltf(filepath=path, import_shading=shading)
            error = None
        except Exception:
            import traceback

            error = traceback.format_exc()
    return error, cap


def _task_blender_import(args) -> dict:
    start = time.perf_counter()
    import bpy

    import_bpy = time.perf_counter() - start
    reports = []
    for path in args["paths"]:
        start = time.perf_counter()
        error, cap = _import_gltf(bpy, path, args.get("shading", "NORMALS"))
        seconds = time.perf_counter() - start
        if error:
            reports.append({"path": path, "error": error, "log": cap.text, "messages": cap.records,
                            "seconds": round(seconds, 3)})
            continue
        report = _scene_report(bpy, path)
        report.update(messages=cap.records, log=cap.text, seconds=round(seconds, 3))
        reports.append(report)
    return {"reports": reports, "import_bpy_seconds": round(import_bpy, 3)}


def _task_blender_render(args) -> dict:
    import bpy

    error, cap = _import_gltf(bpy, args["path"], "NORMALS")
    if error:
        raise RuntimeError(f"import of {args['path']} failed:\n{error}\n{cap.text}")
    report = _scene_report(bpy, args["path"])
    report.update(messages=cap.records)
    bounds = [o["bounds"] for o in report["objects"] if "bounds" in o]
    if not bounds:
        raise RuntimeError(f"{args['path']}: no mesh with vertices to render")
    out = _render_scene(bpy, bounds, args)
    out["report"] = report
    return out


def _scene_bounds(bpy) -> list:
    """World-space (lo, hi) of every mesh object the render shows."""
    from mathutils import Vector

    bounds = []
    for obj in bpy.context.scene.objects:
        if obj.type == "MESH" and len(obj.data.vertices) and not obj.hide_render:
            corners = [obj.matrix_world @ Vector(c) for c in obj.bound_box]
            bounds.append(([min(c[i] for c in corners) for i in range(3)],
                           [max(c[i] for c in corners) for i in range(3)]))
    return bounds


def _render_scene(bpy, bounds, args) -> dict:
    """A Cycles (CPU) picture of the current scene framed on ``bounds``:
    a camera from ``args["view"]``, a sun over its shoulder and a plain sky."""
    import math

    from mathutils import Vector

    lo = Vector([min(b[0][i] for b in bounds) for i in range(3)])
    hi = Vector([max(b[1][i] for b in bounds) for i in range(3)])
    centre, radius = (lo + hi) / 2, max((hi - lo).length / 2, 1e-6)
    vx, vy, vz = args["view"]
    direction = Vector((vx, -vz, vy)).normalized()          # glTF (+Y up) -> Blender (+Z up)
    fov = math.radians(args["fov"])
    distance = radius / math.sin(fov / 2) * 1.02
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("camera")
    cam_data.angle = fov
    cam_data.clip_start, cam_data.clip_end = distance * 1e-3, distance + 4 * radius
    cam = bpy.data.objects.new("camera", cam_data)
    cam.location = centre + direction * distance
    cam.rotation_euler = (-direction).to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(cam)
    scene.camera = cam
    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.energy = args["sun_strength"]
    sun = bpy.data.objects.new("sun", sun_data)
    # From over the camera's left shoulder and above.
    right = direction.cross(Vector((0, 0, 1)))
    if right.length < 1e-6:
        right = Vector((1, 0, 0))
    to_sun = (direction + Vector((0, 0, 0.8)) - right.normalized() * 0.5).normalized()
    sun.rotation_euler = (-to_sun).to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(sun)
    world = scene.world or bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    background = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    background.inputs["Color"].default_value = (*args["sky"], 1.0)
    background.inputs["Strength"].default_value = args["sky_strength"]
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args["samples"]
    scene.cycles.use_adaptive_sampling = False
    try:
        import _cycles

        denoise = bool(getattr(_cycles, "with_openimagedenoise", False))
    except ImportError:
        denoise = False
    scene.cycles.use_denoising = denoise
    if denoise:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    scene.render.resolution_x = scene.render.resolution_y = args["size"]
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.film_transparent = False
    scene.view_settings.view_transform = args["view_transform"]
    scene.render.filepath = args["png"]
    start = time.perf_counter()
    with _Captured() as render_cap:
        bpy.ops.render.render(write_still=True)
    render_seconds = time.perf_counter() - start
    if not Path(args["png"]).exists():
        raise RuntimeError(f"Cycles wrote no picture:\n{render_cap.text}")
    return {"png": args["png"], "render_seconds": round(render_seconds, 3), "denoised": denoise,
            "camera": {"location": list(cam.location), "target": list(centre), "fov_deg": args["fov"]},
            "bounds": [list(lo), list(hi)]}


def _task_blender_script(args) -> dict:
    import bpy

    _reset(bpy)
    def render(png, *, size=512, samples=32, view=DEFAULT_VIEW, fov_deg=30.0, sky=(0.55, 0.65, 0.8),
               sky_strength=1.0, sun_strength=3.0, view_transform="Standard") -> dict:
        """blender_render's picture of the script's own scene."""
        bounds = _scene_bounds(bpy)
        if not bounds:
            raise RuntimeError("no mesh with vertices to render")
        return _render_scene(bpy, bounds, {"png": str(png), "size": int(size), "samples": int(samples),
                                           "view": list(view), "fov": float(fov_deg), "sky": list(sky),
                                           "sky_strength": sky_strength, "sun_strength": sun_strength,
                                           "view_transform": view_transform})

    namespace = {"bpy": bpy, "args": args["args"], "result": {}, "render": render,
                 "__name__": "__blender_script__"}
    exec(compile(args["source"], "<blender_script>", "exec"), namespace)
    json.dumps(namespace["result"])
    return namespace["result"]


def _task_usd_check(args) -> dict:
    from pxr import UsdUtils

    engine = args.get("engine", "auto")
    if engine == "auto":
        engine = "compliance" if hasattr(UsdUtils, "ComplianceChecker") else "validation"
    if engine == "compliance":
        checker = UsdUtils.ComplianceChecker(arkit=False, skipARKitRootLayerCheck=False, rootPackageOnly=False,
                                             skipVariants=False, verbose=False)
        checker.CheckCompliance(args["path"])
        return {"engine": engine, "errors": list(checker.GetErrors()),
                "failed_checks": list(checker.GetFailedChecks()), "warnings": list(checker.GetWarnings())}
    from pxr import Usd, UsdValidation

    stage = Usd.Stage.Open(args["path"])
    if stage is None:
        return {"engine": engine, "errors": [f"usd-core cannot open {args['path']}"], "failed_checks": [],
                "warnings": []}
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    found = UsdValidation.ValidationContext(validators).Validate(stage)
    errors, warnings = [], []
    for e in found:
        if e.HasNoError():
            continue
        kind = str(e.GetType()).rsplit(".", 1)[-1]
        text = f"{kind} {e.GetName()}: {e.GetMessage()}"
        (warnings if kind.lower() in ("warn", "info") else errors).append(text)
    return {"engine": engine, "errors": errors, "failed_checks": [], "warnings": warnings}


def _task_usd_summary(args) -> dict:
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(args["path"])
    if stage is None:
        raise RuntimeError(f"usd-core cannot open {args['path']}")
    default = stage.GetDefaultPrim()
    out = {"default_prim": str(default.GetPath()) if default else None,
           "up_axis": str(UsdGeom.GetStageUpAxis(stage)),
           "meters_per_unit": UsdGeom.GetStageMetersPerUnit(stage),
           "start_time_code": stage.GetStartTimeCode(), "end_time_code": stage.GetEndTimeCode(),
           "has_time_code_range": stage.HasAuthoredTimeCodeRange(),
           "prims": [], "materials": {}, "points_time_samples": {}}
    for prim in stage.Traverse():
        out["prims"].append([str(prim.GetPath()), str(prim.GetTypeName())])
        if prim.IsA(UsdGeom.Mesh):
            points = UsdGeom.Mesh(prim).GetPointsAttr()
            out["points_time_samples"][str(prim.GetPath())] = points.GetNumTimeSamples()
        if prim.IsA(UsdShade.Material):
            material = UsdShade.Material(prim)
            surface = material.ComputeSurfaceSource()[0]
            entry = {"surface": str(surface.GetPath()) if surface else None, "shader_id": None, "inputs": {}}
            if surface:
                entry["shader_id"] = str(surface.GetIdAttr().Get())
                for name in PREVIEW_INPUTS:
                    inp = surface.GetInput(name)
                    if not inp:
                        continue
                    info = {"connected": False, "texture": None, "file": None, "output": None,
                            "value": _json_value(inp.Get()) if inp.Get() is not None else None}
                    if inp.HasConnectedSource():
                        source, output, _ = inp.GetConnectedSource()
                        shader = UsdShade.Shader(source.GetPrim())
                        info.update(connected=True, texture=str(source.GetPath()), output=str(output),
                                    source_id=str(shader.GetIdAttr().Get()) if shader else None)
                        file_input = shader.GetInput("file") if shader else None
                        if file_input:
                            asset = file_input.Get()
                            info["file"] = asset.path if asset is not None else None
                            info["resolved"] = asset.resolvedPath if asset is not None else None
                    entry["inputs"][name] = info
            out["materials"][str(prim.GetPath())] = entry
    out["animated_points"] = any(n > 1 for n in out["points_time_samples"].values())
    return out


def _main(argv) -> int:
    task, args, result_path = argv[0], json.loads(Path(argv[1]).read_text()), Path(argv[2])
    try:
        result = globals()[f"_task_{task}"](args)
    except BaseException:
        import traceback

        error = traceback.format_exc()
        result_path.write_text(json.dumps({"error": error}))
        sys.stderr.write(error)
        return 3
    result_path.write_text(json.dumps(result))
    return 0


if __name__ == "__main__":
    code = _main(sys.argv[1:])
    sys.stdout.flush(), sys.stderr.flush()
    os._exit(code)     # no slow bpy teardown
