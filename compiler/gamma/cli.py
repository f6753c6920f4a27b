"""The ``gammac`` command: ``check``, ``emit``, ``fmt``, ``recipes`` and ``run``.

Only argument parsing and reporting live here: the front end checks, the
back ends compile, the driver runs; this module turns their errors into
diagnostics or one line and an exit status.

Exit status (SPEC §16.2): 0 success, 1 an error in the user's input (effect
file, mesh), 2 a usage error, 130 interrupted by SIGINT (Ctrl-C), 143 stopped
by SIGTERM.  A user mistake is reported as diagnostics or a one-line
``gammac: error: ...``, never as a Python traceback.
"""

from __future__ import annotations

import argparse
import sys
import time

# Start-up time reported in summary.json runs from here, or from the
# ``gammac`` command's first line (launch.py), which came before (the
# interpreter's own start, before the first import of gamma, is not included).
_STARTED = getattr(sys.modules.get("gamma.launch"), "STARTED", None) or time.perf_counter()

# The front end (and what it imports) is imported once the command line is
# parsed: ``gammac run`` starts reading its mesh before that (prefetch.py),
# before even this module is imported when it can (launch.py).

EXIT_OK, EXIT_INPUT, EXIT_USAGE = 0, 1, 2


def _float(text: str) -> float:
    """A number written in ASCII: Python's float() also reads other scripts'
    digits ('٣'), which no user means on a command line."""
    if not text.isascii():
        raise ValueError(text)
    return float(text)


def _bounded_int(text: str) -> int:
    try:
        if not text.isascii():
            raise ValueError(text)
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"'{text}' is negative")
    return value


def _bake_size(text: str) -> int:
    """A texture side in pixels, within budget.LIMITS["--bake-size"]."""
    from .driver.budget import LIMITS

    value = _bounded_int(text)
    low, high = LIMITS["--bake-size"]
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"'{text}' is not a texture size from {low} to {high:,} pixels")
    return value


