"""Every ```gamma block of language/SPEC.md is a complete file that checks;
every ```gamma-error block is rejected with the message SPEC gives for it
(the "→ `MESSAGE`" line after the block)."""

import re

import pytest

from conftest import ROOT, run_gammac

SPEC = (ROOT / "language" / "SPEC.md").read_text(encoding="utf-8")
GOOD = re.findall(r"```gamma\n(.*?)```", SPEC, re.S)
BAD = re.findall(r"```gamma-error\n(.*?)```", SPEC, re.S)
#: The message SPEC names for each error example: "→ `...`" right after it.
BAD_MESSAGES = [" ".join(m.split()) for m in
                re.findall(r"```gamma-error\n.*?```\s*→\s*`([^`]*)`", SPEC, re.S)]


def test_spec_has_examples():
    assert len(GOOD) >= 5


@pytest.mark.parametrize("index", range(len(GOOD)))
def test_spec_example_checks(tmp_path, index):
    (tmp_path / "example.gamma").write_text(GOOD[index])
    r = run_gammac("check", tmp_path / "example.gamma")
    assert r.returncode == 0, GOOD[index] + r.stderr


def test_every_error_example_names_its_message():
    assert len(BAD_MESSAGES) == len(BAD) >= 5


@pytest.mark.parametrize("index", range(len(BAD)))
def test_spec_error_example_is_diagnosed(tmp_path, index):
    (tmp_path / "example.gamma").write_text(BAD[index])
    r = run_gammac("check", tmp_path / "example.gamma")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    first = r.stderr.splitlines()[0]
    assert ": error: " in first
    # SPEC's message, with its "…" standing for text that varies
    pattern = ".*".join(re.escape(part) for part in BAD_MESSAGES[index].split("…"))
    assert re.search(pattern, " ".join(r.stderr.split())), (BAD_MESSAGES[index], r.stderr)
