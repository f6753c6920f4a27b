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

from .options import LIMITS, OPTIONS, REQUIRED, SWEEPABLE, VECTOR_FLAGS, OptionError, ascii_float, from_args, whole

# Start-up time reported in summary.json runs from here, or from the
# ``gammac`` command's first line (launch.py), which came before (the
# interpreter's own start, before the first import of gamma, is not included).
_STARTED = getattr(sys.modules.get("gamma.launch"), "STARTED", None) or time.perf_counter()

# The front end (and what it imports) is imported once the command line is
# parsed: ``gammac run`` starts reading its mesh before that (prefetch.py),
# before even this module is imported when it can (launch.py).

EXIT_OK, EXIT_INPUT, EXIT_USAGE = 0, 1, 2


def _typed(parse):
    """An options.py value parser as an argparse type: its OptionError is
    the one-line message argparse shows."""
    def convert(text: str):
        try:
            return parse(text)
        except OptionError as err:
            raise argparse.ArgumentTypeError(str(err)) from None

    convert.__name__ = parse.__name__
    return convert


def _param(text: str) -> tuple[str, float]:
    import math

    name, sep, value = text.partition("=")
    try:
        number = ascii_float(value)
    except ValueError:
        number = math.nan
    parts = name.split(".")
    if not sep or len(parts) > 2 or not all(x.isidentifier() for x in parts) or not math.isfinite(number):
        raise argparse.ArgumentTypeError(f"'{text}' is not NAME=NUMBER or RECIPE.NAME=NUMBER")
    return name, number


