"""``gammac sweep``: every combination of a parameter grid run as one
``gammac run``, each combination (a *cell*) a Ray task.

A cell is the sweep's run options (``options.RunOptions``) with the cell's
values, run by the driver in a worker into a private temporary folder (the
same run as the ``gammac run`` command DIR/index.json records for it); its files
come back through Ray as bytes and are moved into DIR/cells/NAME whole (a
cell folder is complete or absent), so workers need no shared filesystem for
outputs, only the effect and scene at the same paths.

Resuming: a cell whose folder exists and whose index entry says it finished
with the same command is not run again.  A failing cell (an error exit, an
exception, a worker lost more often than Ray retries) is recorded with its
parameters and message; the others go on.  After the cells, DIR/contact-sheet.png
shows each cell's final render in a labelled grid.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import math
import os
import shlex
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from dataclasses import replace

from ...files import atomic_write
from ...options import BY_NAME, SWEEPABLE, command_line

INDEX_VERSION = 1
#: Ray re-runs a cell whose worker died (a crash, a lost node) this many times.
CELL_RETRIES = 3


class SweepError(Exception):
    """A one-line, user-facing problem with the sweep's arguments or folder."""


@dataclass
class Axis:
    name: str
    values: list[str]          # as the user wrote them (ranges expanded)


def parse_grid(text: str) -> Axis:
    """``NAME=V1,V2,...``; a value ``A..B`` is every whole number from A to B."""
    name, sep, spec = text.partition("=")
    name = name.strip().replace("-", "_")
    if not sep or not name.isidentifier() or not spec.strip():
        raise SweepError(f"--grid {text}: expected NAME=V1,V2,... or NAME=A..B")
    values: list[str] = []
    for item in spec.split(","):
        item = item.strip()
        if ".." in item:
            low, _, high = item.partition("..")
            try:
                a, b = int(low), int(high)
            except ValueError:
                raise SweepError(f"--grid {text}: '{item}' is not a range of whole numbers A..B") from None
            if b < a:
                raise SweepError(f"--grid {text}: the range '{item}' is empty")
            if b - a >= 10_000:
                raise SweepError(f"--grid {text}: the range '{item}' has more than 10,000 values")
            values.extend(str(v) for v in range(a, b + 1))
            continue
        try:
            number = float(item)
        except ValueError:
            number = math.nan
        if not math.isfinite(number):
            raise SweepError(f"--grid {text}: '{item}' is not a number")
        if name in SWEEPABLE and number != int(number):
            raise SweepError(f"--grid {text}: {SWEEPABLE[name]} takes whole numbers, not '{item}'")
        values.append(item)
    numbers = [float(v) for v in values]
    dup = next((v for i, v in enumerate(values) if float(v) in numbers[:i]), None)
    if dup is not None:
        raise SweepError(f"--grid {text}: the value {dup} is given twice")
    return Axis(name, values)


def cell_name(values: dict[str, str]) -> str:
    return "_".join(f"{k}={v}" for k, v in values.items())


@dataclass
class Cell:
    values: dict[str, str]                 # grid name -> value text
    argv: list[str]                        # the gammac run arguments (without the output folder)
    opts: object = None                    # its RunOptions (the output folder set by the worker)
    params: list = field(default_factory=list)   # its (name, value) overrides of the effect's parameters
    name: str = ""
    index: int = 0
    status: str = "pending"                # pending | ok | failed
    seconds: float | None = None
    summary: dict = field(default_factory=dict)
    error: str | None = None

    def parameters(self) -> dict:
        return {k: int(v) if k in SWEEPABLE else float(v) for k, v in self.values.items()}

    def label(self) -> str:
        return " ".join(f"{k}={v}" for k, v in self.values.items())


def plan_cells(effect_path: str, params: list, base, axes: list[Axis], threads: int) -> list[Cell]:
    """Every combination of the axes, first axis slowest: ``base`` (RunOptions)
    and ``params`` with the cell's values."""
    names = [a.name for a in axes]
    if len(set(names)) != len(names):
        raise SweepError(f"--grid {next(n for n in names if names.count(n) > 1)} is given twice")
    effect = str(Path(effect_path).resolve())
    base = replace(base, scene=str(Path(base.scene).resolve()), threads=threads, progress=False)
    cells = []
    for i, combo in enumerate(itertools.product(*(a.values for a in axes))):
        values = dict(zip(names, combo))
        opts = replace(base, **{k: int(v) for k, v in values.items() if k in SWEEPABLE})
        mine = list(params) + [(k, float(v)) for k, v in values.items() if k not in SWEEPABLE]
        argv = ["run", effect, "--scene", opts.scene, *command_line(opts, keep=values)]
        for name, value in mine:
            argv += ["--param", f"{name}={value!r}"]
        cells.append(Cell(values, argv, opts, mine, cell_name(values), i))
    return cells


