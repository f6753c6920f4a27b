"""`gammac fmt`: stdlib/ and examples/ are kept in canonical layout; --check and --write."""

import pytest

from conftest import ROOT, run_gammac

FILES = sorted((ROOT / "stdlib").glob("*.gamma")) + sorted((ROOT / "examples").glob("*.gamma"))


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_repository_files_are_formatted(path):
    r = run_gammac("fmt", "--check", path)
    assert r.returncode == 0, r.stderr


def test_check_and_write(tmp_path):
    messy = tmp_path / "m.gamma"
    messy.write_text("ton T{motion straight=1;carry a=1}  // note\n")
    assert run_gammac("fmt", "--check", messy).returncode == 1
    assert run_gammac("fmt", "--write", messy).returncode == 0
    assert messy.read_text() == "ton T {\n    motion straight = 1\n    carry a = 1\n}  // note\n"
    assert run_gammac("fmt", "--check", messy).returncode == 0


def test_syntax_error_is_a_diagnostic(tmp_path):
    bad = tmp_path / "b.gamma"
    bad.write_text("ton T { motion = }\n")
    r = run_gammac("fmt", bad)
    assert r.returncode == 1 and "error:" in r.stderr and "Traceback" not in r.stderr
