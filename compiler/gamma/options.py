"""The options of a run, declared once.

Each row of ``OPTIONS`` is one option: its name (the ``RunOptions`` field and
the ``gamma.run`` keyword), its command-line flag, default, value parser,
help, limits, whether ``gammac sweep --grid`` may sweep it and whether
``launch.py`` reads it ahead.  From the table come ``gammac``'s argparse
options (``cli.add_options``), ``RunOptions`` (a dataclass), ``gamma.run``'s
keywords, the limits the runner checks (``LIMITS``, ``check_limits``), the
early read (``EARLY``), the grid names of a sweep (``SWEEPABLE``) and the
``gammac run`` command line of an options object (``command_line``).

This module imports nothing at start-up (``gammac --help`` and the early
read use it): ``RunOptions`` is made on first use, with ``dataclasses``.
"""

from __future__ import annotations

import math

#: Direction from the scene's centre toward the camera when --view is not given.
DEFAULT_VIEW = (-0.6, 0.35, 1.0)   # front-left-above for a +z-facing, y-up model

#: The default of an option that must be given.
REQUIRED = object()


class OptionError(ValueError):
    """A command-line value an option cannot take; the message says why."""


# ---- value parsers (command-line text -> value) -------------------------------------------

def ascii_float(text: str) -> float:
    """A number written in ASCII: Python's float() also reads other scripts'
    digits ('٣'), which no user means on a command line."""
    if not text.isascii():
        raise ValueError(text)
    return float(text)


def whole(text: str) -> int:
    try:
        if not text.isascii():
            raise ValueError(text)
        value = int(text)
    except ValueError:
        raise OptionError(f"'{text}' is not a whole number") from None
    if value < 0:
        raise OptionError(f"'{text}' is negative")
    return value


def number(text: str) -> float:
    try:
        return ascii_float(text)
    except ValueError:
        raise OptionError(f"'{text}' is not a number") from None


def _three(text: str, what: str, nonzero: bool) -> tuple[float, float, float]:
    try:
        values = tuple(ascii_float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values) or (nonzero and not any(values)):
        raise OptionError(f"'{text}' is not a {what} X,Y,Z")
    return values


def direction(text: str) -> tuple[float, float, float]:
    return _three(text, "direction", nonzero=True)


def point(text: str) -> tuple[float, float, float]:
    return _three(text, "point", nonzero=False)


def angle(text: str) -> float:
    value = number(text)
    if not 0 <= value <= 180:
        raise OptionError(f"{text!r} is not an angle from 0 to 180 degrees")
    return value


def bake_size(text: str) -> int:
    """A texture side in pixels, within the --bake-size row's limits."""
    value = whole(text)
    low, high = LIMITS["--bake-size"]
    if not low <= value <= high:
        raise OptionError(f"'{text}' is not a texture size from {low} to {high:,} pixels")
    return value


