"""The fuzzer of the compiler's front end: a grammar-aware mutator plus random
bytes over the examples and the standard library.

Every generated file goes through ``gammac check`` in-process (and, for a
share of them, ``emit --ir`` and ``fmt``).  A case *fails* when the command
raises a Python exception (a traceback for the user), exits with a status
SPEC §16.2 does not list, prints an exit-1 result without a positioned
error, or -- for a file that checks -- ``fmt`` output that does not check
again or is not a fixed point.

``make test`` runs a fixed number of cases (tests/test_fuzz.py); ``make fuzz``
runs this script for a time budget:

    python tests/fuzz_gamma.py --seconds 600 [--seed N] [--save tests/fuzz_regressions]

Each failure is written to the --save folder as ``crash-HASH.gamma``; checked
in, it becomes a regression test (tests/test_fuzz.py runs every file there).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import random
import re
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SEEDS = sorted((ROOT / "examples").glob("*.gamma")) + sorted((ROOT / "stdlib").glob("*.gamma")) + \
    [ROOT / "tests" / "golden" / "effect.gamma"]
REGRESSIONS = Path(__file__).resolve().parent / "fuzz_regressions"

TOKEN = re.compile(r'//[^\n]*|/\*.*?\*/|"[^"\n]*"|[A-Za-z_][A-Za-z_0-9]*|'
                   r'(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+\-*/]=|[<>=!]=|\s+|.', re.S)
#: Numbers that stress constant folding, float32 conversion and the limits.
NUMBERS = ["0", "-0", "1", "1e39", "3.4e38", "1e-45", "1e-46", "0.5", "999999999999", "1e12", "1e13",
           "4294967296", "2147483648", "-1", "1e308", "1e309", "00001", "1.", ".5"]
ODD = ["\x00", "\ufeff", "\u2028", "\x85", "\f", "\r", "\t", "é", "\U0001f600", "\\", "@", "#", "$", "`",
       "/*", "*/", "//", "\"", "'", "\n" * 3]


def grammar_words() -> tuple[list[str], list[str]]:
    """Keywords and punctuation of the grammar (language/gamma.lark)."""
    text = (ROOT / "language" / "gamma.lark").read_text(encoding="utf-8")
    words = sorted(set(re.findall(r'"([A-Za-z_]+)"', text)))
    punct = sorted(set(re.findall(r'"([^"\sA-Za-z0-9]{1,2})"', text)))
    return words, punct


KEYWORDS, PUNCTUATION = grammar_words()


def tokens(text: str) -> list[str]:
    return TOKEN.findall(text)


def declarations(text: str) -> list[str]:
    """Top-level declarations (a line starting with a keyword begins one)."""
    starts = [m.start() for m in re.finditer(r"^(?=[a-z])", text, re.M)] + [len(text)]
    return [text[a:b] for a, b in zip(starts, starts[1:]) if text[a:b].strip()]


class Mutator:
    def __init__(self, rng: random.Random, seeds: list[str]):
        self.rng = rng
        self.seeds = seeds
        self.names = sorted({t for s in seeds for t in tokens(s) if t.isidentifier()})
        self.decls = [d for s in seeds for d in declarations(s)]

    def token_edit(self, toks: list[str]) -> list[str]:
        rng = self.rng
        if not toks:
            return [rng.choice(KEYWORDS)]
        i = rng.randrange(len(toks))
        kind = rng.random()
        if kind < 0.2:
            del toks[i:i + rng.randint(1, 3)]
        elif kind < 0.35:
            toks.insert(i, rng.choice(KEYWORDS + PUNCTUATION) + rng.choice(["", " "]))
        elif kind < 0.5:
            j = rng.randrange(len(toks))
            toks[i], toks[j] = toks[j], toks[i]
        elif kind < 0.62:
            numbers = [k for k, t in enumerate(toks) if t[:1].isdigit()]
            if numbers:
                toks[rng.choice(numbers)] = rng.choice(NUMBERS)
        elif kind < 0.74:
            names = [k for k, t in enumerate(toks) if t.isidentifier()]
            if names:
                toks[rng.choice(names)] = rng.choice(self.names)
        elif kind < 0.82:
            toks.insert(i, rng.choice(ODD))
        elif kind < 0.9:
            j = min(len(toks), i + rng.randint(1, 30))
            toks[i:i] = toks[i:j]                       # duplicate a run of tokens
        else:
            depth = rng.choice([5, 50, 100, 400])        # nesting
            opener, closer = rng.choice([("(", ")"), ("{", "}"), ("if 1 > 0 {", "}"), ("-(", ")"),
                                         ("not ", "")])
            toks.insert(i, opener * depth)
            toks.insert(min(len(toks), i + 2), closer * depth)
        return toks

    def mutant(self) -> bytes:
        rng = self.rng
        choice = rng.random()
        if choice < 0.1:                                 # random bytes
            return bytes(rng.randrange(256) for _ in range(rng.randint(0, 300)))
        text = rng.choice(self.seeds)
        if choice < 0.3:                                 # cross-over of declarations
            decls = declarations(text)
            for _ in range(rng.randint(1, 3)):
                if decls and rng.random() < 0.5:
                    del decls[rng.randrange(len(decls))]
                else:
                    decls.insert(rng.randrange(len(decls) + 1), rng.choice(self.decls))
            text = "".join(decls)
        toks = tokens(text)
        if choice < 0.55:                                # keeps the syntax: names and numbers
            for _ in range(rng.randint(1, 4)):
                numbers = [k for k, t in enumerate(toks) if t[:1].isdigit()]
                names = [k for k, t in enumerate(toks) if t.isidentifier() and t not in KEYWORDS]
                if numbers and (rng.random() < 0.5 or not names):
                    toks[rng.choice(numbers)] = rng.choice(NUMBERS)
                elif names:
                    toks[rng.choice(names)] = rng.choice(self.names)
        else:
            for _ in range(rng.randint(1, 3)):
                toks = self.token_edit(toks)
        data = "".join(toks).encode("utf-8", "surrogatepass")
        if rng.random() < 0.05:                          # a broken encoding
            k = rng.randrange(len(data) + 1)
            data = data[:k] + bytes([rng.randrange(128, 256)]) + data[k:]
        return data


def run_cli(args: list[str]) -> tuple[int, str, str]:
    from gamma.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(args)
        except SystemExit as exit_:
            code = exit_.code
    return code, out.getvalue(), err.getvalue()


def examine(path: Path, data: bytes, deep: bool) -> str | None:
    """None if the compiler answered properly, else what went wrong."""
    path.write_bytes(data)
    try:
        code, _, err = run_cli(["check", str(path)])
        if code not in (0, 1, 2):
            return f"check exited {code}"
        if code == 1 and not re.search(r":\d+:\d+: error: |^gammac: error: ", err, re.M):
            return f"check exit 1 without a positioned error: {err[:300]}"
        if code != 0 or not deep:
            return None
        code, _, err = run_cli(["emit", "--ir", str(path)])
        if code != 0:
            return f"emit --ir exited {code} on a file that checks: {err[:300]}"
        code, formatted, err = run_cli(["fmt", str(path)])
        if code != 0:
            return f"fmt exited {code} on a file that checks: {err[:300]}"
        path.write_text(formatted, encoding="utf-8")
        code, _, err = run_cli(["check", str(path)])
        if code != 0:
            return f"fmt output does not check: {err[:300]}"
        code, again, _ = run_cli(["fmt", str(path)])
        if again != formatted:
            return "fmt is not idempotent"
        return None
    except BaseException as exc:                         # noqa: BLE001 - any escape is the finding
        if isinstance(exc, KeyboardInterrupt):
            raise
        return "".join(traceback.format_exception(exc))[-1500:]


def fuzz(cases: int | None, seconds: float | None, seed: int, folder: Path, save: Path | None = None,
         deep_share: float = 0.25) -> list[tuple[bytes, str]]:
    rng = random.Random(seed)
    mutator = Mutator(rng, [p.read_text(encoding="utf-8") for p in SEEDS])
    failures = []
    deadline = time.monotonic() + seconds if seconds else None
    path = folder / "fuzz.gamma"
    n = 0
    while (cases is None or n < cases) and (deadline is None or time.monotonic() < deadline):
        data = mutator.mutant()
        problem = examine(path, data, deep=rng.random() < deep_share)
        n += 1
        if problem:
            failures.append((data, problem))
            if save is not None:
                save.mkdir(parents=True, exist_ok=True)
                name = f"crash-{hashlib.sha256(data).hexdigest()[:12]}.gamma"
                (save / name).write_bytes(data)
                print(f"FAIL {name}: {problem.splitlines()[-1]}", file=sys.stderr)
    print(f"{n} cases, {len(failures)} failures", file=sys.stderr)
    return failures


def main() -> int:
    import tempfile

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=300)
    p.add_argument("--seed", type=int, default=int(time.time()))
    p.add_argument("--save", type=Path, default=REGRESSIONS)
    args = p.parse_args()
    print(f"fuzzing the compiler for {args.seconds:g} s, seed {args.seed}", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        failures = fuzz(None, args.seconds, args.seed, Path(tmp), args.save)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
