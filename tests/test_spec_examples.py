"""Every ```gamma block of language/SPEC.md is a complete file that checks;
every ```gamma-error block is rejected with diagnostics (not a crash)."""

import re

import pytest

from conftest import ROOT, run_gammac

SPEC = (ROOT / "language" / "SPEC.md").read_text(encoding="utf-8")
GOOD = re.findall(r"```gamma\n(.*?)```", SPEC, re.S)
BAD = re.findall(r"```gamma-error\n(.*?)```", SPEC, re.S)


def test_spec_has_examples():
    assert len(GOOD) >= 5


@pytest.mark.parametrize("index", range(len(GOOD)))
def test_spec_example_checks(tmp_path, index):
    (tmp_path / "example.gamma").write_text(GOOD[index])
    r = run_gammac("check", tmp_path / "example.gamma")
    assert r.returncode == 0, GOOD[index] + r.stderr


@pytest.mark.parametrize("index", range(len(BAD)))
def test_spec_error_example_is_diagnosed(tmp_path, index):
    (tmp_path / "example.gamma").write_text(BAD[index])
    r = run_gammac("check", tmp_path / "example.gamma")
    assert r.returncode == 1 and ": error: " in r.stderr and "Traceback" not in r.stderr
