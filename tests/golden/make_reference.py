"""Regenerate the golden scene and reference outputs (run by hand, then review
the diff and the renders before committing):

    .venv/bin/python tests/golden/make_reference.py
"""

import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
from meshes import write_obj  # noqa: E402

ARGS = ["--surfels", "400", "--iterations", "3", "--seed", "11", "--threads", "2",
        "--size", "128", "--quiet"]


def open_box():
    """A unit box without its top (y up), each face split into 4x4 quads."""
    import numpy as np

    verts, faces = [], []

    def face(origin, du, dv, n=4):
        base = len(verts)
        for i in range(n + 1):
            for j in range(n + 1):
                verts.append(np.array(origin) + np.array(du) * i / n + np.array(dv) * j / n)
        for i in range(n):
            for j in range(n):
                a = base + i * (n + 1) + j
                faces.extend([(a, a + n + 1, a + 1), (a + 1, a + n + 1, a + n + 2)])

    face((-0.5, 0, -0.5), (1, 0, 0), (0, 0, 1))     # floor
    face((-0.5, 0, -0.5), (0, 1, 0), (1, 0, 0))     # walls
    face((-0.5, 0, 0.5), (1, 0, 0), (0, 1, 0))
    face((-0.5, 0, -0.5), (0, 0, 1), (0, 1, 0))
    face((0.5, 0, -0.5), (0, 1, 0), (0, 0, 1))
    return np.array(verts), np.array(faces)


if __name__ == "__main__":
    write_obj(HERE / "open_box.obj", *open_box())
    out = HERE / "_run"
    shutil.rmtree(out, ignore_errors=True)
    subprocess.run([sys.executable, "-m", "gamma.cli", "run", str(HERE / "effect.gamma"),
                    "--scene", str(HERE / "open_box.obj"), "--out", str(out), *ARGS], check=True)
    ref = HERE / "reference"
    shutil.rmtree(ref, ignore_errors=True)
    ref.mkdir()
    for ply in sorted((out / "maps").glob("*.ply")):
        shutil.copy(ply, ref / ply.name)
    import json

    summary = json.loads((out / "summary.json").read_text())
    counts = [{k: it[k] for k in ("emitted", "settled", "escaped", "capped", "interactions")}
              for it in summary["iterations"]]
    (ref / "counts.json").write_text(json.dumps(counts, indent=1) + "\n")
    print("reference written; renders for review in", out / "renders")