def _texel_density(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not (value > 0 and value < 1e9):
        raise argparse.ArgumentTypeError(f"'{text}' is not a positive number of texels per scene unit")
    return value


def _vector3(text: str) -> tuple[float, float, float]:
    import math

    try:
        values = tuple(_float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values) or not any(values):
        raise argparse.ArgumentTypeError(f"'{text}' is not a direction X,Y,Z")
    return values


def _param(text: str) -> tuple[str, float]:
    import math

    name, sep, value = text.partition("=")
    try:
        number = _float(value)
    except ValueError:
        number = math.nan
    parts = name.split(".")
    if not sep or len(parts) > 2 or not all(x.isidentifier() for x in parts) or not math.isfinite(number):
        raise argparse.ArgumentTypeError(f"'{text}' is not NAME=NUMBER or RECIPE.NAME=NUMBER")
    return name, number


def _fov(text: str) -> float:
    try:
        return _float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None


def _point3(text: str) -> tuple[float, float, float]:
    import math

    try:
        values = tuple(_float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"'{text}' is not a point X,Y,Z")
    return values


class _HelpFormatter(argparse.HelpFormatter):
    """Shows each option's default in --help (where it has a meaningful one)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("%(default)" in text or not action.option_strings or default in (None, False, [], "")
                or default is argparse.SUPPRESS):
            return text
        return f"{text} (default: %(default)s)" if text else "(default: %(default)s)"


#: Options whose value is a vector and may start with a minus sign.
VECTOR_OPTIONS = ("--view", "--eye", "--down", "--look-at", "--up")


def _join_negative_vectors(argv: list[str]) -> list[str]:
    """``--view -0.6,0.2,1`` as ``--view=-0.6,0.2,1``: argparse would otherwise
    take the value for an option (it knows only plain negative numbers)."""
    import re

    out, i = [], 0
    while i < len(argv):
        arg = argv[i]
        if (arg in VECTOR_OPTIONS and i + 1 < len(argv)
                and re.fullmatch(r"-[0-9.][0-9.eE+-]*(,[^,]*)*", argv[i + 1])):
            out.append(f"{arg}={argv[i + 1]}")
            i += 2
            continue
        out.append(arg)
        i += 1
    return out


def _version() -> str:
    from . import __version__

    return f"gammac {__version__}"


class _VersionAction(argparse.Action):
    """--version, looked up only when asked for (the package metadata costs start-up time)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0,
                         help=help or "show the version and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version())
        parser.exit()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gammac", description="Compile and run .gamma weathering effects.",
                                epilog="Exit status: 0 success, 1 an error in the input (effect, mesh, "
                                       "files), 2 a usage error (options, --param, --assign), 130 interrupted.")
    p.add_argument("--version", action=_VersionAction)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    sub_parser = sub.add_parser

    def add_parser(*args, **kwargs):
        return sub_parser(*args, formatter_class=_HelpFormatter, **kwargs)

    sub.add_parser = add_parser
    c = sub.add_parser("check", help="parse and check an effect; report every error")
    c.add_argument("file")
    c.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                   help="override a parameter of the effect")
    e = sub.add_parser("emit", help="print the compiled form of an effect")
    e.add_argument("file")
    e.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                   help="override a parameter of the effect")
    what = e.add_mutually_exclusive_group(required=True)
    what.add_argument("--ast", action="store_const", dest="what", const="ast", help="the syntax tree")
    what.add_argument("--effect", action="store_const", dest="what", const="effect",
                      help="the checked effect: declarations and typed, resolved rule bodies (the IR)")
    what.add_argument("--ir", action="store_const", dest="what", const="ir", help="LLVM IR as generated")
    what.add_argument("--ir-opt", action="store_const", dest="what", const="ir-opt", help="LLVM IR after optimisation")
    what.add_argument("--asm", action="store_const", dest="what", const="asm", help="native assembly")
    f = sub.add_parser("fmt", help="print an effect in canonical layout (comments kept)")
    f.add_argument("file")
    how = f.add_mutually_exclusive_group()
    how.add_argument("--write", "-w", action="store_true", help="rewrite the file in place")
    how.add_argument("--check", action="store_true", help="exit 1 if the file is not formatted")
    rc = sub.add_parser("recipes", help="list the standard library's recipes, their parameters and defaults")
    rc.add_argument("--verbose", "-v", action="store_true", help="print each recipe's whole description")
    rc.add_argument("--json", action="store_true",
                    help="the same as JSON (name, path, summary, doc, params, tons, surfaces, sources), for tools")
    r = sub.add_parser("run", help="simulate an effect on a mesh and write maps, renders and a summary")
    r.add_argument("file")
    _add_run_options(r)
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    where = r.add_mutually_exclusive_group()
    where.add_argument("--ray", action="store_true",
                       help="trace each iteration's gamma-tons on Ray workers on this machine "
                            "(same result; optional extra: pip install '.[ray]')")
    where.add_argument("--ray-address", metavar="ADDRESS",
                       help="trace each iteration's gamma-tons on the Ray cluster at ADDRESS")
    r.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its last complete iteration (same command; "
                        "--iterations may grow)")
    r.add_argument("--init", metavar="DIR",
                   help="start from the final surfel state of the run in DIR (same scene, --surfels and "
                        "--seed): properties of the same surface and name start at its values, the rest "
                        "at this effect's initial values")
    s = sub.add_parser("sweep", help="run every combination of a parameter grid (a Ray task each)",
                       description="Run the effect once per combination of the --grid values (each a "
                                   "'gammac run' with the other options, as a Ray task) into "
                                   "OUT/cells/NAME; OUT/index.json lists the cells, "
                                   "OUT/contact-sheet.png shows their final renders. Finished cells "
                                   "are skipped on a rerun. Needs the optional extra: pip install '.[ray]'. "
                                   "--threads is per cell (default 1: cells run side by side).")
    s.add_argument("file")
    s.add_argument("--grid", action="append", required=True, metavar="NAME=VALUES",
                   help="a parameter of the effect or one of seed, iterations, surfels, tons, "
                        "max_interactions, with values V1,V2,... or a range A..B (repeatable)")
    s.add_argument("--ray-address", metavar="ADDRESS",
                   help="an existing Ray cluster (default: a local Ray on this machine)")
    s.add_argument("--quiet", action="store_true", help="no progress")
    _add_run_options(s)
    s.set_defaults(threads=1)
    v = sub.add_parser("render", help="a picture of a saved run's iteration, without simulating")
    v.add_argument("dir", help="the --out folder of a gammac run")
    v.add_argument("--iteration", type=_bounded_int, help="iteration to show (default: the last saved)")
    _camera_options(v)
    _picture_options(v, saved=True)
    v.add_argument("--output", "-o", metavar="FILE",
                   help="PNG to write (default: DIR/renders/view_iter_NNNN[_PROPERTY].png)")
    v.add_argument("--threads", type=_bounded_int, default=0, help="worker threads (0: all cores)")
    x = sub.add_parser("export", help="glTF/OBJ + baked textures of a saved run, without simulating")
    x.add_argument("dir", help="the --out folder of a gammac run")
    which = x.add_mutually_exclusive_group()
    which.add_argument("--iteration", type=_bounded_int, help="iteration to export (default: the last saved)")
    which.add_argument("--all", action="store_true", help="every saved iteration")
    _bake_options(x)
    x.add_argument("--format", choices=("gltf", "usd"), default="gltf",
                   help="usd: also an OpenUSD stage DIR/export/SCENE.usdc, the iterations as time samples")
    x.add_argument("--threads", type=_bounded_int, default=0, help="worker threads (0: all cores)")
    x.add_argument("--quiet", action="store_true", help="no progress bar")
    w = sub.add_parser("watch", help="run an effect again on every save and show it in the browser")
    w.add_argument("file")
    _simulation_options(w)
    w.add_argument("--port", type=_bounded_int, default=8000, help="port on 127.0.0.1 (0: any free one)")
    w.add_argument("--preview", type=float, default=0.25,
                   help="fraction of the gamma-tons of the quick first pass after a save (1: none)")
    return p


