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


def test_every_declaration_kind_formats(tmp_path):
    """One of each top-level declaration of the grammar, so a new one cannot be forgotten."""
    import re

    grammar = (ROOT / "language" / "gamma.lark").read_text()
    kinds = set(re.findall(r"^\s*\|?\s*(\w+_decl)\s*$", grammar.split("?decl:")[1].split("\n\n")[0], re.M))
    text = ('param k = 1\nimport "patina.gamma"\nassign "chain*" = Copper\nton T {\n    carry a = k\n}\n'
            'source s = point(0, 0, 0) emits T count 1\non hit(t: T, s: Copper) {\n    s.patina += t.a\n}\n'
            'update(s: Copper) {\n    s.patina *= 0.5\n}\n'
            'appearance(s: Copper) {\n    color = rgb(0.2, 0.6, 0.5) * s.patina\n}\n')
    covered = {"param_decl", "import_decl", "assign_decl", "ton_decl", "surface_decl", "source_decl",
               "rule_decl", "update_decl", "appearance_decl"}
    assert kinds <= covered, kinds - covered
    path = tmp_path / "all.gamma"
    path.write_text(text)
    r = run_gammac("fmt", path)
    assert r.returncode == 0, r.stderr
    assert 'assign "chain*" = Copper' in r.stdout
