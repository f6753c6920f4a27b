"""Benchmark: what mask() and attribute() cost (SPEC §12a).  Surfels read
them once, at setup, so tracing should cost what it did without them.

Spot (the cow, with its UVs) under uniform dust, three variants of one
effect, in one process: the rule deposits a constant (baseline), or scales
the deposit by mask("mask.png") (a 1024² 16-bit image), or by a vertex
attribute (a per-vertex ramp, read from a PLY copy of the mesh).  Per
variant: the setup (surfels, indices, and reading the scene's inputs), the
best of the iterations' trace seconds, and the trace rate against the
baseline's, measured in the same run.

    .venv/bin/python bench/bench_scene_inputs.py [--surfels 100000] [--tons 400000] [--record]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from report import ROOT, cpu_name, load_average, report

from gamma.backends.jit import JitKernels
from gamma.driver.running import scene_inputs
from gamma.driver.running.runner import RunOptions, build_config, runtime_module
from gamma.driver.running.scene import load_scene
from gamma.frontend.checker import check
from gamma.frontend.parser import parse

EFFECT = """
ton Dust {{ motion straight = 1.0 }}
surface Hide {{ reflectance straight = 0.0  property dust = 0.0 }}
source fall = environment(hemisphere) emits Dust count 100000 strength 1
on hit(t: Dust, s: Hide) {{ s.dust += 0.01 * {steer} }}
"""
STEERS = {"baseline": "1", "mask": 'mask("mask.png")', "attribute": 'attribute("wetness")'}


def write_inputs(folder: Path, rt) -> Path:
    """mask.png (1024², 16-bit grey noise) and spot.ply with a 'wetness' ramp and the UVs."""
    from PIL import Image

    rng = np.random.default_rng(1)
    Image.fromarray((rng.random((1024, 1024)) * 65535).astype(np.uint16)).save(folder / "mask.png")
    mesh = rt.Mesh.load(str(ROOT / "examples" / "scenes" / "spot.obj"))
    verts = np.asarray(mesh.vertices(), np.float32)
    tris = np.asarray(mesh.triangles(), np.int32)
    # per-corner UVs to per-vertex, as the OBJ's vertices carry them (first corner wins)
    corner_uv = np.asarray(mesh.triangle_uvs(), np.float32).reshape(-1, 2)
    uv = np.zeros((len(verts), 2), np.float32)
    uv[tris.reshape(-1)[::-1]] = corner_uv[::-1]
    wet = ((verts[:, 1] - verts[:, 1].min()) / np.ptp(verts[:, 1])).astype(np.float32)
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(verts)}",
            *[f"property float {n}" for n in ("x", "y", "z", "u", "v", "wetness")],
            f"element face {len(tris)}", "property list uchar int vertex_indices", "end_header"]
    body = np.column_stack([verts, uv, wet]).astype("<f4").tobytes()
    faces = np.zeros(len(tris), dtype=[("n", "u1"), ("i", "<i4", 3)])
    faces["n"], faces["i"] = 3, tris
    path = folder / "spot.ply"
    path.write_bytes(("\n".join(head) + "\n").encode() + body + faces.tobytes())
    return path


def measure(rt, folder: Path, scene_path: Path, name: str, surfels: int, tons: int, iterations: int) -> dict:
    effect_path = folder / f"{name}.gamma"
    effect_path.write_text(EFFECT.format(steer=STEERS[name]))
    effect = check(parse(effect_path.read_text(), str(effect_path)))
    kernels = JitKernels(effect)
    scene = load_scene(rt, str(scene_path), effect, [], None)
    opts = RunOptions(scene=str(scene_path), out="", surfels=surfels, tons=tons, threads=2)
    t0 = time.perf_counter()
    cfg = build_config(rt, effect, kernels, opts, scene.bounds, scene.down)
    cfg.triangle_surface = scene.triangle_surface
    sim = rt.Simulation(scene.mesh, cfg)
    t1 = time.perf_counter()
    scene_inputs.write(sim, effect, scene_inputs.columns(effect, scene, sim))
    t2 = time.perf_counter()
    traces = []
    for it in range(1, iterations + 1):
        traced = sim.trace(it)
        traces.append((traced["trace_seconds"], traced["emitted"] - traced["missed"]))
        sim.update(it)
    best = min(traces)
    return {"setup": t1 - t0, "inputs": t2 - t1, "trace": best[0], "rate": best[1] / best[0]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--tons", type=int, default=400_000)
    ap.add_argument("--iterations", type=int, default=5)
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()
    rt = runtime_module()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        scene = write_inputs(folder, rt)
        results = {name: measure(rt, folder, scene, name, args.surfels, args.tons, args.iterations)
                   for name in STEERS}
    base = results["baseline"]["rate"]
    rows = [f"| {name} | {r['setup']:.2f} | {r['inputs']:.3f} | {r['trace']:.3f} | {r['rate'] / 1e6:.2f} | "
            f"{r['rate'] / base:.3f} |" for name, r in results.items()]
    info = (f"{cpu_name()}, 2 threads, load {load_average():.1f}; Spot, {args.surfels:,} surfels, "
            f"{args.tons:,} γ-tons per iteration, best of {args.iterations} iterations; mask: 1024² 16-bit PNG")
    header = ("| rule reads | setup s | reading the inputs s | trace s | hitting γ-tons / s (M) | rate / baseline |\n"
              "|---|---|---|---|---|---|")
    report("mask() and attribute(): setup and trace against a rule that reads neither", info, header, rows,
           args.record)


if __name__ == "__main__":
    main()