def _add_run_options(r: argparse.ArgumentParser) -> None:
    """The options of ``gammac run`` that ``gammac sweep`` passes on to each cell."""
    _simulation_options(r)
    r.add_argument("--out", required=True, help="output folder")
    _picture_options(r)
    r.add_argument("--export", nargs="?", const="last", choices=("last", "all"),
                   help="write DIR/export/SCENE_NNNN.glb and per object a texture set (DIR/export/OBJECT/) "
                        "of the last iteration (--export all: of every iteration) once the run is complete")
    _bake_options(r)


def _bake_options(r: argparse.ArgumentParser) -> None:
    size = r.add_mutually_exclusive_group()
    size.add_argument("--bake-size", type=_bake_size, default=1024,
                      help="baked texture width and height in pixels (default 1024)")
    size.add_argument("--texel-density", type=_texel_density, metavar="TEXELS",
                      help="texels per scene unit instead of --bake-size: each object's textures get "
                           "the size that gives it")
    r.add_argument("--float-maps", action="store_true",
                   help="the height and every property as 32-bit float OpenEXR images instead of 16-bit PNGs")
    r.add_argument("--preset", choices=("gltf", "unreal", "unity"), default="gltf",
                   help="the texture set's packing: gltf (ORM, OpenGL normal map), unreal (ORM, DirectX "
                        "normal map) or unity (HDRP mask map: metallic, occlusion, detail, smoothness)")