def check_overlap(axes: list[Axis], base, params: list) -> None:
    """A grid name must not also be fixed by the run options or a --param."""
    for axis in axes:
        if axis.name in SWEEPABLE:
            if getattr(base, axis.name) != BY_NAME[axis.name].default:
                raise SweepError(f"{SWEEPABLE[axis.name]} is given and also swept by --grid {axis.name}")
        else:
            given = next((value for name, value in params if name == axis.name), None)
            if given is not None:
                raise SweepError(f"--param {axis.name}={given!r} is given and also swept by --grid {axis.name}")


def run_cell(effect_path: str, params: list, opts, crash_marker: str | None = None) -> dict:
    """Run one cell in this process (a Ray worker) into a temporary folder;
    returns its exit status, messages and files.

    ``crash_marker`` is for tests: the first attempt to see that path absent
    creates it and kills its own process, as a lost worker would."""
    if crash_marker and not os.path.exists(crash_marker):
        Path(crash_marker).write_text(str(os.getpid()))
        os._exit(1)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gamma-cell-") as tmp:
        out = Path(tmp) / "out"
        messages = io.StringIO()
        with contextlib.redirect_stderr(messages), contextlib.redirect_stdout(messages):
            code = _run_cell(effect_path, params, replace(opts, out=str(out)))
        files = {}      # relative path -> bytes, or None for a folder (kept even if empty)
        if code == 0:
            for path in sorted(out.rglob("*")):
                files[path.relative_to(out).as_posix()] = path.read_bytes() if path.is_file() else None
    return {"exit": code, "messages": messages.getvalue(), "files": files,
            "seconds": time.perf_counter() - t0, "host": os.uname().nodename}


def _run_cell(effect_path: str, params: list, opts) -> int:
    """The run of a cell; its exit status as ``gammac run``'s, its errors on stderr."""
    from ...backends import effect_cache
    from ...frontend.diagnostics import GammaError, UsageError, render
    from ..running.runner import RunError, run

    try:
        with open(effect_path, encoding="utf-8") as f:
            source = f.read()
        effect = effect_cache.check(effect_path, source, dict(params))
        if effect.warnings:
            print(render(effect.warnings, effect.path, effect.source), file=sys.stderr)
        run(effect, opts)
    except GammaError as err:
        print(err.render(), file=sys.stderr)
        return 1
    except (RunError, OSError) as err:
        print(f"gammac: error: {err}", file=sys.stderr)
        return 1
    except UsageError as err:
        print(f"gammac: error: {err}", file=sys.stderr)
        return 2
    return 0


def cell_summary(files: dict) -> dict:
    """What index.json keeps of a cell's summary.json: its final iteration."""
    summary = json.loads(files["summary.json"])
    iterations = summary.get("iterations") or [{}]
    last = iterations[-1]
    keep = {k: last[k] for k in ("emitted", "settled", "escaped", "capped", "interactions") if k in last}
    keep["property_sums"] = last.get("property_sums", {})
    keep["iterations"] = len(summary.get("iterations", []))
    keep["rendered"] = summary.get("rendered")
    keep["surfels"] = summary.get("surfels")
    return keep


def final_render(folder: Path, summary: dict) -> Path | None:
    n = summary.get("iterations") or 0
    path = folder / "renders" / f"iter_{n:04d}.png"
    return path if n and path.is_file() else None


