"""Bounded fuzzing of `gammac check`: on arbitrary bytes and on mutated valid
files it must answer with the project's own diagnostics (exit 0, 1 or 2) and
never with a Python exception.  Runs in-process, seeded, a few seconds."""

import contextlib
import io
import random

import pytest

from conftest import ROOT
from gamma.cli import main

VALID = sorted((ROOT / "examples").glob("*.gamma")) + sorted((ROOT / "stdlib").glob("*.gamma")) + \
    [ROOT / "tests" / "golden" / "effect.gamma"]
TOKENS = ["{", "}", "(", ")", ",", ";", "=", "+=", "-=", "*=", "==", "<", "*", "/", "-", ".", "1e99",
          "0", "nan", "relative(", "ton", "surface", "source", "on", "update", "let", "if", "else",
          "import", "param", "\"x.gamma\"", "t.", "s.", "*", "\n", " ", "//", "/*", "\"", "\x00", "é"]


def check_text(tmp_path, data: bytes) -> int:
    path = tmp_path / "fuzz.gamma"
    path.write_bytes(data)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(["check", str(path)])
        except SystemExit as exit_:       # argparse
            code = exit_.code
    assert code in (0, 1, 2), (data, err.getvalue())
    if code == 1:
        assert "error" in err.getvalue(), data
    return code


def mutate(text: str, rng: random.Random) -> str:
    for _ in range(rng.randint(1, 4)):
        i = rng.randrange(len(text) + 1)
        j = min(len(text), i + rng.randint(0, 12))
        choice = rng.random()
        if choice < 0.35:
            text = text[:i] + text[j:]                       # delete a span
        elif choice < 0.7:
            text = text[:i] + rng.choice(TOKENS) + text[i:]  # insert a token
        else:
            k = rng.randrange(len(text) + 1)                 # duplicate a span elsewhere
            text = text[:k] + text[i:j] + text[k:]
    return text


def test_arbitrary_bytes(tmp_path):
    rng = random.Random(1)
    for _ in range(300):
        check_text(tmp_path, bytes(rng.randrange(256) for _ in range(rng.randint(0, 200))))


@pytest.mark.parametrize("seed", range(4))
def test_mutated_valid_files(tmp_path, seed):
    rng = random.Random(seed)
    outcomes = set()
    for _ in range(150):
        original = rng.choice(VALID).read_text()
        outcomes.add(check_text(tmp_path, mutate(original, rng).encode("utf-8", "surrogatepass")))
    assert 1 in outcomes          # the mutations do produce errors


# ---- the shipped fuzzer (tests/fuzz_gamma.py; `make fuzz` runs it longer) ----

import fuzz_gamma  # noqa: E402


def test_grammar_aware_fuzzer_fixed_budget(tmp_path):
    """A fixed number of grammar-aware mutants and random byte strings; a
    quarter of those that check also go through emit --ir and fmt."""
    failures = fuzz_gamma.fuzz(cases=300, seconds=None, seed=2026, folder=tmp_path)
    assert not failures, failures[0][1] + "\n" + repr(failures[0][0][:500])


REGRESSION_FILES = sorted(fuzz_gamma.REGRESSIONS.glob("*.gamma"))


def test_regressions_exist():
    assert len(REGRESSION_FILES) >= 5


@pytest.mark.parametrize("path", REGRESSION_FILES, ids=lambda p: p.name)
def test_fuzz_regression(tmp_path, path):
    """Every input the fuzzer (or a user) once broke the compiler with."""
    problem = fuzz_gamma.examine(tmp_path / "case.gamma", path.read_bytes(), deep=True)
    assert problem is None, problem


# ---- the mesh fuzzer (tests/fuzz_meshes.py; `make fuzz` runs it longer) ----

def test_mesh_fuzzer_fixed_budget(tmp_path):
    """A fixed number of mutants of the valid OBJ, PLY and glTF files of
    tests/mesh_corpus.py, loaded as `gammac run --scene` loads them, in
    children with a memory and a time limit: each ends in a mesh or one
    line naming the file, with nothing else on stderr."""
    import fuzz_meshes

    failures = fuzz_meshes.fuzz(seconds=None, seed=2026, folder=tmp_path, save=None, cases=240)
    assert not failures, failures[0]
