"""gammac fmt: the canonical layout (gamma.frontend.fmt.format_source).

Formatting is idempotent, keeps every comment and keeps the meaning: the
formatted file parses to the same AST as the original, positions aside.
"""

import dataclasses
import re

import pytest

from conftest import ROOT
from gamma.frontend.diagnostics import GammaError
from gamma.frontend.fmt import format_source
from gamma.frontend.parser import parse


def _dump(node):
    """The AST without source positions, as nested tuples."""
    if dataclasses.is_dataclass(node):
        return (type(node).__name__,) + tuple(
            (f.name, _dump(getattr(node, f.name))) for f in dataclasses.fields(node)
            if f.name != "pos" and not f.name.endswith("_pos"))
    if isinstance(node, (list, tuple)):
        return tuple(_dump(x) for x in node)
    return node


def _ast(text):
    return _dump(parse(text).decls)


def _parses(text):
    try:
        parse(text)
    except GammaError:
        return False
    return True


def _corpus():
    files = sorted(ROOT.glob("examples/*.gamma")) + sorted(ROOT.glob("stdlib/*.gamma"))
    files += sorted((ROOT / "tests" / "diagnostics").glob("*.gamma"))
    files.append(ROOT / "tests" / "golden" / "effect.gamma")
    cases = [(str(f.relative_to(ROOT)), f.read_text(encoding="utf-8")) for f in files]
    spec = (ROOT / "language" / "SPEC.md").read_text(encoding="utf-8")
    for i, block in enumerate(re.findall(r"```gamma(?:-error)?\n(.*?)```", spec, re.S)):
        cases.append((f"SPEC.md#{i}", block))
    return [pytest.param(text, id=name) for name, text in cases if _parses(text)]


CORPUS = _corpus()


def test_corpus_is_not_empty():
    assert len(CORPUS) >= 10


@pytest.mark.parametrize("text", CORPUS)
def test_idempotent(text):
    once = format_source(text)
    assert format_source(once) == once


@pytest.mark.parametrize("text", CORPUS)
def test_meaning_preserved(text):
    assert _ast(format_source(text)) == _ast(text)


@pytest.mark.parametrize("text", CORPUS)
def test_comments_preserved(text):
    out = format_source(text)
    assert out.count("//") == text.count("//")
    assert out.count("/*") == text.count("/*")
    assert out.count("*/") == text.count("*/")


@pytest.mark.parametrize("text", CORPUS)
def test_layout_basics(text):
    out = format_source(text)
    assert out.endswith("\n") and not out.endswith("\n\n")
    assert "\n\n\n" not in out
    for line in out.splitlines():
        assert line == line.rstrip()
        indent = len(line) - len(line.lstrip(" "))
        assert "\t" not in line[:indent]


def test_canonical_file_is_unchanged_but_for_top_level_blank_lines():
    text = (ROOT / "tests" / "golden" / "effect.gamma").read_text(encoding="utf-8")
    # every top-level declaration is one blank line from the next, one-liners too
    expected = text.replace("count 1500\nsource", "count 1500\n\nsource")
    assert expected != text
    assert format_source(text) == expected


MESSY = """\
// header comment


param   rate=0.015   // trailing
param k = (1.50) ; param z=-(2e-3)
import "rust.gamma"(rate=0.03 ,wetting= .1)
ton Rain{motion parabolic=0.8,flow=0.2; carry humidity = 1.  // carried
  /* own line block */
  bounce relative( 0.02 ) step relative(0.005)}
surface Iron { }
surface Empty {
   // nothing yet
}
source shower=area(rect,position=(-0.3,2.0,0.75),normal=down,size=(0.3,0.3))
    emits Rain count 100 from 2 until (10)
on hit(t:Rain,s:*){ // the rule
    let w = ((a + b) + (c + d)) * (e)


    if (a < b) and not (c or d) { x = 1; y += 2 } else if a == b { } else { z -= -(-1) }
    t.rust += (s.rust - (t.rust - 1)) / (2 * (3 / 4))  /* block */ // line
    // at end of block
}
update(s:Iron){}
// end of file
"""

MESSY_FORMATTED = """\
// header comment

param rate = 0.015  // trailing

param k = 1.50

param z = -2e-3

import "rust.gamma" (rate = 0.03, wetting = .1)

ton Rain {
    motion parabolic = 0.8, flow = 0.2
    carry humidity = 1.  // carried
    /* own line block */
    bounce relative(0.02)
    step relative(0.005)
}

surface Iron { }

surface Empty {
    // nothing yet
}

source shower = area(rect, position = (-0.3, 2.0, 0.75), normal = down, size = (0.3, 0.3)) \
emits Rain count 100 from 2 until 10

on hit(t: Rain, s: *) {  // the rule
    let w = (a + b + (c + d)) * e

    if a < b and not (c or d) {
        x = 1
        y += 2
    } else if a == b { } else {
        z -= - -1
    }
    t.rust += (s.rust - (t.rust - 1)) / (2 * (3 / 4))  /* block */  // line
    // at end of block
}

update(s: Iron) { }
// end of file
"""