class SweepProgress:
    """Cells done out of all, with an estimate of the time left."""

    def __init__(self, total: int, already: int, enabled: bool):
        self.total, self.done, self.enabled = total, already, enabled
        self.already = already
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()

    def eta(self) -> str:
        ran = self.done - self.already
        left = self.total - self.done
        if not ran or not left:
            return ""
        seconds = (time.perf_counter() - self.t0) / ran * left
        return f"  ETA {int(seconds // 60)}:{int(seconds % 60):02d}"

    def cell(self, cell: Cell) -> None:
        self.done += 1
        if not self.enabled:
            return
        width = 30
        filled = int(width * self.done / max(1, self.total))
        what = f"{cell.label()} {cell.status}" + (f" in {cell.seconds:.1f} s" if cell.seconds else "")
        line = f"[{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total} cells  {what}{self.eta()}"
        if self.tty:
            sys.stderr.write("\r" + line.ljust(100)[:140] + ("\n" if self.done == self.total else ""))
        else:
            sys.stderr.write(line + "\n")
        sys.stderr.flush()


def read_index(out: Path) -> dict:
    path = out / "index.json"
    if not path.exists():
        return {}
    try:
        index = json.loads(path.read_text(encoding="utf-8"))
        return {c["name"]: c for c in index.get("cells", []) if isinstance(c, dict) and "name" in c}
    except (OSError, ValueError, TypeError) as err:
        print(f"gammac: warning: '{path}' is unreadable ({err}); every cell runs again", file=sys.stderr)
        return {}


def write_index(out: Path, effect: str, scene: str, axes: list[Axis], run_args: list[str],
                cells: list[Cell]) -> None:
    """DIR/index.json: the grid, the sweep's run options as ``gammac run``
    arguments, and per cell its parameters, status, summary and command."""
    index = {
        "version": INDEX_VERSION,
        "effect": effect, "scene": scene,
        "grid": {a.name: a.values for a in axes},
        "run_options": run_args,
        "cells": [{
            "name": c.name, "parameters": c.parameters(), "folder": f"cells/{c.name}",
            "status": c.status, "seconds": c.seconds, "summary": c.summary, "error": c.error,
            "command": shlex.join(["gammac", *c.argv, "--out", str((out / "cells" / c.name).resolve())]),
            "argv": c.argv,
        } for c in cells],
    }
    atomic_write(out / "index.json", (json.dumps(index, indent=2) + "\n").encode("utf-8"))


