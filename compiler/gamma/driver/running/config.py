"""An effect's runtime ``Config`` and its inputs: sources in scene units,
the ton types' defaults, the textures it reads and the scene's materials.
Shared by a run's set-up (``runner``) and the simulations rebuilt from a
saved run (``reload``); it imports neither.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ... import abi
from ...ir.effect import Effect, Length, Source
from . import budget
from .common import RunError, cpu_count


#: Defaults for ton types that do not say, as fractions of the scene diagonal.
DEFAULT_BOUNCE = Length(0.02, relative=True)
DEFAULT_STEP = Length(0.005, relative=True)
DEFAULT_DRIP_DEGREES = 10.0  # SPEC §4: water clings to walls and slight overhangs
def split_counts(counts: list[int], total: int) -> list[int]:
    """Split ``total`` in proportion to ``counts`` (largest remainder; sums exactly)."""
    whole = sum(counts)
    exact = [total * c / whole for c in counts]
    out = [int(math.floor(x)) for x in exact]
    order = sorted(range(len(counts)), key=lambda i: (out[i] - exact[i], i))
    for i in order[: total - sum(out)]:
        out[i] += 1
    return out


def _direction(value, down) -> tuple[float, float, float]:
    if value == "down":
        return tuple(down)
    if value == "up":
        return tuple(-c for c in down)
    return tuple(value)


def source_arguments(src: Source, lo, hi, diagonal: float, down) -> dict:
    """The runtime's ``add_source`` keyword arguments, in scene units."""
    p = src.params
    args = {"first_iteration": src.first, "last_iteration": src.last, "strength": src.strength or 0.0}
    if "position" in p:
        args["position"] = p["position"].resolve(lo, hi)
    if "direction" in p:
        args["direction"] = _direction(p["direction"], down)
    if "normal" in p:
        args["direction"] = _direction(p["normal"], down)
    if "angle" in p:
        args["angle_deg"] = p["angle"]
        args["falloff"] = p["falloff"]
    if p.get("size") is not None:
        args["size"] = tuple(length.resolve(diagonal) for length in p["size"])
    if p.get("radius") is not None:
        args["radius"] = p["radius"].resolve(diagonal)
    if "emission" in p:
        args["emission"] = p["emission"]
    if src.kind == "surface":           # the surface's index and the weight kernel's are added by build_config
        args["along_normal"] = p["direction"] == "normal"
        if p["direction"] == "normal":
            del args["direction"]
    return args


def build_config(rt, effect: Effect, kernels, opts, bounds, down):
    lo, hi = (np.asarray(b, float) for b in bounds)
    diagonal = float(np.linalg.norm(hi - lo))
    cfg = rt.Config()
    cfg.surfels = opts.surfels
    cfg.seed = opts.seed
    cfg.threads = opts.threads or cpu_count()
    cfg.max_interactions = opts.max_interactions
    cfg.row_width = effect.row_width
    cfg.down = tuple(float(c) for c in down)
    cfg.surface_rows = [s.initial_row + [0.0] * (effect.row_width - len(s.initial_row))
                        for s in effect.surfaces.values()]
    for ton in effect.tons.values():
        bounce = (ton.bounce or DEFAULT_BOUNCE).resolve(diagonal)
        step = (ton.step or DEFAULT_STEP).resolve(diagonal)
        drip = DEFAULT_DRIP_DEGREES if ton.drip is None else ton.drip
        cfg.add_ton_type(*ton.motion, ton.initial, bounce, step, drip)
    counts = [s.count for s in effect.sources]
    if opts.tons is not None:
        counts = split_counts(counts, opts.tons)
    for src, count in zip(effect.sources, counts):
        args = source_arguments(src, lo, hi, diagonal, down)
        if "position" in args:
            problem = budget.distance_problem(f"source '{src.name}'", args["position"], (lo + hi) / 2, diagonal)
            if problem:
                raise RunError(problem)
        if src.kind == "surface":
            args["surface"] = effect.surfaces[src.params["surface"]].index
            weight = src.params.get("weight")
            args["weight_kernel"] = kernels.address[weight.symbol] if weight is not None else 0
        cfg.add_source(src.kind, src.ton, count, **args)
    for k in effect.transport_kernels():
        cfg.set_transport(abi.EVENTS[k.event], k.ton.index, k.surface.index,
                          kernels.address[k.symbol], k.writes_surface)
    for k in effect.update_kernels():
        cfg.set_update(k.surface.index, kernels.address[k.symbol])
    for k in effect.appearance_kernels():
        cfg.set_appearance(k.surface.index, kernels.address[k.symbol], k.writes_look("displacement"))
    for surface in effect.surfaces.values():
        for slot, rate, _ in surface.shape.values():
            cfg.add_shape_rate(surface.index, slot, rate)
    # per-surfel measures (SPEC §12) cost setup time: computed only when a rule reads them
    reads = effect.context_reads()
    cfg.measure_accessibility = "accessibility" in reads
    cfg.measure_curvature = "curvature" in reads
    # mask() in a rule reads the image at the surfel's texture coordinates, at setup (scene_inputs.py)
    cfg.measure_uv = "uv" in effect.context_reads(("transport", "update")) or \
        any(item.kind == "mask" for item in effect.inputs)
    for name in mass_properties(effect):
        cfg.add_mass_property([s.properties.get(name, -1) for s in effect.surfaces.values()],
                              [t.carry.get(name, -1) for t in effect.tons.values()])
    cfg.code_owner = kernels            # the simulation keeps the machine code its addresses point into
    return cfg