def _simulation_options(r: argparse.ArgumentParser) -> None:
    """What a simulation needs: ``run``, ``sweep`` and ``watch``."""
    r.add_argument("--threads", type=_bounded_int, default=0, help="worker threads (0: all cores)")
    r.add_argument("--param", type=_param, action="append", default=[], metavar="[RECIPE.]NAME=VALUE",
                   help="override a parameter of the effect, or of an imported recipe "
                        "(RECIPE = its file name without .gamma); repeatable")
    r.add_argument("--scene", required=True, help="OBJ, PLY, glTF (.gltf, .glb) mesh, or a JSON scene file")
    r.add_argument("--assign", action="append", default=[], metavar="[PATTERN=]SURFACE",
                   help="bind the parts whose object, group, material, node or file name matches "
                        "PATTERN (default *) to SURFACE; repeatable, first match wins")
    r.add_argument("--down", type=_vector3, metavar="X,Y,Z", help="gravity direction (default: 0,-1,0)")
    _camera_options(r)
    r.add_argument("--iterations", type=_bounded_int, default=10, help="iterations to simulate")
    r.add_argument("--surfels", type=_bounded_int, default=100_000, help="surfels on the scene")
    r.add_argument("--tons", type=_bounded_int,
                   help="gamma-tons per iteration (overrides the sources' counts, split in proportion)")
    r.add_argument("--seed", type=_bounded_int, default=1, help="random seed (same seed, same maps)")
    r.add_argument("--max-interactions", type=_bounded_int, default=100,
                   help="bound on interactions per gamma-ton")


def _picture_options(r: argparse.ArgumentParser, saved: bool = False) -> None:
    """Picture options; for a saved run (``saved``), shading defaults to the run's."""
    r.add_argument("--show", help="property rendered in false colour (default: the surface's first)")
    r.add_argument("--size", type=_bounded_int, default=512, help="render width and height in pixels")
    r.add_argument("--samples", type=_bounded_int, default=4,
                   help="camera rays per pixel of appearance renders (anti-aliasing)")
    r.add_argument("--ao", type=_bounded_int, default=8, dest="ao_samples",
                   help="ambient-occlusion rays per pixel sample (0: none)")
    r.add_argument("--shading", choices=("smooth", "flat"), default=None if saved else "smooth",
                   help="smooth: normals interpolated across edges gentler than --crease; "
                        "flat: every triangle's own normal" + (" (default: the run's)" if saved else ""))
    r.add_argument("--crease", type=_crease, default=None if saved else 60.0, metavar="DEG",
                   help="edges whose faces meet at more than this angle stay sharp in smooth shading"
                        + (" (default: the run's)" if saved else ""))


def _crease(text: str) -> float:
    try:
        value = _float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not 0 <= value <= 180:
        raise argparse.ArgumentTypeError(f"{text!r} is not an angle from 0 to 180 degrees")
    return value


def _camera_options(p: argparse.ArgumentParser) -> None:
    from .driver.camera import DEFAULT_VIEW

    p.add_argument("--view", type=_vector3, metavar="X,Y,Z",
                   help="direction from the scene's centre toward the camera "
                        f"(default: {','.join(f'{c:g}' for c in DEFAULT_VIEW)})")
    p.add_argument("--eye", type=_point3, metavar="X,Y,Z",
                   help="camera position in scene units (overrides --view)")
    p.add_argument("--look-at", type=_point3, metavar="X,Y,Z", dest="look_at",
                   help="point the camera looks at (default: the scene's centre)")
    p.add_argument("--up", type=_vector3, metavar="X,Y,Z",
                   help="the camera's up direction (default: against gravity)")
    p.add_argument("--fov", type=_fov, default=30.0, help="vertical field of view in degrees")


def _read(path: str) -> str:
    """The text of a user's file, or a one-line error."""
    from pathlib import Path

    from .files import file_problem

    problem = file_problem(Path(path))
    if problem:
        raise _Fail(f"cannot read '{path}': {problem}")
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except FileNotFoundError:
        raise _Fail(f"cannot read '{path}': file not found") from None
    except UnicodeDecodeError:
        raise _Fail(f"cannot read '{path}': it is not UTF-8 text") from None
    except OSError as err:
        raise _Fail(f"cannot read '{path}': {err.strerror or err}") from None


