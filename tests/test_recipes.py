"""The standard library: at least ten documented recipes, each importable
alone without warnings, all importable together, listed by `gammac recipes`,
and each matching its golden run (tests/golden/recipes, regenerated only by
tests/golden/make_recipe_reference.py)."""

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, run_gammac

GOLDEN = Path(__file__).parent / "golden"
sys.path.insert(0, str(GOLDEN))
from make_recipe_reference import COUNTERS, digest, recipes, run_recipe  # noqa: E402

RECIPES = recipes()


def test_at_least_ten_recipes():
    assert len(RECIPES) >= 10, RECIPES


@pytest.mark.parametrize("stem", RECIPES)
def test_recipe_imports_alone_without_warnings(tmp_path, stem):
    (tmp_path / "main.gamma").write_text(f'import "{stem}.gamma"\n')
    r = run_gammac("check", "main.gamma", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", r.stderr


def test_all_recipes_import_together(tmp_path):
    """No two recipes declare the same ton type, surface or source."""
    (tmp_path / "main.gamma").write_text("".join(f'import "{s}.gamma"\n' for s in RECIPES))
    r = run_gammac("check", "main.gamma", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", r.stderr


def test_every_recipe_documents_itself():
    """A summary and a usage line at the top, every parameter with a default
    and a comment, declared before anything else."""
    from gamma.frontend.recipes import stdlib_recipes

    listed = stdlib_recipes(ROOT / "stdlib")
    assert [r.path.stem for r in listed] == RECIPES
    for r in listed:
        assert len(r.summary) > 20, r.name
        assert f'import "{r.name}"' in r.doc, r.name
        assert r.params, r.name
        for p in r.params:
            assert p.doc, f"{r.name}: parameter {p.name} has no comment"
        text = r.path.read_text().splitlines()
        first_decl = next(i for i, line in enumerate(text) if line and not line.startswith(("//", "param")))
        last_param = max(i for i, line in enumerate(text) if line.startswith("param"))
        assert last_param < first_decl, f"{r.name}: parameters belong at the top"


def test_gammac_recipes_lists_them_with_parameters():
    r = run_gammac("recipes")
    assert r.returncode == 0, r.stderr
    for stem in RECIPES:
        assert f"{stem}.gamma  " in r.stdout
    assert re.search(r"param rate = 0.04 +rust per unit of humidity and iteration", r.stdout)
    assert f"{len(RECIPES)} recipes" in r.stdout
    verbose = run_gammac("recipes", "--verbose")
    assert 'import "rust.gamma" (rate = 0.08)' in verbose.stdout


def test_gammac_recipes_json_is_the_same_listing_for_tools():
    """The Blender add-on's recipe list: every recipe, with a path it can run
    and the parameters as the text listing gives them."""
    r = run_gammac("recipes", "--json")
    assert r.returncode == 0, r.stderr
    listed = {entry["name"]: entry for entry in json.loads(r.stdout)}
    assert sorted(listed) == sorted(f"{stem}.gamma" for stem in RECIPES)
    rust = listed["rust.gamma"]
    assert Path(rust["path"]).is_absolute() and Path(rust["path"]).read_text().startswith("//")
    rate = next(p for p in rust["params"] if p["name"] == "rate")
    assert rate == {"name": "rate", "default": "0.04", "doc": "rust per unit of humidity and iteration"}
    assert rust["surfaces"] and rust["summary"].endswith(".")


@pytest.mark.parametrize("stem", RECIPES)
def test_recipe_matches_golden_run(tmp_path, stem):
    reference = GOLDEN / "recipes" / f"{stem}.json"
    assert reference.exists(), f"no golden run for {stem}: run tests/golden/make_recipe_reference.py {stem}"
    r = run_recipe(stem, tmp_path)
    assert r.returncode == 0, r.stderr
    got, want = digest(tmp_path / "out"), json.loads(reference.read_text())
    assert len(got["iterations"]) == len(want["iterations"])
    for i, (g, w) in enumerate(zip(got["iterations"], want["iterations"]), 1):
        assert {k: g["counters"][k] for k in COUNTERS} == w["counters"], f"iteration {i}"
        assert sorted(g["properties"]) == sorted(w["properties"])
        for name, wp in w["properties"].items():
            gp = g["properties"][name]
            # exact on this machine; the tolerance absorbs an Embree ISA
            # difference in the last bits of a hit point
            np.testing.assert_allclose([gp["sum"], *gp["quartiles"]], [wp["sum"], *wp["quartiles"]],
                                       rtol=1e-5, atol=1e-7, err_msg=f"{stem} iteration {i} {name}")
    # and the recipe changed something: a golden run of nothing proves nothing
    assert any(abs(p["sum"]) > 0 for p in got["iterations"][-1]["properties"].values())
