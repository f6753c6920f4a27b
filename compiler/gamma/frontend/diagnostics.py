"""Diagnostics: positioned messages, collected, printed like a C compiler.

    patina.gamma:12:5: error: unknown property 'patna' of surface Copper
        s.patna += 0.05 * t.patina
          ^~~~~

A user mistake never reaches the user as a Python traceback: every phase
of the front end adds ``Diagnostic`` objects to one ``Report``; at the end
the report raises ``GammaError`` holding every error, or hands its warnings
to the checked effect.  They are printed once, by the caller (``gammac``).
"""

from __future__ import annotations

from dataclasses import dataclass

from .ast import Pos


class UsageError(Exception):
    """A mistake on the command line rather than in the file (exit status 2)."""


@dataclass(frozen=True)
class SourceFile:
    path: str
    text: str


@dataclass(frozen=True)
class Diagnostic:
    pos: Pos
    message: str
    severity: str = "error"            # or "warning"
    file: SourceFile | None = None     # None: the file the GammaError is about

    def format(self, path: str, source: str) -> str:
        # Lines as the parser counts them: only '\n' ends a line (a form feed
        # or U+2028 inside a comment does not).
        lines = [line.removesuffix("\r") for line in source.split("\n")]
        head = f"{path}:{self.pos.line}:{self.pos.col}: {self.severity}: {self.message}"
        if not 1 <= self.pos.line <= len(lines):
            return head
        text, col = _shown(lines[self.pos.line - 1].expandtabs(1), self.pos.col)
        width = min(self.pos.width, 60)
        if len(text) > 120:  # show a window of a very long line around the caret
            start = max(0, col - 60)
            text = ("..." if start else "") + text[start:start + 120] + "..."
            col = col - start + (3 if start else 0)
        caret = " " * (col - 1) + "^" + "~" * max(0, width - 1)
        return f"{head}\n    {text}\n    {caret}"


#: Characters a terminal or ``str.splitlines`` would take for a line end (the
#: parser does not): shown escaped, so the echoed line is whole and on one line.
_ESCAPED = {"\f": "\\f", "\v": "\\v", "\x1c": "\\x1c", "\x1d": "\\x1d", "\x1e": "\\x1e",
            "\x85": "\\x85", "\u2028": "\\u2028", "\u2029": "\\u2029", "\r": "\\r"}


def _shown(text: str, col: int) -> tuple[str, int]:
    """The line as echoed, and the 1-based column ``col`` moves to in it."""
    out, shown_col = [], col
    for i, c in enumerate(text):
        escaped = _ESCAPED.get(c, c)
        if i < col - 1:
            shown_col += len(escaped) - 1
        out.append(escaped)
    return "".join(out), shown_col


def render(diagnostics: list[Diagnostic], path: str, source: str) -> str:
    """Diagnostics of the main file first, then of imported files, by position."""
    def key(d):
        f = d.file.path if d.file else path
        return (f != path, f, d.pos.line, d.pos.col)

    return "\n".join(d.format(d.file.path if d.file else path, d.file.text if d.file else source)
                     for d in sorted(diagnostics, key=key))


class Report:
    """Every diagnostic of one compilation, errors and warnings apart, each once
    (a wildcard rule is checked once per expansion but reported once)."""

    def __init__(self):
        self.errors: list[Diagnostic] = []
        self.warnings: list[Diagnostic] = []

    def error(self, pos: Pos, message: str, file: SourceFile | None = None) -> None:
        self.add(Diagnostic(pos, message, "error", file))

    def warn(self, pos: Pos, message: str, file: SourceFile | None = None) -> None:
        self.add(Diagnostic(pos, message, "warning", file))

    def add(self, diag: Diagnostic) -> None:
        found = self.warnings if diag.severity == "warning" else self.errors
        if diag not in found:
            found.append(diag)

    def extend(self, diagnostics) -> None:
        """Diagnostics from elsewhere (an imported file's syntax errors), kept as they are."""
        self.errors.extend(diagnostics)

    def raise_errors(self, path: str, source: str) -> None:
        if self.errors:
            raise GammaError(path, source, self.errors)


class GammaError(Exception):
    """Raised with every error found in a file (and the files it imports)."""

    def __init__(self, path: str, source: str, diagnostics: list[Diagnostic]):
        self.path = path
        self.source = source
        self.diagnostics = diagnostics
        super().__init__(self.render())

    def render(self) -> str:
        return render(self.diagnostics, self.path, self.source)


def did_you_mean(name: str, candidates) -> str:
    """' (did you mean 'x'?)' for a close candidate, else ''."""
    import difflib

    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""
