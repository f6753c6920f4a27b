"""Parameters, imports (next to the file, then stdlib/), overrides and warnings."""

import pytest

from conftest import ROOT, run_gammac
from gamma.frontend.checker import load


def write(path, text):
    path.write_text(text)
    return path


def test_import_from_stdlib_with_override(tmp_path):
    main = write(tmp_path / "main.gamma", 'param fast = 0.2\nimport "patina.gamma" (rate = fast)\n')
    effect = load(str(main))
    assert set(effect.tons) == {"Weather"} and set(effect.surfaces) == {"Copper"}
    settle = next(k for k in effect.kernels if k.event == "settle")
    rate = settle.bodies[0][0].value.left                  # s.patina += rate * t.patina
    assert rate.value == pytest.approx(0.2)                 # the importer's value won, folded in
    assert effect.sources[0].count == 1_000_000             # the recipe's own default
    assert effect.surfaces["Copper"].initial_row[0] == 0.5   # trap, a parameter used in a declaration


def test_import_next_to_the_file_comes_first(tmp_path):
    write(tmp_path / "patina.gamma", "ton Local { motion straight = 1 carry x = 1 }\n")
    effect = load(str(write(tmp_path / "main.gamma", 'import "patina.gamma"\n')))
    assert set(effect.tons) == {"Local"}


def test_command_line_param_override(tmp_path):
    main = write(tmp_path / "m.gamma", 'param k = 0.05\nton T { motion straight = 1 carry a = 1 }\n'
                 'surface S { property p = 0 }\nsource s = environment(sphere) emits T count 10\n'
                 'on settle(t: T, s: S) { s.p += k * t.a }\n')
    effect = load(str(main), {"k": 0.5})
    assert effect.params == {"k": 0.5}
    r = run_gammac("check", main, "--param", "nope=1")
    assert r.returncode == 2 and "--param nope" in r.stderr and "Traceback" not in r.stderr


def test_import_errors_point_into_the_right_file(tmp_path):
    write(tmp_path / "lib.gamma", "ton T { motion straight = 2 }\n")
    write(tmp_path / "loop.gamma", 'import "loop.gamma"\n')
    main = write(tmp_path / "main.gamma", 'import "lib.gamma" (missing = 1)\nimport "loop.gamma"\n'
                 'import "nowhere.gamma"\n')
    r = run_gammac("check", main.name, cwd=tmp_path)
    assert r.returncode == 1
    assert "main.gamma:1:21: error: lib.gamma has no parameter 'missing'" in r.stderr
    assert "lib.gamma:1:27: error: motion probability 'straight' = 2 is outside [0, 1]" in r.stderr
    assert "loop.gamma:1:8: error: 'loop.gamma' imports itself" in r.stderr
    assert "main.gamma:3:8: error: cannot find 'nowhere.gamma'" in r.stderr


def test_warnings_do_not_fail_the_check(tmp_path):
    main = write(tmp_path / "w.gamma", "param unused = 1\nton T { motion straight = 1 carry a = 1 }\n"
                 "ton Silent { carry a = 1 }\nsurface S { property p = 0, idle = 0 }\n"
                 "source s = environment(sphere) emits T count 10\n"
                 "on hit(t: T, s: S) { s.p += t.a }\non hit(t: Silent, s: S) { s.p += t.a }\n")
    r = run_gammac("check", main.name, cwd=tmp_path)
    assert r.returncode == 0
    assert "w.gamma:1:7: warning: parameter 'unused' is never used" in r.stderr
    assert "w.gamma:4:29: warning: property 'idle' of S is never changed by any rule" in r.stderr
    assert "w.gamma:7:4: warning: this rule never fires for ton Silent: no source emits it" in r.stderr


def test_every_stdlib_recipe_checks():
    recipes = sorted((ROOT / "stdlib").glob("*.gamma"))
    assert recipes
    for recipe in recipes:
        assert run_gammac("check", recipe).returncode == 0, recipe
