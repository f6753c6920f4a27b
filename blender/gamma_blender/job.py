"""A ``gammac run`` child process as the add-on sees it: the command line,
progress read from the child's progress bar, cancellation and the outcome.

Nothing here imports ``bpy``: the modal operator (a timer over ``poll``), the
script path (a loop over ``poll``) and the tests drive the same object.
Blender's bundled Python never loads gamma's native runtime; only the
``gammac`` executable does, in its own process.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

#: The child's progress bar: "... | 3/10 iteration [00:01<00:02] ...".
_PROGRESS = re.compile(r"(\d+)/(\d+) iteration")
#: A diagnostic in an effect: "path/effect.gamma:12:5: error: ...".
_DIAGNOSTIC = re.compile(r"^(?P<file>[^\n:]+\.gamma):(?P<line>\d+):(?P<col>\d+): (?P<kind>error|warning): (?P<text>.*)$")
#: Share of the progress bar given to the iterations; the texture set's bake takes the rest.
RUN_SHARE = 0.85
#: gammac's exit status when a SIGINT stopped it.
EXIT_INTERRUPTED = 130


class GammaError(Exception):
    """A failure to show the user as one report (never a traceback)."""


def find_gammac(setting: str) -> str:
    """The ``gammac`` executable named by the preference (a path, or a
    name looked up on PATH)."""
    setting = (setting or "gammac").strip()
    path = Path(os.path.expanduser(setting))
    if path.is_file() and os.access(path, os.X_OK):
        return str(path)
    found = shutil.which(setting)
    if found:
        return found
    raise GammaError(f"gammac not found ('{setting}'): install gamma (pip install gamma) or set "
                     "the path to gammac in the add-on's preferences")


def list_recipes(gammac: str) -> list[dict]:
    """The standard library's recipes (``gammac recipes --json``)."""
    try:
        r = subprocess.run([gammac, "recipes", "--json"], capture_output=True, text=True, timeout=60,
                           stdin=subprocess.DEVNULL)
    except OSError as e:
        raise GammaError(f"could not start {gammac}: {e}") from None
    except subprocess.TimeoutExpired:
        raise GammaError(f"{gammac} recipes took over a minute") from None
    if r.returncode != 0:
        raise GammaError(f"{gammac} recipes failed: {last_lines(r.stderr)}")
    try:
        return json.loads(r.stdout)
    except ValueError:
        raise GammaError(f"{gammac} recipes --json gave no JSON: is it gamma's gammac?") from None


def last_lines(text: str, count: int = 6) -> str:
    """The end of a child's stderr without its progress-bar redraws."""
    lines = [ln.strip() for ln in text.replace("\r", "\n").splitlines()]
    lines = [ln for ln in lines if ln and not _PROGRESS.search(ln)]
    return "\n".join(lines[-count:])


def diagnostics(stderr: str) -> list[dict]:
    """The effect's errors and warnings as ``{file, line, col, kind, text}``."""
    found = []
    for line in stderr.replace("\r", "\n").splitlines():
        m = _DIAGNOSTIC.match(line.strip())
        if m:
            found.append(dict(m.groupdict(), line=int(m["line"]), col=int(m["col"])))
    return found


@dataclass
class RunSettings:
    """What one weathering run asks of ``gammac run``."""
    effect: str                          # an effect file or a recipe's path
    iterations: int = 10
    surfels: int = 100_000
    bake_size: int = 1024
    seed: int = 1
    tons: int = 0                        # 0: the effect's own counts
    params: dict = field(default_factory=dict)
    assign: list = field(default_factory=list)   # "PATTERN=SURFACE" strings
    threads: int = 0
    init: str = ""                       # a run folder to start from (gammac run --init)

    def arguments(self, scene: Path, out: Path) -> list[str]:
        args = ["run", self.effect, "--scene", str(scene), "--out", str(out),
                "--iterations", str(self.iterations), "--surfels", str(self.surfels),
                "--seed", str(self.seed), "--export", "--bake-size", str(self.bake_size),
                # Blender draws its own pictures: gammac's renders are kept to a thumbnail
                "--size", "128", "--samples", "1", "--ao", "0",
                # the scene comes from Blender's glTF exporter: +Y up, so gravity is -Y
                "--down", "0,-1,0"]
        if self.tons > 0:
            args += ["--tons", str(self.tons)]
        if self.threads > 0:
            args += ["--threads", str(self.threads)]
        for name, value in self.params.items():
            args += ["--param", f"{name}={value}"]
        for rule in self.assign:
            args += ["--assign", rule]
        if self.init:
            args += ["--init", self.init]
        return args


