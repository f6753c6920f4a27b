"""The grammar's LALR tables built with the package (gamma/frontend/lalr_tables.py):
installed, used by a fresh gammac, equal to a fresh analysis, and ignored
(never trusted) when they do not match the grammar or are damaged."""

import subprocess
import sys

import pytest

from conftest import ROOT
from gamma.frontend import lalr_tables, parser as gamma_parser

GRAMMAR = gamma_parser.grammar_path()
TEXT = GRAMMAR.read_text(encoding="utf-8")
INSTALLED = GRAMMAR.with_name(lalr_tables.TABLES_NAME)
EXAMPLES = sorted((ROOT / "examples").glob("*.gamma")) + sorted((ROOT / "stdlib").glob("*.gamma"))


def test_the_package_ships_tables_matching_its_grammar():
    assert INSTALLED.is_file(), f"{INSTALLED} missing: the build did not install the tables"
    assert lalr_tables.load(INSTALLED, TEXT) is not None


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_prebuilt_tables_parse_like_a_fresh_analysis(path):
    source = path.read_text(encoding="utf-8")
    prebuilt = lalr_tables.load(INSTALLED, TEXT)
    fresh = lalr_tables.build(TEXT)
    a, b = prebuilt.parse(source), fresh.parse(source)
    assert a == b
    # positions too: diagnostics and the formatter depend on them
    assert [(t.line, t.column, t.end_line, t.end_column) for t in a.scan_values(lambda v: True)] == \
           [(t.line, t.column, t.end_line, t.end_column) for t in b.scan_values(lambda v: True)]


def test_tables_of_another_grammar_are_ignored(tmp_path):
    other = TEXT + "\n// a change\n"
    tables = tmp_path / "gamma.lalr"
    lalr_tables.save(other, tables)
    assert lalr_tables.load(tables, other) is not None
    assert lalr_tables.load(tables, TEXT) is None


@pytest.mark.parametrize("damage", [b"", b"not json\n", b'{"magic": 1}\n',
                                    "trailing pickle garbage"])
def test_damaged_tables_are_ignored(tmp_path, damage):
    tables = tmp_path / "gamma.lalr"
    if isinstance(damage, str):          # a right header over a truncated pickle
        lalr_tables.save(TEXT, tables)
        data = tables.read_bytes()
        damage = data[:data.index(b"\n") + 1] + data[data.index(b"\n") + 1:][:100]
    tables.write_bytes(damage)
    assert lalr_tables.load(tables, TEXT) is None


def test_missing_tables_fall_back_to_analysis(tmp_path):
    assert lalr_tables.load(tmp_path / "absent.lalr", TEXT) is None


def test_fresh_gammac_check_does_not_analyse_the_grammar(tmp_path):
    # With every cache off, a fresh process must still not run the LALR analysis:
    # the installed tables are part of the package, not a cache.
    code = (
        "import sys\n"
        "from gamma.frontend import lalr_tables\n"
        "def refuse(*a, **k): raise SystemExit('grammar analysed at start-up')\n"
        "lalr_tables.build = refuse\n"
        "from gamma.cli import main\n"
        f"sys.exit(main(['check', {str(ROOT / 'examples' / 'patina.gamma')!r}]))\n")
    env = {"GAMMA_CACHE_DIR": "off", "PATH": "/usr/bin:/bin"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