def texel_density(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise OptionError(f"'{text}' is not a number") from None
    if not (value > 0 and value < 1e9):
        raise OptionError(f"'{text}' is not a positive number of texels per scene unit")
    return value


# ---- the table ------------------------------------------------------------------------------

class Option:
    """One run option.  ``group`` says which ``gammac`` commands take it
    (``cli.add_options``); ``flag`` None: only the Python API has it.
    ``action``: argparse's (``append``, ``store_true``, ``store_false``);
    ``also``: fields the command line sets to the same value; ``exclusive``:
    options of one name are mutually exclusive; ``saved``: ``gammac render``
    of a saved run defaults it to the run's value."""

    __slots__ = ("name", "flag", "default", "help", "parse", "group", "limits", "sweep", "early",
                 "metavar", "choices", "action", "const", "also", "exclusive", "saved")

    def __init__(self, name, flag, default, help="", parse=None, *, group, limits=None, sweep=False,
                 early=False, metavar=None, choices=None, action=None, const=None, also=(),
                 exclusive=None, saved=False):
        self.name, self.flag, self.default, self.help, self.parse = name, flag, default, help, parse
        self.group, self.limits, self.sweep, self.early = group, limits, sweep, early
        self.metavar, self.choices, self.action, self.const = metavar, choices, action, const
        self.also, self.exclusive, self.saved = also, exclusive, saved

    def __repr__(self) -> str:
        return f"Option({self.name!r}, {self.flag!r})"


_VIEW = ",".join(f"{c:g}" for c in DEFAULT_VIEW)

OPTIONS: tuple[Option, ...] = (
    # what a simulation needs: gammac run, sweep and watch
    Option("threads", "--threads", 0, "worker threads (0: all cores)", whole, group="simulation",
           limits=(0, 256), early=True),
    Option("scene", "--scene", REQUIRED, "OBJ, PLY, glTF (.gltf, .glb) mesh, or a JSON scene file",
           group="simulation", early=True),
    Option("assign", "--assign", [], "bind the parts whose object, group, material, node or file name "
           "matches PATTERN (default *) to SURFACE; repeatable, first match wins", group="simulation",
           action="append", metavar="[PATTERN=]SURFACE"),
    Option("down", "--down", None, "gravity direction (default: 0,-1,0)", direction, group="simulation",
           metavar="X,Y,Z"),
    # the camera: also gammac render
    Option("view", "--view", None, f"direction from the scene's centre toward the camera (default: {_VIEW})",
           direction, group="camera", metavar="X,Y,Z"),
    Option("eye", "--eye", None, "camera position in scene units (overrides --view)", point,
           group="camera", metavar="X,Y,Z"),
    Option("look_at", "--look-at", None, "point the camera looks at (default: the scene's centre)", point,
           group="camera", metavar="X,Y,Z"),
    Option("up", "--up", None, "the camera's up direction (default: against gravity)", direction,
           group="camera", metavar="X,Y,Z"),
    Option("fov", "--fov", 30.0, "vertical field of view in degrees", number, group="camera"),
    Option("iterations", "--iterations", 10, "iterations to simulate", whole, group="simulation",
           limits=(1, 1_000_000), sweep=True),
    Option("surfels", "--surfels", 100_000, "surfels on the scene", whole, group="simulation",
           limits=(1, 20_000_000), sweep=True, early=True),
    Option("tons", "--tons", None, "gamma-tons per iteration (overrides the sources' counts, split in "
           "proportion)", whole, group="simulation", limits=(0, 10**12), sweep=True),
    Option("seed", "--seed", 1, "random seed (same seed, same maps)", whole, group="simulation",
           limits=(0, 2**63 - 1), sweep=True, early=True),
    Option("max_interactions", "--max-interactions", 100, "bound on interactions per gamma-ton", whole,
           group="simulation", limits=(1, 10**6), sweep=True),
    # where a run writes: gammac run and sweep
    Option("out", "--out", REQUIRED, "output folder", group="output"),
    # pictures: also gammac render
    Option("show", "--show", None, "property rendered in false colour (default: the surface's first)",
           group="picture"),
    Option("width", "--size", 512, "render width and height in pixels", whole, group="picture",
           limits=(16, 8192), metavar="SIZE", also=("height",)),
    Option("height", None, 512, "render height in pixels (the command line's --size sets both)",
           group="picture"),
    Option("samples", "--samples", 4, "camera rays per pixel of appearance renders (anti-aliasing)", whole,
           group="picture", limits=(1, 64)),
    Option("ao_samples", "--ao", 8, "ambient-occlusion rays per pixel sample (0: none)", whole,
           group="picture", limits=(0, 256)),
    Option("shading", "--shading", "smooth", "smooth: normals interpolated across edges gentler than "
           "--crease; flat: every triangle's own normal", group="picture", choices=("smooth", "flat"),
           saved=True),
    Option("crease", "--crease", 60.0, "edges whose faces meet at more than this angle stay sharp in "
           "smooth shading", angle, group="picture", metavar="DEG", saved=True),
    Option("export", "--export", False, "write DIR/export/SCENE_NNNN.glb and per object a texture set "
           "(DIR/export/OBJECT/) of the last iteration (--export all: of every iteration) once the run is "
           "complete", group="export", const="last", choices=("last", "all")),
    # texture sets: also gammac export
    Option("bake_size", "--bake-size", 1024, "baked texture width and height in pixels", bake_size,
           group="bake", limits=(8, 16384), exclusive="size"),   # export.MAX_BAKE_SIZE
    Option("texel_density", "--texel-density", None, "texels per scene unit instead of --bake-size: each "
           "object's textures get the size that gives it", texel_density, group="bake", metavar="TEXELS",
           exclusive="size"),
    Option("float_maps", "--float-maps", False, "the height and every property as 32-bit float OpenEXR "
           "images instead of 16-bit PNGs", group="bake", action="store_true"),
    Option("preset", "--preset", "gltf", "the texture set's packing: gltf (ORM, OpenGL normal map), unreal "
           "(ORM, DirectX normal map) or unity (HDRP mask map: metallic, occlusion, detail, smoothness)",
           group="bake", choices=("gltf", "unreal", "unity")),
    Option("progress", "--quiet", True, "no progress bar", group="progress", action="store_false"),
    # gammac run alone
    Option("ray", "--ray", False, "trace each iteration's gamma-tons on Ray workers on this machine "
           "(same result; optional extra: pip install '.[ray]')", group="run", action="store_true",
           exclusive="where"),
    Option("ray_address", "--ray-address", None, "trace each iteration's gamma-tons on the Ray cluster at "
           "ADDRESS", group="run", metavar="ADDRESS", exclusive="where"),
    Option("resume", "--resume", False, "continue the run in --out from its last complete iteration (same "
           "command; --iterations may grow)", group="run", action="store_true"),
    Option("init", "--init", None, "start from the final surfel state of the run in DIR (same scene, "
           "--surfels and --seed): properties of the same surface and name start at its values, the rest "
           "at this effect's initial values", group="run",
           metavar="DIR"),
    Option("started", None, None, "time.perf_counter() when gammac started (the start-up time "
           "summary.json reports)", group="api"),
)

BY_NAME = {o.name: o for o in OPTIONS}
#: (low, high) of each option that has limits, by flag (SPEC §16.1).
LIMITS = {o.flag: o.limits for o in OPTIONS if o.limits}
#: Options ``gammac sweep --grid NAME=...`` may sweep (whole numbers), name -> flag.
SWEEPABLE = {o.name: o.flag for o in OPTIONS if o.sweep}
#: Options launch.py reads ahead of argparse, flag -> default (None: required).
EARLY = {o.flag: (None if o.default is REQUIRED else o.default) for o in OPTIONS if o.early}
#: Options whose value is a vector and may start with a minus sign.
VECTOR_FLAGS = tuple(o.flag for o in OPTIONS if o.parse in (direction, point))


def limit_problem(opts) -> str | None:
    """The first option of ``opts`` outside its limits, as a message."""
    for o in OPTIONS:
        if o.limits is None:
            continue
        low, high = o.limits
        for name in (o.name, *o.also):
            value = getattr(opts, name)
            value = 0 if value is None else value
            if not low <= value <= high:
                return f"{o.flag} must be between {low} and {high:,}, not {value}"
    return None


def from_args(args, **given):
    """The ``RunOptions`` of parsed command-line ``args`` (the options its
    command has), with ``given`` fields set as well."""
    values = {}
    for o in OPTIONS:
        if o.flag is not None and hasattr(args, o.name):
            values[o.name] = getattr(args, o.name)
            for other in o.also:
                values[other] = values[o.name]
    values.update(given)
    return run_options_class()(**values)


def _text(value) -> str:
    if isinstance(value, (tuple, list)):
        return ",".join(map(_text, value))
    return repr(value) if isinstance(value, float) else str(value)


def command_line(opts, skip=("scene", "out"), keep=()) -> list[str]:
    """The options of ``opts`` that differ from their defaults (and those
    named in ``keep``) as ``gammac run`` arguments (numbers in repr form, so
    they parse back exactly)."""
    out = []
    for o in OPTIONS:
        if o.flag is None or o.name in skip:
            continue
        value = getattr(opts, o.name)
        if value == o.default and o.name not in keep:
            continue
        if o.action in ("store_true", "store_false"):
            out.append(o.flag)
        elif o.action == "append":
            for item in value:
                out += [o.flag, _text(item)]
        else:
            out += [o.flag, _text(value)]
    return out


def keyword_help() -> str:
    """One line per keyword option of ``gamma.run`` (its docstring's list)."""
    lines = []
    for o in OPTIONS:
        if o.name in ("scene", "out", "progress"):
            continue
        default = "required" if o.default is REQUIRED else repr(o.default)
        lines.append(f"    {o.name} = {default}: {o.help}")
    return "\n".join(lines)


def _make_run_options():
    from dataclasses import field, make_dataclass

    from .records import Record

    def declared(o: Option):
        if o.default is REQUIRED:
            return field(metadata={"option": o})
        if isinstance(o.default, list):
            return field(default_factory=list, metadata={"option": o})
        return field(default=o.default, metadata={"option": o})

    cls = make_dataclass("RunOptions", [(o.name, object, declared(o)) for o in OPTIONS], bases=(Record,),
                         eq=False, repr=False, kw_only=True)
    cls.__module__ = __name__
    cls.__doc__ = "The options of a run: one field per row of ``gamma.options.OPTIONS``."
    return cls


def run_options_class():
    """``RunOptions``, made on first use: importing dataclasses would slow
    ``gammac --help`` and the early read (bench/RESULTS.md)."""
    cls = globals().get("RunOptions")
    if cls is None:
        globals()["RunOptions"] = cls = _make_run_options()
    return cls


def __getattr__(name: str):
    if name == "RunOptions":
        return run_options_class()
    raise AttributeError(f"module 'gamma.options' has no attribute '{name}'")