class GammaJob:
    """One ``gammac run`` child: ``start``, then ``poll`` until it says done
    (the modal timer or a script's loop), ``cancel`` at any time.

    ``state`` is "running", "done", "failed" or "cancelled"; ``progress`` in
    [0, 1]; ``message`` what to tell the user; ``stderr`` all the child said."""

    def __init__(self, gammac: str, settings: RunSettings, scene: Path, out: Path):
        self.gammac, self.settings, self.scene, self.out = gammac, settings, scene, out
        self.state = "new"
        self.progress = 0.0
        self.iteration = 0
        self.message = ""
        self.stderr = ""
        self.returncode: int | None = None
        self.started = 0.0
        self.seconds = 0.0
        self._process: subprocess.Popen | None = None
        self._reader: threading.Thread | None = None
        self._lock = threading.Lock()
        self._cancelled = False

    @property
    def command(self) -> list[str]:
        return [self.gammac] + self.settings.arguments(self.scene, self.out)

    def start(self) -> None:
        self.started = time.monotonic()
        try:
            self._process = subprocess.Popen(
                self.command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                # its own process group: a Ctrl-C in Blender's terminal reaches the child only through cancel()
                start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        except OSError as e:
            raise GammaError(f"could not start {self.gammac}: {e}") from None
        self.state = "running"
        self.message = "starting"
        self._reader = threading.Thread(target=self._read, name="gamma-stderr", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        stream = self._process.stderr
        while True:
            chunk = stream.read1(4096) if hasattr(stream, "read1") else stream.read(4096)
            if not chunk:
                break
            with self._lock:
                self.stderr += chunk.decode("utf-8", "replace")

    def poll(self) -> bool:
        """Update ``progress`` and ``state``; True once the child has ended."""
        if self.state != "running":
            return True
        with self._lock:
            text = self.stderr
        tail = text[-2000:]
        found = _PROGRESS.findall(tail)
        if found:
            done, total = (int(x) for x in found[-1])
            self.iteration = done
            self.progress = RUN_SHARE * done / max(total, 1)
            self.message = (f"iteration {done}/{total}" if done < total else "baking the texture set")
        code = self._process.poll()
        if code is None:
            return False
        self._reader.join(timeout=5)
        self.returncode = code
        self.seconds = time.monotonic() - self.started
        if self._cancelled:
            self.state, self.message = "cancelled", "cancelled: the objects are as they were"
        elif code == 0:
            self.state, self.progress, self.message = "done", 1.0, "done"
        else:
            self.state = "failed"
            self.message = self.failure()
        return True

    def failure(self) -> str:
        """What went wrong, for a report: the effect's errors with file:line:col, else the child's last words."""
        errors = [d for d in diagnostics(self.stderr) if d["kind"] == "error"]
        if errors:
            return "\n".join(f"{Path(d['file']).name}:{d['line']}:{d['col']}: {d['text']}" for d in errors[:8])
        if self.returncode == EXIT_INTERRUPTED:
            return "gammac was interrupted"
        return last_lines(self.stderr) or f"gammac ended with status {self.returncode}"

    def cancel(self, wait: float = 10.0) -> None:
        """Stop the child as Ctrl-C would (gammac leaves its outputs whole),
        then kill it if it does not end within ``wait`` seconds."""
        if self._process is None or self._process.poll() is not None:
            self._cancelled = self._cancelled or self.state == "running"
            return
        self._cancelled = True
        try:
            os.killpg(self._process.pid, signal.SIGINT)
            self._process.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            os.killpg(self._process.pid, signal.SIGKILL)
            self._process.wait()
        except ProcessLookupError:
            pass

    def wait(self, on_progress=None, interval: float = 0.1) -> None:
        """Poll until the child ends (the script path); a KeyboardInterrupt cancels it and is re-raised."""
        try:
            while not self.poll():
                if on_progress is not None:
                    on_progress(self)
                time.sleep(interval)
        except KeyboardInterrupt:
            self.cancel()
            self.poll()
            raise

    def summary(self) -> dict:
        """The run's summary.json (empty if it has none)."""
        try:
            return json.loads((self.out / "summary.json").read_text())
        except (OSError, ValueError):
            return {}
