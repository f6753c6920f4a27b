"""The progress bar of ``gammac run`` and ``gammac export`` on stderr.

    label:  40%|████      | 2/5 iteration [00:01<00:02], 0.61 s trace, 397k hitting γ-tons/s

It replaces tqdm, whose import alone (``tqdm.version`` reads the installed
distributions' metadata through ``importlib.metadata``) delayed the main
thread of every run.
A run updates its bar once per iteration, so this draws on every update and
needs none of tqdm's rate limiting, nesting or notebook support.

Drawing never stops a run: once stderr refuses a write (a closed pipe, a
full disk), the bar stops drawing and the run goes on.
"""

from __future__ import annotations

import os
import sys
import time

#: Partial blocks for the bar's last cell: tqdm's characters, so a bar looks as it did.
_BLOCKS = " ▏▎▍▌▋▊▉█"
#: ... and where the file's encoding has no block characters (tqdm's ascii bar).
_ASCII_BLOCKS = " 123456789#"
#: Width assumed when stderr is not a terminal (a pipe, a file, a test's capture).
_DEFAULT_WIDTH = 100


def _can_write(file, text: str) -> bool:
    """Whether ``file``'s encoding has ``text`` (a file without one: yes)."""
    encoding = getattr(file, "encoding", None)
    if not encoding:
        return True
    try:
        text.encode(encoding)
        return True
    except (UnicodeEncodeError, LookupError):
        return False


def clock(seconds: float) -> str:
    """mm:ss, or h:mm:ss from an hour on (tqdm's format_interval)."""
    whole = int(seconds)
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours:d}:{minutes:02d}:{secs:02d}" if hours else f"{minutes:02d}:{secs:02d}"


class ProgressBar:
    """A bar of ``total`` steps of ``unit`` drawn on ``file``, redrawn in place
    on every ``update``; ``close`` ends its line.  ``disable`` draws nothing."""

    def __init__(self, total: int, unit: str = " iteration", desc: str = "", file=None,
                 disable: bool = False):
        self.total, self.unit, self.desc = max(int(total), 0), unit, desc
        self.file = sys.stderr if file is None else file
        self.n = 0
        self.postfix = ""
        self.started = time.monotonic()
        self.drawing = not disable
        self.closed = False
        self.drawn = 0                  # length of the line on screen: a shorter one blanks the rest
        self.blocks = _BLOCKS if _can_write(self.file, _BLOCKS) else _ASCII_BLOCKS
        self._draw()

    def set_postfix_str(self, text: str) -> None:
        """Text after the times (shown from the next drawing on)."""
        self.postfix = text

    def update(self, steps: int = 1) -> None:
        self.n += steps
        self._draw()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._write("\n")

    def line(self, width: int | None = None) -> str:
        """The bar's text as drawn now, fitting ``width`` columns less one (a
        line as wide as the terminal wraps; default: the file's terminal)."""
        elapsed = time.monotonic() - self.started
        if self.n and self.total:
            remaining = clock(elapsed / self.n * max(self.total - self.n, 0))
        else:
            remaining = "?"
        left = f"{self.desc}: " if self.desc else ""
        fraction = min(self.n / self.total, 1.0) if self.total else 0.0
        left += f"{fraction * 100:3.0f}%|"
        right = f"| {self.n}/{self.total}{self.unit} [{clock(elapsed)}<{remaining}]"
        if width is None:
            width = self._width()
        room = max(width - 1, 1)
        postfix = f", {self.postfix}" if self.postfix else ""
        if len(left) + 1 + len(right) + len(postfix) > room:
            postfix = ""                # the postfix goes first, then the bar's cells
        cells = max(room - len(left) - len(right) - len(postfix), 0)
        steps = len(self.blocks) - 1
        filled, part = divmod(int(fraction * cells * steps), steps)
        bar = self.blocks[-1] * filled
        if filled < cells:
            bar += (self.blocks[part] if part else " ") + " " * (cells - filled - 1)
        return (left + bar + right + postfix)[:room]

    def _width(self) -> int:
        """Columns of the terminal the bar is drawn on ($COLUMNS first, as
        shutil has it), or _DEFAULT_WIDTH when it is not a terminal."""
        try:
            columns = int(os.environ.get("COLUMNS", "0"))
        except ValueError:
            columns = 0
        if columns > 0:
            return columns
        try:
            if self.file.isatty():
                return os.get_terminal_size(self.file.fileno()).columns or _DEFAULT_WIDTH
        except (AttributeError, ValueError, OSError):
            pass
        return _DEFAULT_WIDTH

    def _draw(self) -> None:
        if self.drawing:
            text = self.line()
            self._write("\r" + text + " " * max(self.drawn - len(text), 0))
            self.drawn = len(text)

    def _write(self, text: str) -> None:
        if not self.drawing:
            return
        try:
            self.file.write(text)
            self.file.flush()
        except (OSError, ValueError):   # a closed pipe or file: the run goes on without its bar
            self.drawing = False


def progress(items, total: int | None = None, unit: str = " iteration", desc: str = "", file=None,
             disable: bool = False):
    """Each of ``items``, the bar updated after each (a generator)."""
    items = list(items) if total is None else items
    bar = ProgressBar(len(items) if total is None else total, unit, desc, file, disable)
    try:
        for item in items:
            yield item
            bar.update(1)
    finally:
        bar.close()
