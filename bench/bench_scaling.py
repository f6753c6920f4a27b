"""Benchmark: setup time, tracer cost and memory against surfel count, triangle
count and threads.

    .venv/bin/python bench/bench_scaling.py [--surfels 50000,100000,400000,1600000] [--record]

Each configuration runs in a fresh process (so its peak memory is its own):
patina (straight motion, environment source, 1M gamma-tons) on the Stanford
bunny (69k triangles) and on the bunny subdivided twice (1.1M triangles,
4-to-1 midpoint subdivision, same shape).  Per configuration:

- setup: surfel sampling, BVH build, kd-trees + triangle lookup (the
  runtime's own phase timings), and the total per 100,000 surfels;
- tracer: hitting interactions/s and the efficiency against Embree casting
  the tracer's own rays in the same process (see bench_tracer.py);
- peak resident memory of the process (mesh, surfels, indices, one trace).

Bytes per surfel and per triangle are differences of peak memory between
configurations of the same run (1.6M vs 400k surfels on the bunny; 1.1M vs
69k triangles at the same surfel count).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

from report import ROOT, SCENE, cpu_name, load_average, report



def subdivide(vertices, triangles):
    """One 4-to-1 midpoint subdivision (shared edge midpoints)."""
    import numpy as np

    t = triangles.astype(np.int64)
    edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    edges.sort(axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    mids = 0.5 * (vertices[unique[:, 0]] + vertices[unique[:, 1]])
    base = len(vertices)
    m = len(t)
    a, b, c = (inverse[:m] + base, inverse[m:2 * m] + base, inverse[2 * m:] + base)
    out = np.concatenate([
        np.stack([t[:, 0], a, c], 1), np.stack([t[:, 1], b, a], 1),
        np.stack([t[:, 2], c, b], 1), np.stack([a, b, c], 1)])
    return np.concatenate([vertices, mids]).astype(np.float32), out.astype(np.int32)


def one(surfels: int, subdivisions: int, threads: int, tons: int) -> dict:
    """Measures one configuration in this process (called in a child)."""
    from gamma.backends.jit import JitKernels
    from gamma.frontend.checker import load
    from gamma.driver.running.runner import RunOptions, build_config, runtime_module

    rt = runtime_module()
    mesh = rt.Mesh.load(str(SCENE))
    if subdivisions:
        v, t = mesh.vertices(), mesh.triangles()
        for _ in range(subdivisions):
            v, t = subdivide(v, t)
        mesh = rt.Mesh.from_arrays(v, t)
        del v, t
    effect = load(str(ROOT / "examples" / "patina.gamma"))
    kernels = JitKernels(effect)
    opts = RunOptions(scene=str(SCENE), out="", surfels=surfels, tons=tons, threads=threads)
    cfg = build_config(rt, effect, kernels, opts, mesh.bounds, (0.0, -1.0, 0.0))
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    t0 = time.perf_counter()
    sim = rt.Simulation(mesh, cfg)
    setup = time.perf_counter() - t0
    sim.trace(1)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    rays = sim.record_rays(2)
    traced = sim.trace(2)
    raw = sim.cast_rays(rays, threads)
    return {"surfels": sim.num_surfels, "triangles": mesh.num_triangles, "threads": threads,
            "setup": setup, "phases": sim.setup_seconds, "lookup": sim.lookup_stats,
            "hits_per_s": traced["interactions"] / traced["trace_seconds"],
            "efficiency": (raw["seconds"] / raw["rays"]) / (traced["trace_seconds"] / traced["rays"]),
            "rss": rss, "rss_before_setup": rss_before}


def child(surfels: int, subdivisions: int, threads: int, tons: int) -> dict:
    out = subprocess.run([sys.executable, __file__, "--one", f"{surfels},{subdivisions},{threads},{tons}"],
                         check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--surfels", default="50000,100000,400000,1600000")
    ap.add_argument("--tons", type=int, default=1_000_000)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()
    if args.one:
        s, d, th, tons = (int(x) for x in args.one.split(","))
        print(json.dumps(one(s, d, th, tons)))
        return

    load_before = load_average()
    configs = [(int(s), 0, 2) for s in args.surfels.split(",")]
    configs += [(100_000, 0, 1), (100_000, 2, 2), (1_600_000, 2, 2)]
    rows = []
    for s, d, th in configs:
        r = child(s, d, th, args.tons)
        rows.append(r)
        print(f"  {r['surfels']:,} surfels, {r['triangles']:,} triangles, {th} threads: setup {r['setup']:.2f} s, "
              f"efficiency {r['efficiency']:.0%}, peak {r['rss'] / 2**20:,.0f} MiB", flush=True)
    header = ("| surfels | triangles | threads | setup s | per 100k surfels s | sampling s | BVH s | "
              "kd-trees + lookup s | lookup candidates/triangle | hitting interactions/s | efficiency | "
              "peak MiB |\n|---|---|---|---|---|---|---|---|---|---|---|---|")
    table = []
    for r in rows:
        ph, lk = r["phases"], r["lookup"]
        table.append(
            f"| {r['surfels']:,} | {r['triangles']:,} | {r['threads']} | {r['setup']:.2f} | "
            f"{r['setup'] / (r['surfels'] / 1e5):.3f} | {ph['sample']:.2f} | {ph['geometry']:.2f} | "
            f"{ph['surfels']:.2f} | {lk['candidates'] / r['triangles']:.1f} | {r['hits_per_s']:,.0f} | "
            f"{r['efficiency']:.0%} | {r['rss'] / 2**20:,.0f} |")
    by = {(r["surfels"], r["triangles"], r["threads"]): r for r in rows}
    notes = []
    bunny = rows[0]["triangles"]
    big = [r for r in rows if r["triangles"] != bunny]
    small = sorted((r for r in rows if r["triangles"] == bunny and r["threads"] == 2), key=lambda r: r["surfels"])
    if len(small) >= 2:
        a, b = small[-2], small[-1]
        notes.append(f"bytes per surfel ≈ {(b['rss'] - a['rss']) / (b['surfels'] - a['surfels']):,.0f} "
                     f"(peak memory, {a['surfels']:,} → {b['surfels']:,} surfels on the bunny)")
    for r in big:
        base = by.get((r["surfels"], bunny, r["threads"]))
        if base:
            notes.append(f"bytes per triangle ≈ {(r['rss'] - base['rss']) / (r['triangles'] - bunny):,.0f} "
                         f"(peak memory, {bunny:,} → {r['triangles']:,} triangles at {r['surfels']:,} surfels)")
    info = (f"patina, environment source, {args.tons:,} γ-tons per trace, one fresh process per row; "
            f"{cpu_name()}, {os.cpu_count()} cores, load average {load_before:.1f} → {load_average():.1f}")
    report("setup, tracer and memory against size", info, header, table + [""] + [f"- {n}" for n in notes],
           args.record)


if __name__ == "__main__":
    main()