def _load(path: str, params=(), cached: bool = False):
    """The checked effect of ``path``; ``cached``: through the compiled-effect
    cache (backends/effect_cache.py), which also keeps its kernels."""
    overrides = {}
    for name, value in params:
        if name in overrides:
            raise _Fail(f"--param {name} is given twice")
        overrides[name] = value
    source = _read(path)
    if cached:
        from .backends import effect_cache

        effect = effect_cache.check(path, source, overrides)
    else:
        from .frontend.checker import check
        from .frontend.parser import parse

        effect = check(parse(source, path), overrides)
    if effect.warnings:
        from .frontend.diagnostics import render

        print(render(effect.warnings, effect.path, effect.source), file=sys.stderr)
    return effect


class _Fail(Exception):
    pass


def _run_options(args):
    """RunOptions from the parsed options of ``run`` or ``watch``."""
    from .driver.runner import RunOptions

    size = getattr(args, "size", 512)
    return RunOptions(scene=args.scene, out=getattr(args, "out", ""), assign=args.assign, down=args.down,
                      view=args.view, eye=args.eye, look_at=args.look_at, up=args.up, fov=args.fov,
                      iterations=args.iterations, surfels=args.surfels, tons=args.tons,
                      seed=args.seed, threads=args.threads, max_interactions=args.max_interactions,
                      show=getattr(args, "show", None), width=size, height=size,
                      progress=not getattr(args, "quiet", False),
                      samples=getattr(args, "samples", 4), ao_samples=getattr(args, "ao_samples", 8),
                      export=getattr(args, "export", None) or False, bake_size=getattr(args, "bake_size", 1024),
                      texel_density=getattr(args, "texel_density", None), preset=getattr(args, "preset", "gltf"),
                      float_maps=getattr(args, "float_maps", False),
                      resume=getattr(args, "resume", False), init=getattr(args, "init", None),
                      started=_STARTED,
                      ray=getattr(args, "ray", False), ray_address=getattr(args, "ray_address", None),
                      shading=getattr(args, "shading", "smooth"), crease=getattr(args, "crease", 60.0))


class _PipeTolerant:
    """A text stream that stops writing, without an error, once its reader
    has gone (``gammac run ... | head``): the run finishes its work."""

    def __init__(self, stream):
        self._stream = stream
        self.closed_pipe = False

    def _gone(self) -> None:
        import os

        self.closed_pipe = True
        try:   # the interpreter's own flush at exit must not fail either
            os.dup2(os.open(os.devnull, os.O_WRONLY), self._stream.fileno())
        except (OSError, ValueError):
            pass

    def write(self, text: str) -> int:
        if not self.closed_pipe:
            try:
                self._stream.write(text)
            except (BrokenPipeError, ValueError):
                self._gone()
        return len(text)

    def flush(self) -> None:
        if not self.closed_pipe:
            try:
                self._stream.flush()
            except (BrokenPipeError, ValueError):
                self._gone()

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _tolerate_closed_pipes() -> None:
    if not isinstance(sys.stdout, _PipeTolerant):
        sys.stdout = _PipeTolerant(sys.stdout)
    if not isinstance(sys.stderr, _PipeTolerant):
        sys.stderr = _PipeTolerant(sys.stderr)


def _fmt(args) -> int:
    from pathlib import Path

    from .frontend.fmt import format_source
    from .files import atomic_write

    text = _read(args.file)
    formatted = format_source(text, args.file)
    if args.check:
        if formatted != text:
            print(f"{args.file}: not in canonical layout (gammac fmt --write {args.file})", file=sys.stderr)
            return EXIT_INPUT
        return EXIT_OK
    if args.write:
        if formatted != text:
            import os

            path = Path(args.file)
            if not os.access(path, os.W_OK) or not path.stat().st_mode & 0o222:
                raise _Fail(f"cannot write '{args.file}': the file is read-only")
            try:
                atomic_write(path, formatted.encode("utf-8"), mode=path.stat().st_mode & 0o7777)
            except OSError as err:
                raise _Fail(f"cannot write '{args.file}': {err.strerror or err}") from None
        return EXIT_OK
    sys.stdout.write(formatted)
    return EXIT_OK


