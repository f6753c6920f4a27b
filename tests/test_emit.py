"""``gammac emit``: the compiler can be looked inside."""

import pytest

from conftest import ROOT, run_gammac

PATINA = ROOT / "examples" / "patina.gamma"


@pytest.mark.parametrize("flag,needle", [("--ir", "define external i32 @\"gamma.settle.Weather.Copper\""),
                                         ("--ir-opt", "i32 @gamma.settle.Weather.Copper("),
                                         ("--asm", "gamma.settle.Weather.Copper:")])
def test_emit(flag, needle):
    r = run_gammac("emit", flag, PATINA)
    assert r.returncode == 0, r.stderr
    assert needle in r.stdout


def test_ir_points_back_to_the_source():
    r = run_gammac("emit", "--ir", PATINA)
    line = next(i for i, l in enumerate(PATINA.read_text().splitlines(), 1) if "s.patina +=" in l)
    assert f"; {line}:5: s.patina += ..." in r.stdout


def test_emit_ast_shows_positions():
    r = run_gammac("emit", "--ast", PATINA)
    assert r.returncode == 0, r.stderr
    assert "TonDecl @" in r.stdout and "RuleDecl @" in r.stdout and "event: 'settle'" in r.stdout


def test_emit_effect_shows_the_typed_resolved_ir():
    r = run_gammac("emit", "--effect", PATINA)
    assert r.returncode == 0, r.stderr
    line = next(i for i, l in enumerate(PATINA.read_text().splitlines(), 1) if "s.patina +=" in l)
    kernel = r.stdout[r.stdout.index("kernel on settle(Weather, Copper) -> gamma.settle.Weather.Copper"):]
    # the property and the carried attribute bound to their slots, the statement numbered
    assert "#1 surf:patina[3] += " in kernel and "ton:patina[0]" in kernel
    assert f"{PATINA}:{line}:5" in kernel
