"""Golden diagnostics: each tests/diagnostics/NAME.gamma holds one kind of
mistake (or several); NAME.err is the exact text ``gammac check`` must print,
positions included.  Regenerate a reference only after reading the diff."""

from pathlib import Path

import pytest

from conftest import run_gammac

CASES = sorted(Path(__file__).parent.joinpath("diagnostics").glob("*.gamma"))


def test_enough_kinds_of_mistake():
    assert len(CASES) >= 8


@pytest.mark.parametrize("case", CASES, ids=[c.stem for c in CASES])
def test_golden_diagnostic(case):
    result = run_gammac("check", case.name, cwd=case.parent)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr == case.with_suffix(".err").read_text()


def test_every_error_is_reported():
    text = (Path(__file__).parent / "diagnostics" / "every_error_reported.err").read_text()
    assert text.count(": error: ") == 4
