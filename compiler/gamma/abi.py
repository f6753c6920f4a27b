"""The compiler <-> runtime interface, declared once.

Everything the generated kernels, the Python driver and the C++ runtime must
agree on lives here: the ABI version, the kernel signatures, the layout of a
surfel's row and of the context struct a kernel may read, the event
numbering, the source kinds and statistics of the runtime, and the binding
(``BINDING``: every name the Python side calls on ``gamma._runtime``).  The
C++ side does not restate the kernel interface: CMake runs this file as a
script (``python abi.py --header OUT``) to generate ``gamma_abi.h``, and the
code generator builds its LLVM types from the same tables.  The binding is
checked when the driver imports the runtime (``check_runtime``), so a runtime
built from other sources fails with a list of what differs, not halfway
through a run.  Only the standard library is imported so the build can run
this before the package is installed.
"""

from __future__ import annotations

import sys

#: Bumped whenever anything below changes; ``driver.runner.runtime_module``
#: refuses a runtime built for another version.
ABI_VERSION = 10

#: A surfel's state is one row of floats.  The first three slots are its
#: gamma-reflectance, then the properties of its surface in declaration order.
REFLECTANCE_SLOTS = ("straight", "parabolic", "flow")  # Delta_s, Delta_p, Delta_f
ROW_HEADER = len(REFLECTANCE_SLOTS)

#: Events a transport rule can be attached to; the value is the index used by
#: the runtime's kernel table.
#: ``hit`` fires at every interaction, before the outcome's own event.
EVENTS = {"hit": 0, "reflect": 1, "bounce": 2, "flow": 3, "settle": 4}

#: Fields of the read-only context a kernel receives, in struct order.
#: (name, C type, element count).  All fields are 4 bytes wide so the struct
#: has no padding; offsets are computed, not written down twice.
CONTEXT_FIELDS = (
    ("position", "float", 3),       # hit point (transport) / surfel position (update)
    ("normal", "float", 3),         # geometric normal facing the incoming ray / surfel normal
    ("direction", "float", 3),      # travel direction of the gamma-ton (zero in update rules)
    ("height", "float", 1),         # height of position above the scene's lowest point, along "up"
    ("iteration", "int32_t", 1),    # 1-based iteration number (iter_0001 is the first)
    ("interactions", "int32_t", 1), # interactions of this gamma-ton so far, this one included
    ("random_key", "uint32_t", 2),  # low, high word of the key of random() for this call
    ("uv", "float", 2),             # texture coordinates of the point / the surfel (0 without)
    ("up", "float", 3),             # unit vector opposite the scene's down (SPEC §15)
    ("accessibility", "float", 1),  # openness of the surfel / point in [0, 1] (SPEC §12)
    ("curvature", "float", 1),      # mean curvature of the surface there, convex > 0
)

_C_SIZE = {"float": 4, "int32_t": 4, "uint32_t": 4}


def context_offsets() -> dict[str, int]:
    """Byte offset of every context field."""
    offsets, at = {}, 0
    for name, ctype, count in CONTEXT_FIELDS:
        offsets[name] = at
        at += _C_SIZE[ctype] * count
    return offsets


CONTEXT_SIZE = sum(_C_SIZE[t] * n for _, t, n in CONTEXT_FIELDS)

#: Kernel signatures.  Transport kernels get the gamma-ton's carried attributes
#: (read/write), the surfel's row as it was at the start of the iteration
#: (read-only) and a zeroed delta row the runtime adds to the surfel after the
#: tracing pass.  Update kernels get the surfel's row in place.
#: Both return 0, or the 1-based number of the first statement (in the
#: kernel's order, see ``Kernel.statements``) whose result was NaN or
#: infinite: that store was skipped, and the runtime counts the event.
TRANSPORT_SIGNATURE = (
    "int32_t",
    (("float*", "ton"), ("const float*", "surf"), ("float*", "surf_delta"),
     ("const GammaContext*", "ctx")),
)
UPDATE_SIGNATURE = ("int32_t", (("float*", "surf"), ("const GammaContext*", "ctx")))
#: What an appearance block sets at a point (SPEC §8a): the outputs in the
#: order of the kernel's ``look`` array, each (name, floats, kind), and the
#: value each starts as where the scene's material says nothing (the colour
#: always starts as the scene's base colour).  ``roughness``, ``metallic`` and
#: ``occlusion`` are clamped to [0, 1] by the runtime, like the colour;
#: ``displacement`` is a distance in scene units along the normal.
APPEARANCE_OUTPUTS = (
    ("color", 3, "color"),
    ("roughness", 1, "float"),
    ("metallic", 1, "float"),
    ("displacement", 1, "float"),
    ("occlusion", 1, "float"),
)
APPEARANCE_DEFAULTS = {"roughness": 0.8, "metallic": 0.0, "displacement": 0.0, "occlusion": 1.0}


