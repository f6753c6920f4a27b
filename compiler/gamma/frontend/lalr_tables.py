"""The grammar's LALR tables, built once when the package is built.

Analysing ``gamma.lark`` into LALR tables takes longer than everything else
``gammac check`` does on a 200-line file, so the build runs this module as a
script (CMakeLists.txt) and installs the tables next to the grammar as
``gamma.lalr``.  A fresh process then only unpickles them (``load``).

The file starts with a JSON header line naming the lark version and the
grammar's SHA-256; tables built by another lark or from another grammar are
ignored (``load`` returns None and the caller analyses the grammar itself),
so a stale or foreign file can cost time but never parse wrongly.

This module imports nothing from the package: the build runs it by path
(through runpy, so that this folder is not put on sys.path).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import pickle
import sys
from pathlib import Path

import lark

#: The options of gammac's parser; the tables depend on them.
LARK_OPTIONS = dict(parser="lalr", propagate_positions=True, maybe_placeholders=True)

TABLES_NAME = "gamma.lalr"
_MAGIC = "gamma-lalr-tables"


def _header(grammar_text: str) -> dict:
    return {"magic": _MAGIC, "lark": lark.__version__,
            "grammar_sha256": hashlib.sha256(grammar_text.encode("utf-8")).hexdigest(),
            "options": {k: LARK_OPTIONS[k] for k in sorted(LARK_OPTIONS)}}


def build(grammar_text: str, **extra) -> lark.Lark:
    """Analyse the grammar (slow); ``extra`` are options tables don't depend on."""
    return lark.Lark(grammar_text, **LARK_OPTIONS, **extra)


def save(grammar_text: str, out: Path) -> None:
    """Write the tables to ``out`` atomically (a half-written file is never left)."""
    body = io.BytesIO()
    build(grammar_text).save(body)
    tmp = out.with_name(out.name + f".tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        f.write(json.dumps(_header(grammar_text), sort_keys=True).encode("utf-8") + b"\n")
        f.write(body.getvalue())
    os.replace(tmp, out)


def load(tables: Path, grammar_text: str, **extra) -> lark.Lark | None:
    """The parser from prebuilt tables, or None when they are missing or were
    built from another grammar, by another lark or with other options.
    ``extra`` may only hold options lark accepts on load (e.g. lexer_callbacks)."""
    try:
        with open(tables, "rb") as f:
            header = json.loads(f.readline().decode("utf-8"))
            if header != _header(grammar_text):
                return None
            return lark.Lark.load(f, **extra)
    except (OSError, ValueError, EOFError, pickle.UnpicklingError, KeyError, TypeError, AttributeError,
            lark.exceptions.ConfigurationError, ImportError):
        # pickle from another lark release can fail in any of these ways; the
        # caller falls back to analysing the grammar.
        return None


def main(argv: list[str]) -> int:
    if len(argv) != 3:
        print("usage: lalr_tables.py GRAMMAR.lark OUT.lalr", file=sys.stderr)
        return 2
    save(Path(argv[1]).read_text(encoding="utf-8"), Path(argv[2]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