def store_cell(out: Path, cell: Cell, files: dict) -> None:
    """Move a finished cell's files into DIR/cells/NAME in one rename."""
    cells = out / "cells"
    staging = Path(tempfile.mkdtemp(prefix=f".{cell.name}.", dir=cells))
    try:
        for rel, data in files.items():
            path = staging / rel
            if data is None:
                path.mkdir(parents=True, exist_ok=True)
            else:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(data)
        final = cells / cell.name
        if final.exists():
            shutil.rmtree(final)
        os.replace(staging, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def contact_sheet(out: Path, axes: list[Axis], cells: list[Cell], tile: int = 240) -> bytes:
    """Each cell's final render (scaled to ``tile`` pixels across), labelled
    with its values; rows follow all but the last grid axis, columns the last
    axis' values."""
    from PIL import Image, ImageDraw, ImageFont

    columns = len(axes[-1].values) if len(axes) > 1 or len(cells) <= 8 else math.ceil(math.sqrt(len(cells)))
    rows = math.ceil(len(cells) / columns)
    thumbs = {}
    for cell in cells:
        render = final_render(out / "cells" / cell.name, cell.summary) if cell.status == "ok" else None
        if render is not None:
            with Image.open(render) as image:
                image = image.convert("RGB")
            scale = tile / max(image.width, image.height)
            thumbs[cell.name] = image.resize((max(1, round(image.width * scale)),
                                              max(1, round(image.height * scale))), Image.LANCZOS)
    tile_h = max((t.height for t in thumbs.values()), default=tile // 2)
    label_h, pad = 38, 8
    try:
        font = ImageFont.load_default(size=14)
    except TypeError:        # Pillow without FreeType: the small bitmap font
        font = ImageFont.load_default()
    sheet = Image.new("RGB", (columns * (tile + pad) + pad, rows * (tile_h + label_h + pad) + pad),
                      (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for i, cell in enumerate(cells):
        x = pad + (i % columns) * (tile + pad)
        y = pad + (i // columns) * (tile_h + label_h + pad)
        thumb = thumbs.get(cell.name)
        if thumb is not None:
            sheet.paste(thumb, (x + (tile - thumb.width) // 2, y + (tile_h - thumb.height) // 2))
        else:
            draw.rectangle((x, y, x + tile - 1, y + tile_h - 1), fill=(225, 225, 225))
            note = {"ok": "no render", "failed": "FAILED"}.get(cell.status, cell.status)
            draw.text((x + 8, y + tile_h // 2 - 8), note, font=font,
                      fill=(170, 0, 0) if cell.status == "failed" else (90, 90, 90))
        words = cell.label().split(" ")
        half = (len(words) + 1) // 2
        for line_no, text in enumerate((" ".join(words[:half]), " ".join(words[half:]))):
            if text:
                draw.text((x + 2, y + tile_h + 3 + 17 * line_no), text, fill=(0, 0, 0), font=font)
    buffer = io.BytesIO()
    sheet.save(buffer, format="PNG")
    return buffer.getvalue()


def sweep(effect_path: str, params: list, base, axes: list[Axis], address: str | None = None,
          threads: int = 1, progress: bool = True, _crash_marker: str | None = None) -> list[Cell]:
    """Run every cell not already finished into ``base.out``; ``base``: the
    RunOptions every cell shares, ``params``: the effect's (name, value)
    overrides.  Returns all cells with their status."""
    from .cluster import connect

    if not axes:
        raise SweepError("give at least one --grid NAME=VALUES")
    check_overlap(axes, base, params)
    cells = plan_cells(effect_path, params, base, axes, threads)
    scene = base.scene
    run_args = command_line(base, skip=("scene", "out", "threads", "progress")) + [a for name, value in params for a in ("--param", f"{name}={value!r}")]
    folder = Path(base.out)
    try:
        (folder / "cells").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SweepError(f"cannot write to '{folder}': {err.strerror or err}") from None
    earlier = read_index(folder)
    todo = []
    for cell in cells:
        old = earlier.get(cell.name)
        if old and old.get("status") == "ok" and old.get("argv") == cell.argv and (folder / "cells" / cell.name).is_dir():
            cell.status, cell.seconds, cell.summary = "ok", old.get("seconds"), old.get("summary", {})
        else:
            todo.append(cell)
    effect_abs, scene_abs = str(Path(effect_path).resolve()), str(Path(scene).resolve())
    write_index(folder, effect_abs, scene_abs, axes, run_args, cells)
    if progress and len(todo) < len(cells):
        print(f"gammac: {len(cells) - len(todo)} of {len(cells)} cells finished earlier; "
              f"running {len(todo)}", file=sys.stderr)
    bar = SweepProgress(len(cells), len(cells) - len(todo), progress)
    if todo:
        with connect(address) as conn:
            ray = conn.ray
            cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
            task = ray.remote(run_cell).options(num_cpus=min(threads, cpus), max_retries=CELL_RETRIES,
                                                retry_exceptions=False)
            effect = str(Path(effect_path).resolve())
            pending = {task.remote(effect, c.params, c.opts, _crash_marker): c for c in todo}
            try:
                while pending:
                    ready, _ = ray.wait(list(pending), num_returns=1)
                    cell = pending.pop(ready[0])
                    finish_cell(ray, ready[0], cell, folder)
                    write_index(folder, effect_abs, scene_abs, axes, run_args, cells)
                    bar.cell(cell)
            finally:
                for ref in pending:
                    ray.cancel(ref, force=True)
    atomic_write(folder / "contact-sheet.png", contact_sheet(folder, axes, cells))
    return cells


def finish_cell(ray, ref, cell: Cell, folder: Path) -> None:
    try:
        result = ray.get(ref)
    except Exception as err:   # a Python error or a worker lost more often than retried
        cell.status, cell.error = "failed", f"{type(err).__name__}: {err}".strip()
    else:
        cell.seconds = result["seconds"]
        if result["exit"] == 0:
            store_cell(folder, cell, result["files"])
            cell.status, cell.summary, cell.error = "ok", cell_summary(result["files"]), None
        else:
            cell.status = "failed"
            cell.error = result["messages"].strip() or f"gammac run exited with status {result['exit']}"
    if cell.status == "failed":
        shutil.rmtree(folder / "cells" / cell.name, ignore_errors=True)   # an earlier run's, now stale
        shown = "\n  ".join(cell.error.splitlines()[-6:])
        print(f"\ngammac: cell {cell.label()} failed:\n  {shown}", file=sys.stderr)