#: Largest texture() image, in pixels per side (SPEC §8a); checked from the
#: image's header, before it is decoded, so a decompression bomb costs nothing.
MAX_TEXTURE_SIDE = 8192


def mass_properties(effect: Effect) -> list[str]:
    """Properties whose pick-up is accounted (SPEC §19): a name that is both a
    surface property and an attribute some ton type carries."""
    carried = {name for t in effect.tons.values() for name in t.carry}
    names = []
    for s in effect.surfaces.values():
        names += [n for n in s.properties if n in carried and n not in names]
    return names


def load_textures(effect: Effect) -> list[np.ndarray]:
    """Every texture() image as float32 [H, W, 3] in [0, 1] (display values)."""
    from PIL import Image, UnidentifiedImageError

    from ...files import file_problem

    images = []
    for path, kind in zip(effect.textures, effect.texture_kinds or ["color"] * len(effect.textures)):
        problem = file_problem(Path(path))
        if problem:
            raise RunError(f"cannot read {'texture' if kind == 'color' else 'mask'} '{path}': {problem}")
        if kind == "mask":              # luminance at full precision in every channel (scene_inputs.py)
            from .scene_inputs import MaskError, as_texture

            try:
                images.append(as_texture(path))
            except MaskError as err:
                raise RunError(str(err)) from None
            continue
        try:
            with Image.open(path) as image:
                w, h = image.size
                if max(w, h) > MAX_TEXTURE_SIDE:
                    raise RunError(f"texture '{path}' is {w}x{h} pixels; at most "
                                   f"{MAX_TEXTURE_SIDE}x{MAX_TEXTURE_SIDE} are supported")
                images.append(np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0)
        except (OSError, UnidentifiedImageError, Image.DecompressionBombError, ValueError) as err:
            raise RunError(f"cannot read texture '{path}': {err}") from None
    return images


def set_materials(sim, triangle_material: np.ndarray, materials: list) -> None:
    """Hand the scene's own materials (gltf.Material per material) to the
    runtime: base colour, roughness and metallic, factors and textures."""
    images = []

    def number(image) -> int:
        if image is None:
            return -1
        images.append(np.ascontiguousarray(image, np.float32))
        return len(images) - 1

    factors = np.asarray([(*m.base_factor, m.roughness, m.metallic) for m in materials], np.float32)
    textures = np.asarray([(number(m.base_colour), number(m.rough_metal)) for m in materials], np.int32)
    sim.set_base_colours(np.asarray(triangle_material, np.int32), factors, textures, images)