def _watch(args) -> int:
    """The effect's errors are shown in the page (and on stderr), not fatal."""
    from .driver.runner import RunError, RunInterrupted
    from .frontend.checker import UsageError
    from .viewer.watch import watch

    if not 0.0 < args.preview <= 1.0:
        raise UsageError(f"--preview must be a fraction in (0, 1], not {args.preview:g}")
    overrides = {}
    for name, value in args.param:
        if name in overrides:
            raise UsageError(f"--param {name} is given twice")
        overrides[name] = value
    try:
        return watch(args.file, overrides, _run_options(args), args.port, args.preview)
    except RunError as err:
        raise _Fail(str(err)) from None
    except RunInterrupted as stop:       # ^C while a result is computed (its folder is a scratch one)
        return _leave_interrupted(stop, f"gammac: interrupted by {stop.signal_name}")


def _saved(args) -> int:
    """``render`` and ``export`` of a saved run's maps."""
    from .driver.runner import LIMITS, RunError
    from .driver.saved import export_saved, render_saved
    from .frontend.checker import UsageError

    try:
        if args.command == "render":
            low, high = LIMITS["--size"]
            if not low <= args.size <= high:
                raise UsageError(f"--size must be between {low} and {high:,}, not {args.size}")
            path = render_saved(args.dir, args.iteration, args.show, args.output, args.size, args.samples,
                                args.ao_samples, view=args.view, eye=args.eye, look_at=args.look_at,
                                up=args.up, fov=args.fov, threads=args.threads, shading=args.shading,
                                crease=args.crease)
            print(f"gammac: wrote {path}", file=sys.stderr)
        else:
            iterations = None
            if args.all:
                from pathlib import Path

                iterations = sorted(int(p.stem[5:]) for p in Path(args.dir, "maps").glob("iter_[0-9][0-9][0-9][0-9].ply"))
            elif args.iteration is not None:
                iterations = [args.iteration]
            done = export_saved(args.dir, iterations, args.bake_size, args.threads, progress=not args.quiet,
                                texel_density=args.texel_density, usd=args.format == "usd", preset=args.preset,
                                float_maps=args.float_maps)
            print(f"gammac: exported iteration{'s' if len(done) > 1 else ''} "
                  f"{', '.join(map(str, done))} to {args.dir}/export", file=sys.stderr)
    except RunError as err:
        raise _Fail(str(err)) from None
    return EXIT_OK


_SWEEP_OWN = {"scene", "out", "threads"}   # run options the sweep handles itself


def _run_options_text(args) -> list[str]:
    """The run options of parsed ``args`` that differ from their defaults, as
    ``gammac run`` arguments (numbers in repr form, so they parse back exactly)."""
    def text(value) -> str:
        if isinstance(value, (tuple, list)):
            return ",".join(map(text, value))
        return repr(value) if isinstance(value, float) else str(value)

    probe = argparse.ArgumentParser(add_help=False)
    _add_run_options(probe)
    out = []
    for action in probe._actions:
        value = getattr(args, action.dest)
        if action.dest in _SWEEP_OWN or value == action.default:
            continue
        flag = action.option_strings[0]
        if isinstance(action, argparse._StoreTrueAction):
            out.append(flag)
        elif isinstance(action, argparse._AppendAction):
            for item in value:
                out += [flag, f"{item[0]}={text(item[1])}" if action.dest == "param" else text(item)]
        else:
            out += [flag, text(value)]
    return out


