"""Regenerate the golden outputs of the stdlib recipes (run by hand after a
change that is meant to alter them, review the diff, say so in the commit):

    .venv/bin/python tests/golden/make_recipe_reference.py [RECIPE ...]

Each recipe is imported alone and run on tests/golden/open_box.obj (a floor,
four walls, open top: faces that look up, sideways and, from outside,
nothing looks down) with few surfels and gamma-tons; the reference keeps the
counters and, per property, its sum and quartiles after every iteration.
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
REFERENCE = HERE / "recipes"
SCENE = HERE / "open_box.obj"
ARGS = ["--surfels", "1500", "--iterations", "3", "--tons", "6000", "--seed", "5", "--threads", "2",
        "--size", "16", "--samples", "1", "--ao", "0", "--quiet"]
COUNTERS = ("emitted", "settled", "escaped", "capped", "interactions")


def recipes():
    return sorted(p.stem for p in (ROOT / "stdlib").glob("*.gamma"))


def run_recipe(stem: str, work: Path) -> subprocess.CompletedProcess:
    main = work / "main.gamma"
    main.write_text(f'import "{stem}.gamma"\n')
    return subprocess.run([sys.executable, "-m", "gamma.cli", "run", str(main), "--scene", str(SCENE),
                           "--out", str(work / "out"), *ARGS], capture_output=True, text=True)


def digest(out: Path) -> dict:
    from gamma.driver.outputs.outputs import read_ply

    summary = json.loads((out / "summary.json").read_text())
    result = {"iterations": []}
    for i, it in enumerate(summary["iterations"], 1):
        maps = read_ply(out / "maps" / f"iter_{i:04d}.ply")
        props = {}
        for name in it["property_sums"]:
            column = maps[name].astype(np.float64)
            props[name] = {"sum": float(column.sum()),
                           "quartiles": [float(q) for q in np.quantile(column, [0.25, 0.5, 0.75])]}
        result["iterations"].append({"counters": {k: it[k] for k in COUNTERS}, "properties": props})
    return result


if __name__ == "__main__":
    REFERENCE.mkdir(exist_ok=True)
    for stem in sys.argv[1:] or recipes():
        with tempfile.TemporaryDirectory() as work:
            r = run_recipe(stem, Path(work))
            if r.returncode != 0:
                sys.exit(f"{stem}: {r.stderr}")
            (REFERENCE / f"{stem}.json").write_text(json.dumps(digest(Path(work) / "out"), indent=1) + "\n")
        print(f"wrote {REFERENCE / stem}.json")