class _HelpFormatter(argparse.HelpFormatter):
    """Shows each option's default in --help (where it has a meaningful one)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("%(default)" in text or not action.option_strings or default in (None, False, [], "")
                or default is argparse.SUPPRESS or action.nargs == 0):
            return text
        return f"{text} (default: %(default)s)" if text else "(default: %(default)s)"


def _join_negative_vectors(argv: list[str]) -> list[str]:
    """``--view -0.6,0.2,1`` as ``--view=-0.6,0.2,1``: argparse would otherwise
    take the value for an option (it knows only plain negative numbers)."""
    import re

    out, i = [], 0
    while i < len(argv):
        arg = argv[i]
        if (arg in VECTOR_FLAGS and i + 1 < len(argv)
                and re.fullmatch(r"-[0-9.][0-9.eE+-]*(,[^,]*)*", argv[i + 1])):
            out.append(f"{arg}={argv[i + 1]}")
            i += 2
            continue
        out.append(arg)
        i += 1
    return out


def _version() -> str:
    from .version import version

    return f"gammac {version()}"


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
    _add_param(r)
    add_options(r, *RUN_GROUPS, "run")
    s = sub.add_parser("sweep", help="run every combination of a parameter grid (a Ray task each)",
                       description="Run the effect once per combination of the --grid values (each a "
                                   "'gammac run' with the other options, as a Ray task) into "
                                   "OUT/cells/NAME; OUT/index.json lists the cells, "
                                   "OUT/contact-sheet.png shows their final renders. Finished cells "
                                   "are skipped on a rerun. Needs the optional extra: pip install '.[ray]'. "
                                   "--threads is per cell (default 1: cells run side by side).")
    s.add_argument("file")
    s.add_argument("--grid", action="append", required=True, metavar="NAME=VALUES",
                   help="a parameter of the effect or one of " + ", ".join(SWEEPABLE)
                        + ", with values V1,V2,... or a range A..B (repeatable)")
    s.add_argument("--ray-address", dest="cluster", metavar="ADDRESS",
                   help="an existing Ray cluster (default: a local Ray on this machine)")
    _add_param(s)
    add_options(s, *RUN_GROUPS)
    s.set_defaults(threads=1)
    v = sub.add_parser("render", help="a picture of a saved run's iteration, without simulating")
    v.add_argument("dir", help="the --out folder of a gammac run")
    v.add_argument("--iteration", type=_typed(whole), help="iteration to show (default: the last saved)")
    add_options(v, "camera", "picture", saved=True)
    v.add_argument("--output", "-o", metavar="FILE",
                   help="PNG to write (default: DIR/renders/view_iter_NNNN[_PROPERTY].png)")
    v.add_argument("--threads", type=_typed(whole), default=0, help="worker threads (0: all cores)")
    x = sub.add_parser("export", help="glTF/OBJ + baked textures of a saved run, without simulating")
    x.add_argument("dir", help="the --out folder of a gammac run")
    which = x.add_mutually_exclusive_group()
    which.add_argument("--iteration", type=_typed(whole), help="iteration to export (default: the last saved)")
    which.add_argument("--all", action="store_true", help="every saved iteration")
    add_options(x, "bake")
    x.add_argument("--format", choices=("gltf", "usd"), default="gltf",
                   help="usd: also an OpenUSD stage DIR/export/SCENE.usdc, the iterations as time samples")
    x.add_argument("--threads", type=_typed(whole), default=0, help="worker threads (0: all cores)")
    add_options(x, "progress")
    w = sub.add_parser("watch", help="run an effect again on every save and show it in the browser")
    w.add_argument("file")
    _add_param(w)
    add_options(w, "simulation", "camera")
    w.add_argument("--port", type=_typed(whole), default=8000, help="port on 127.0.0.1 (0: any free one)")
    w.add_argument("--preview", type=float, default=0.25,
                   help="fraction of the gamma-tons of the quick first pass after a save (1: none)")
    return p


#: The option groups (options.py) of ``gammac run`` that ``gammac sweep`` passes on to each cell.
RUN_GROUPS = ("simulation", "camera", "output", "picture", "export", "bake", "progress")


def _add_param(r: argparse.ArgumentParser) -> None:
    """``--param``, the effect's overrides (not a run option: they are the effect's)."""
    r.add_argument("--param", type=_param, action="append", default=[], metavar="[RECIPE.]NAME=VALUE",
                   help="override a parameter of the effect, or of an imported recipe "
                        "(RECIPE = its file name without .gamma); repeatable")


def add_options(p: argparse.ArgumentParser, *groups: str, saved: bool = False) -> None:
    """The run options (options.OPTIONS) of ``groups`` as ``p``'s arguments;
    ``saved``: of a saved run (``gammac render``), whose own values are the
    defaults of the options that say so."""
    exclusive: dict[str, argparse._MutuallyExclusiveGroup] = {}
    for o in OPTIONS:
        if o.flag is None or o.group not in groups:
            continue
        kwargs = {"dest": o.name, "help": o.help}
        if o.default is REQUIRED:
            kwargs["required"] = True
        else:
            kwargs["default"] = None if saved and o.saved else o.default
        if saved and o.saved:
            kwargs["help"] += " (default: the run's)"
        for key, value in (("action", o.action), ("metavar", o.metavar), ("choices", o.choices)):
            if value is not None:
                kwargs[key] = value
        if o.parse is not None:
            kwargs["type"] = _typed(o.parse)
        if o.const is not None:
            kwargs.update(nargs="?", const=o.const)
        if o.exclusive is not None and o.exclusive not in exclusive:
            exclusive[o.exclusive] = p.add_mutually_exclusive_group()
        (p if o.exclusive is None else exclusive[o.exclusive]).add_argument(o.flag, **kwargs)


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
    from .driver.running.runner import RunError, RunInterrupted
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
        return watch(args.file, overrides, from_args(args, out="", started=_STARTED), args.port, args.preview)
    except RunError as err:
        raise _Fail(str(err)) from None
    except RunInterrupted as stop:       # ^C while a result is computed (its folder is a scratch one)
        print(f"gammac: interrupted by {stop.signal_name}", file=sys.stderr)
        return stop.status


def _saved(args) -> int:
    """``render`` and ``export`` of a saved run's maps.  SIGINT and SIGTERM
    stop the set-up, render or bake under way at its next chunk; what was
    written before stays (every file is written whole or not at all)."""
    from .driver.running.interrupt import Interrupted, Interruptions
    from .driver.running.runner import RunError

    try:
        with Interruptions() as stop:
            return stop.call(_saved_command, args, stop)
    except Interrupted as signal:
        print(f"gammac: {args.command} interrupted by {signal.name}; the files written before are kept",
              file=sys.stderr)
        return signal.status
    except RunError as err:
        raise _Fail(str(err)) from None


def _saved_command(args, stop) -> int:
    """The work of ``_saved`` (under its Interruptions ``stop``)."""
    from .driver.outputs.saved import export_saved, render_saved
    from .frontend.checker import UsageError

    if args.command == "render":
        low, high = LIMITS["--size"]
        if not low <= args.width <= high:
            raise UsageError(f"--size must be between {low} and {high:,}, not {args.width}")
        path = render_saved(args.dir, args.iteration, args.show, args.output, args.width, args.samples,
                            args.ao_samples, view=args.view, eye=args.eye, look_at=args.look_at,
                            up=args.up, fov=args.fov, threads=args.threads, shading=args.shading,
                            crease=args.crease, stop=stop)
        print(f"gammac: wrote {path}", file=sys.stderr)
    else:
        iterations = None
        if args.all:
            from pathlib import Path

            iterations = sorted(int(p.stem[5:]) for p in Path(args.dir, "maps").glob("iter_[0-9][0-9][0-9][0-9].ply"))
        elif args.iteration is not None:
            iterations = [args.iteration]
        done = export_saved(args.dir, iterations, args.bake_size, args.threads, progress=args.progress,
                            texel_density=args.texel_density, usd=args.format == "usd", preset=args.preset,
                            float_maps=args.float_maps, stop=stop)
        print(f"gammac: exported iteration{'s' if len(done) > 1 else ''} "
              f"{', '.join(map(str, done))} to {args.dir}/export", file=sys.stderr)
    return EXIT_OK


def _sweep(args) -> int:
    """``gammac sweep``: check the effect and every option here, then run the cells."""
    from .driver.distributed.cluster import RayUnavailable
    from .driver.distributed.sweep import SweepError, parse_grid, sweep
    from .frontend.checker import UsageError

    try:
        axes = [parse_grid(g) for g in args.grid]
    except SweepError as err:
        raise _Fail(str(err)) from None
    # The effect must check with the first value of every parameter swept.
    first = [(a.name, float(a.values[0])) for a in axes if a.name not in SWEEPABLE]
    swept = {name for name, _ in first}
    try:
        _load(args.file, [p for p in args.param if p[0] not in swept] + first)
    except UsageError as err:      # name the option the user wrote
        text = str(err)
        for name in swept:
            text = text.replace(f"--param {name}:", f"--grid {name}:")
        raise UsageError(text) from None
    try:
        cells = sweep(args.file, args.param, from_args(args, out=args.out), axes, address=args.cluster,
                      threads=args.threads or 1, progress=args.progress)
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
        # so that entry leaves through _leave like every command
        code = done.code
        if code is None or isinstance(code, int):
            return code or 0
        print(code, file=sys.stderr)
        return EXIT_INPUT
    if args.command == "run":
        from .driver.running import prefetch

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
            from .driver.running import prefetch

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
        from .driver.running.runner import RunError, RunInterrupted

        if not args.out.strip():
            print("gammac: error: --out must name a folder (it is empty)", file=sys.stderr)
            return EXIT_USAGE

        from .driver.running.runner import run

        opts = from_args(args, started=_STARTED)
        streams = sys.stdout, sys.stderr
        _tolerate_closed_pipes()
        try:
            summary = run(effect, opts)
        except RunError as err:
            raise _Fail(str(err)) from None
        except RunInterrupted as stop:
            print(f"\ngammac: {stop}", file=sys.stderr)
            return stop.status
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


def _leave(status: int) -> None:
    """Exit with ``status`` through the interpreter's normal exit, once the
    caches' files being written for the next run are whole (a setup, and
    after a success a compiled effect: not after a failure or ^C, where it
    can wait for the next run)."""
    setup_cache = sys.modules.get("gamma.driver.caches.setup_cache")
    if setup_cache is not None:
        setup_cache.wait()
    effect_cache = sys.modules.get("gamma.backends.effect_cache")
    if effect_cache is not None and status == EXIT_OK:
        effect_cache.wait()
    sys.exit(status)


def entry() -> None:
    """The ``gammac`` command (``python -m gamma.cli`` too)."""
    import os

    # gammac's numpy work is on small arrays: OpenBLAS's thread pool (one
    # thread per core, made when numpy is imported) only cost start-up
    # and woke beside the tracer (bench/RESULTS.md).  Set before
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