def _sweep(args) -> int:
    """``gammac sweep``: check the effect and every option here, then run the cells."""
    from .driver.cluster import RayUnavailable
    from .driver.sweep import RUN_OPTIONS, SweepError, parse_grid, sweep
    from .frontend.checker import UsageError

    try:
        axes = [parse_grid(g) for g in args.grid]
    except SweepError as err:
        raise _Fail(str(err)) from None
    # The effect must check with the first value of every parameter swept.
    first = [(a.name, float(a.values[0])) for a in axes if a.name not in RUN_OPTIONS]
    swept = {name for name, _ in first}
    try:
        _load(args.file, [p for p in args.param if p[0] not in swept] + first)
    except UsageError as err:      # name the option the user wrote
        text = str(err)
        for name in swept:
            text = text.replace(f"--param {name}:", f"--grid {name}:")
        raise UsageError(text) from None
    try:
        cells = sweep(args.file, args.scene, axes, _run_options_text(args), args.out,
                      address=args.ray_address, threads=args.threads or 1, progress=not args.quiet)
    except (SweepError, RayUnavailable) as err:
        raise _Fail(str(err)) from None
    failed = [c for c in cells if c.status != "ok"]
    print(f"gammac: {len(cells) - len(failed)} of {len(cells)} cells finished; wrote {args.out}/index.json, "
          f"{args.out}/contact-sheet.png, {args.out}/cells/", file=sys.stderr)
    if failed:
        print(f"gammac: error: {len(failed)} cell{'s' if len(failed) != 1 else ''} failed: "
              + "; ".join(c.label() for c in failed), file=sys.stderr)
        return EXIT_INPUT
    return EXIT_OK


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(_join_negative_vectors(list(sys.argv[1:] if argv is None else argv)))
    except SystemExit as done:
        # a usage error, --help or --version (argparse has printed what it had to): returned,
        # so that entry leaves through _leave, not an interpreter exit that would wait for
        # a mesh launch.py started reading ahead
        code = done.code
        if code is None or isinstance(code, int):
            return code or 0
        print(code, file=sys.stderr)
        return EXIT_INPUT
    if args.command == "run":
        from .driver import prefetch

        # read, and its surfels sampled, while the effect is read and checked
        prefetch.start(args.scene, args.surfels, args.seed, args.threads)
    from .frontend.diagnostics import UsageError
    from .frontend.diagnostics import GammaError

    try:
        if args.command == "fmt":
            return _fmt(args)
        if args.command == "watch":
            return _watch(args)
        if args.command in ("render", "export"):
            return _saved(args)
        if args.command == "recipes":
            from .frontend.recipes import as_json, describe, stdlib_recipes

            recipes = stdlib_recipes()
            sys.stdout.write(as_json(recipes) if args.json else describe(recipes, verbose=args.verbose))
            return EXIT_OK
        if args.command == "sweep":
            return _sweep(args)
        effect = _load(args.file, getattr(args, "param", ()), cached=args.command == "run")
        if args.command == "run":
            from .driver import prefetch

            prefetch.expect(len(effect.surfaces))   # a setup made ahead is for one surface
        if args.command == "check":
            return EXIT_OK
        if args.command == "emit":
            from .backends.jit import assembly, compile_ir
            from .backends.codegen import generate

            if args.what == "ast":
                from .frontend.ast import dump
                from .frontend.parser import parse

                sys.stdout.write(dump(parse(effect.source, effect.path).decls) + "\n")
                return EXIT_OK
            if args.what == "effect":
                from .ir.effect import dump

                sys.stdout.write(dump(effect))
                return EXIT_OK
            module = generate(effect)
            if args.what == "ir":
                text = str(module)
            elif args.what == "ir-opt":
                text = str(compile_ir(module))
            else:
                text = assembly(module)
            sys.stdout.write(text)
            return EXIT_OK
        from .driver.runner import RunError, RunInterrupted

        if not args.out.strip():
            print("gammac: error: --out must name a folder (it is empty)", file=sys.stderr)
            return EXIT_USAGE

        opts = _run_options(args)
        from dataclasses import asdict

        from . import api

        fields = asdict(opts)
        scene, out = fields.pop("scene"), fields.pop("out")
        fields["show_progress"] = fields.pop("progress")
        streams = sys.stdout, sys.stderr
        _tolerate_closed_pipes()
        try:
            summary = api.run(effect, scene, out=out, **fields).summary
        except RunError as err:
            raise _Fail(str(err)) from None
        except RunInterrupted as stop:
            return _leave_interrupted(stop, f"\ngammac: {stop}")
        finally:
            if isinstance(sys.stdout, _PipeTolerant) and not sys.stdout.closed_pipe:
                sys.stdout = streams[0]
            if isinstance(sys.stderr, _PipeTolerant) and not sys.stderr.closed_pipe:
                sys.stderr = streams[1]
        renders = f"{args.out}/renders, " if summary["rendered"] else ""
        print(f"gammac: wrote {args.out}/maps, {renders}{args.out}/summary.json", file=sys.stderr)
        return EXIT_OK
    except GammaError as err:
        print(err.render(), file=sys.stderr)
        n = len(err.diagnostics)
        print(f"{n} error{'s' if n != 1 else ''} in {err.path}", file=sys.stderr)
        return EXIT_INPUT
    except _Fail as err:
        print(f"gammac: error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except UsageError as err:
        print(f"gammac: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        print("gammac: error: out of memory (use fewer --surfels or --tons, or a smaller --size)",
              file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("gammac: interrupted", file=sys.stderr)
        return 130


def _leave_interrupted(stop, message: str) -> int:
    """Say ``message`` and return the status of the signal that stopped a run
    (``RunInterrupted``), or leave at once with it if a runtime call still
    runs on another thread: the interpreter's exit would wait for it."""
    print(message, file=sys.stderr)
    if stop.abandoned_call:
        sys.stdout.flush()
        sys.stderr.flush()
        import os

        os._exit(stop.status)
    return stop.status


def _leave(status: int) -> None:
    """Exit with ``status``.  Once a command is done, every file it wrote is
    complete and closed, so the interpreter's teardown (freeing the
    simulation, the scene's BVH, the JIT's code, every module: 0.1-0.3 s after
    a run on the bunny) only delays the shell: skip it with ``os._exit``.
    Not when something still wants the teardown: coverage or a profiler
    writing its data at exit, Ray shutting its local cluster down, a
    non-daemon thread."""
    import os
    import threading

    ordinary = (sys.gettrace() is None and sys.getprofile() is None
                and not any(name in sys.modules for name in ("coverage", "ray"))
                and all(t.daemon or t is threading.main_thread() for t in threading.enumerate()))
    setup_cache = sys.modules.get("gamma.driver.setup_cache")
    if setup_cache is not None:
        setup_cache.wait()              # a setup being kept for the next run: whole or not at all
    effect_cache = sys.modules.get("gamma.backends.effect_cache")
    if effect_cache is not None and status == EXIT_OK:
        effect_cache.wait()             # likewise a compiled effect (not after a failure or ^C: it can wait)
    if ordinary:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):   # a reader that went away, a closed stream
                pass
        os._exit(status)
    sys.exit(status)


def entry() -> None:
    """The ``gammac`` command (``python -m gamma.cli`` too)."""
    import os

    # gammac's numpy work is on small arrays: OpenBLAS's thread pool (one
    # thread per core, made when numpy is imported) only cost start-up
    # (~30-50 ms of numpy's import) and woke beside the tracer.  Set before
    # numpy is imported; a user's own setting is kept.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        status = main()
    except KeyboardInterrupt:       # before main's own handler (its imports, the command line)
        print("gammac: interrupted", file=sys.stderr)
        status = 130
    _leave(status)


if __name__ == "__main__":
    entry()