def appearance_offsets() -> dict[str, int]:
    """Float offset of every appearance output in the ``look`` array."""
    offsets, at = {}, 0
    for name, count, _ in APPEARANCE_OUTPUTS:
        offsets[name] = at
        at += count
    return offsets


APPEARANCE_WIDTH = sum(count for _, count, _ in APPEARANCE_OUTPUTS)

#: Appearance kernels turn a point's (interpolated) surfel row into its look.
#: ``textures`` holds 3 floats (r, g, b in [0, 1]) per texture of the effect
#: (``Effect.textures`` order), sampled by the renderer at ``ctx.uv``, then 3
#: more: the scene's own base colour there (``base_color()``, SPEC §8a).
#: ``look`` (``APPEARANCE_WIDTH`` floats) holds the outputs' starting values
#: when the kernel is called (the scene's material there) and the kernel
#: assigns them in place.  Return value as for the other kernels.
APPEARANCE_SIGNATURE = (
    "int32_t",
    (("const float*", "surf"), ("const float*", "textures"), ("float*", "look"),
     ("const GammaContext*", "ctx")),
)

#: random(): the key in the context, mixed with the call site's number
#: (0, 1, ... in source order within the kernel), gives 24 random bits.
RANDOM_GOLDEN = 0x9E3779B97F4A7C15
RANDOM_MIX = (0xBF58476D1CE4E5B9, 0x94D049BB133111EB)  # splitmix64 finaliser


def mix64(z: int) -> int:
    """splitmix64's finaliser; the C++ runtime and the generated code use the same."""
    m = 0xFFFFFFFFFFFFFFFF
    z = (z + RANDOM_GOLDEN) & m
    z = ((z ^ (z >> 30)) * RANDOM_MIX[0]) & m
    z = ((z ^ (z >> 27)) * RANDOM_MIX[1]) & m
    return z ^ (z >> 31)


def random_value(key: int, site: int) -> float:
    """The value of the ``site``-th random() call for a context key, in [0, 1)."""
    return (mix64(key ^ (site * RANDOM_GOLDEN & 0xFFFFFFFFFFFFFFFF)) >> 40) * 2.0 ** -24


#: Source kinds the runtime emits from (``Config.add_source``'s first argument).
SOURCE_KINDS = ("point", "spot", "rect", "disk", "directional", "sphere", "hemisphere", "surface")

#: Counts ``Simulation.trace`` reports per iteration, in the order summary.json lists them.
STATISTICS = ("emitted", "settled", "escaped", "missed", "capped", "interactions", "rays",
              "bounces", "flow_steps", "drips", "segments", "silent")

#: The books of one conserved property in one iteration (``TraceStats.mass``,
#: gamma/stats.h): removed + emitted + created = deposited + escaped + dropped + in_flight.
MASS_BOOKS = ("removed", "deposited", "escaped", "in_flight", "emitted", "created", "dropped")

#: The binding: every attribute the Python side uses, per object of ``gamma._runtime``.
BINDING = {
    "module": ("ABI_VERSION", "RUNTIME_VERSION", "EMBREE_VERSION", "Mesh", "Config", "Simulation",
               "SurfelSample", "SetupSnapshot", "encode_pngs", "RUNTIME_BUILD", "setup_cache_name",
               "read_mesh_ahead", "FalseColourView", "rasterise_uv", "CancelToken", "Cancelled", "LATTICE_STRIDE"),
    "CancelToken": ("cancel", "cancelled"),
    "FalseColourView": ("width", "height", "surfels", "shade", "values", "picture", "to_bytes", "from_bytes"),
    "SurfelSample": ("ok", "matches", "seconds"),
    "SetupSnapshot": ("load_cached", "matches", "prepared", "taken", "surfels", "make_ahead",
                      "made_ahead"),
    "Mesh": ("load", "from_arrays", "num_vertices", "num_triangles", "degenerate_dropped", "bounds",
             "vertices", "fingerprint", "has_uvs", "triangle_uvs", "part_names", "triangle_labels", "triangles"),
    "Config": ("surfels", "seed", "threads", "max_interactions", "row_width", "surface_rows", "down",
               "triangle_surface", "add_ton_type", "add_source", "set_transport", "set_update",
               "set_appearance", "add_shape_rate", "add_mass_property", "measure_accessibility",
               "measure_curvature", "measure_uv"),
    "Simulation": ("num_surfels", "row_width", "surfel_positions", "surfel_normals", "surfel_surfaces",
                   "rows", "trace", "update", "render", "set_textures", "bake_points", "bake_texels",
                   "render_appearance", "shape", "geometry", "mesh_arrays", "triangle_surfaces",
                   "set_rows", "num_chunks", "trace_chunks", "merge_chunks",
                   "set_shading", "corner_normals", "set_base_colours", "reconfigure", "prepare_points",
                   "num_prepared_points", "bake_prepared", "surfel_measures", "from_snapshot",
                   "setup_snapshot", "setup_snapshot_bytes", "setup_made_ahead", "false_colour_view",
                   "write_setup_snapshot"),
}