def test_messy_input():
    assert format_source(MESSY) == MESSY_FORMATTED
    assert format_source(MESSY_FORMATTED) == MESSY_FORMATTED
    assert _ast(MESSY_FORMATTED) == _ast(MESSY)
    assert MESSY_FORMATTED.count("//") == MESSY.count("//")
    assert MESSY_FORMATTED.count("/*") == MESSY.count("/*")


def test_else_if_chain_and_comments_in_odd_places():
    text = """\
on hit(t: T, s: *) {
  if a { x = 1 } // after then
  else
  // between else and if
  if b { x = 2 }
  else if c
  { x = 3 } else { /* empty else */ }
  y = 1 +   // inside an expression
    2
}
param p = 1 +
  // own line, inside an expression
  2
"""
    expected = """\
on hit(t: T, s: *) {
    if a {
        x = 1
        // between else and if
    } else if b {  // after then
        x = 2
    } else if c {
        x = 3
    } else { }  /* empty else */
    y = 1 + 2  // inside an expression
}

// own line, inside an expression
param p = 1 + 2
"""
    out = format_source(text)
    assert out == expected
    assert format_source(out) == out
    assert _ast(out) == _ast(text)


def test_blank_lines_inside_blocks_kept_at_most_one():
    text = "on hit(t: T, s: S) {\n\n\n  x = 1\n\n\n\n  y = 2\n  z = 3\n\n}\n"
    assert format_source(text) == "on hit(t: T, s: S) {\n    x = 1\n\n    y = 2\n    z = 3\n}\n"


def test_top_level_declarations_one_blank_line_apart():
    text = "param a = 1\n\n\n\nparam b = 2\nparam c = 3\n"
    assert format_source(text) == "param a = 1\n\nparam b = 2\n\nparam c = 3\n"


@pytest.mark.parametrize("expr, shown", [
    ("(a - b) - c", "a - b - c"),
    ("a - (b - c)", "a - (b - c)"),
    ("a / (b * c)", "a / (b * c)"),
    ("(a * b) / c", "a * b / c"),
    ("-(a + b)", "-(a + b)"),
    ("-(a * b)", "-(a * b)"),
    ("(-a) * b", "-a * b"),
    ("+a", "a"),
    ("--a", "- -a"),
    ("(a < b) == (c < d)", "(a < b) == (c < d)"),
    ("(a + 1) < (b * 2)", "a + 1 < b * 2"),
    ("not (a < b)", "not a < b"),
    ("not (a and b)", "not (a and b)"),
    ("(not a) and b", "not a and b"),
    ("a or (b or c)", "a or (b or c)"),
    ("(a or b) and c", "(a or b) and c"),
    ("a or (b and c)", "a or b and c"),
    ("-(a < b)", "-(a < b)"),
    ("f((a), (b + c), (1, 2))", "f(a, b + c, (1, 2))"),
    ("g( )", "g()"),
    ("1.", "1."),
    (".5e+3", ".5e+3"),
    ("007", "007"),
])
def test_expressions_minimal_parentheses(expr, shown):
    text = f"on hit(t: T, s: S) {{ x = {expr} }}\n"
    out = format_source(text)
    assert out == f"on hit(t: T, s: S) {{\n    x = {shown}\n}}\n"
    assert _ast(out) == _ast(text)


def test_numbers_kept_as_written():
    text = "param a = 0.10000000000000000001\nparam b = 1E5\nparam c = 3.\n"
    assert format_source(text) == "param a = 0.10000000000000000001\n\nparam b = 1E5\n\nparam c = 3.\n"


def test_ton_items_keep_their_order():
    text = "ton T { carry b = 1 motion straight = 1; carry a = 2 step 0.1 bounce 0.2 step 0.3 }"
    out = format_source(text)
    assert out == ("ton T {\n    carry b = 1\n    motion straight = 1\n    carry a = 2\n"
                   "    step 0.1\n    bounce 0.2\n    step 0.3\n}\n")
    assert _ast(out) == _ast(text)


def test_source_with_repeated_windows_and_no_arguments():
    text = "source s = f() emits T count 1 until 4 from 2 until 5;"
    out = format_source(text)
    assert out == "source s = f() emits T count 1 until 4 from 2 until 5\n"
    assert _ast(out) == _ast(text)


def test_import_without_arguments():
    assert format_source('import   "a.gamma" ;') == 'import "a.gamma"\n'


def test_crlf_and_empty_inputs():
    assert format_source("param a = 1\r\n// c\r\nparam b = 2\r\n") == "param a = 1\n\n// c\nparam b = 2\n"
    assert format_source("") == ""
    assert format_source("// only a comment\n") == "// only a comment\n"


def test_syntax_error_raises_gamma_error():
    with pytest.raises(GammaError) as info:
        format_source("ton T { motion a = }\n", "bad.gamma")
    assert "bad.gamma" in str(info.value)


def test_components_of_expressions_keep_their_meaning():
    text = ("on hit(t: T, s: S) {\n    let v = (1, 2, 3)\n"
            "    t.a = (v + up).x + cross(v, up).y+( v ).z - -(1,2,3).x * normalize(v).z\n}\n")
    out = format_source(text)
    assert "(v + up).x + cross(v, up).y + (v).z - -(1, 2, 3).x * normalize(v).z" in out
    assert _ast(out) == _ast(text) and format_source(out) == out