def check_runtime(rt) -> list[str]:
    """What the runtime module ``rt`` lacks or has different from this file
    (empty: it matches)."""
    problems = []
    version = getattr(rt, "ABI_VERSION", None)
    if version != ABI_VERSION:
        problems.append(f"runtime ABI {version} does not match compiler ABI {ABI_VERSION}")
    for owner, names in BINDING.items():
        obj = rt if owner == "module" else getattr(rt, owner, None)
        if obj is None:
            continue          # reported as a missing module attribute
        missing = [n for n in names if not hasattr(obj, n)]
        if missing:
            where = "the module" if owner == "module" else owner
            problems.append(f"{where} lacks {', '.join(missing)}")
    return problems


def c_header() -> str:
    """The C header the runtime includes (generated at build time)."""
    lines = [
        "/* Generated from compiler/gamma/abi.py by CMake. Do not edit. */",
        "#pragma once",
        "#include <stdint.h>",
        "#include <stddef.h>",
        f"#define GAMMA_ABI_VERSION {ABI_VERSION}",
        f"#define GAMMA_ROW_HEADER {ROW_HEADER}",
    ]
    for i, slot in enumerate(REFLECTANCE_SLOTS):
        lines.append(f"#define GAMMA_ROW_REFLECTANCE_{slot.upper()} {i}")
    for name, value in EVENTS.items():
        lines.append(f"#define GAMMA_EVENT_{name.upper()} {value}")
    lines.append(f"#define GAMMA_EVENT_COUNT {len(EVENTS)}")
    for name, offset in appearance_offsets().items():
        lines.append(f"#define GAMMA_LOOK_{name.upper()} {offset}")
    lines.append(f"#define GAMMA_LOOK_WIDTH {APPEARANCE_WIDTH}")
    for name, value in APPEARANCE_DEFAULTS.items():
        lines.append(f"#define GAMMA_LOOK_DEFAULT_{name.upper()} {value!r}f")
    # X-macros of the trace counters and the mass books: the C++ struct fields,
    # their sums and their conversions to and from Python follow from them
    lines.append("#define GAMMA_TRACE_COUNTERS(X) " + " ".join(f"X({n})" for n in STATISTICS))
    lines.append("#define GAMMA_MASS_BOOKS(X) " + " ".join(f"X({n})" for n in MASS_BOOKS))
    lines.append("typedef struct GammaContext {")
    for name, ctype, count in CONTEXT_FIELDS:
        lines.append(f"    {ctype} {name}{f'[{count}]' if count > 1 else ''};")
    lines.append("} GammaContext;")
    lines.append(f"#define GAMMA_RANDOM_GOLDEN {RANDOM_GOLDEN:#x}ULL")
    lines.append(f"#define GAMMA_RANDOM_MIX0 {RANDOM_MIX[0]:#x}ULL")
    lines.append(f"#define GAMMA_RANDOM_MIX1 {RANDOM_MIX[1]:#x}ULL")
    for name, off in context_offsets().items():
        lines.append(f"static_assert(offsetof(GammaContext, {name}) == {off}, \"GammaContext layout\");")
    lines.append(f"static_assert(sizeof(GammaContext) == {CONTEXT_SIZE}, \"GammaContext size\");")
    for tname, (ret, params) in (("GammaTransportKernel", TRANSPORT_SIGNATURE),
                                 ("GammaUpdateKernel", UPDATE_SIGNATURE),
                                 ("GammaAppearanceKernel", APPEARANCE_SIGNATURE)):
        args = ", ".join(f"{t} {n}" for t, n in params)
        lines.append(f"typedef {ret} (*{tname})({args});")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--header":
        # Written only when it changes: an edit of this file that leaves the header as it
        # was (a BINDING name, a comment) then rebuilds nothing (Ninja's restat).
        try:
            with open(sys.argv[2], encoding="utf-8") as old:
                unchanged = old.read() == c_header()
        except OSError:
            unchanged = False
        if not unchanged:
            with open(sys.argv[2], "w", encoding="utf-8") as out:
                out.write(c_header())
    else:
        sys.stdout.write(c_header())
