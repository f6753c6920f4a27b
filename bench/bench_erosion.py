"""Benchmark: one erosion iteration of the Stanford bunny (trace, update,
displacement, re-tiling, surfel re-sampling and transfer, rebuild) against a
paint-only iteration (trace + update of the patina effect, same surfels and
gamma-ton count), in one process.

    .venv/bin/python bench/bench_erosion.py [--surfels 100000] [--tons 300000] [--scale 1] [--record]

The erosion effect is examples/erosion.gamma with the whole bunny as
Sandstone.  Its first iteration (which always re-tiles the input) is not counted;
of iterations 2.., the best step where the surfels ride on their triangles
and the best re-tiling step are reported, split by phase (the rebuild
includes the splat kernel and the surfel measures; the renders' normals are
left to the next render, and this benchmark renders nothing), with
the number of triangles the re-tiling made (a local re-tiling keeps the
rest), and the mean of all of them.  The header gives the smallest angle
at the corners the 15° bound covers (all but corners between two boundary
or seam edges) and over all corners, both the worst over iterations 2..,
and how many steps left slivers (`slivers_left`).  The ratio erosion / paint
measured in the same run is the figure to compare (rates swing on this
shared machine).  ``--record`` appends the table to bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import time

from report import ROOT, SCENE, cpu_name, load_average, report

from gamma.backends.jit import JitKernels
from gamma.frontend.checker import load
from gamma.driver.running.runner import RunOptions, build_config, runtime_module



def iteration(sim, it: int) -> dict:
    t0 = time.perf_counter()
    traced = sim.trace(it)
    updated = sim.update(it)
    shaped = sim.shape(it)
    total = time.perf_counter() - t0
    return {"total": total, "trace": traced["trace_seconds"], "update": updated["seconds"],
            "displace": shaped["displace_seconds"], "retile": shaped["retile_seconds"],
            "resample": shaped["resample_seconds"], "rebuild": shaped["rebuild_seconds"],
            "changed": shaped["changed"], "retiled": shaped["retiled"], "triangles": shaped["geometry"]["triangles"],
            "made": shaped["retiled_triangles"],
            "min_angle": shaped["geometry"]["min_angle_deg"], "area": shaped["geometry"]["area"],
            "min_free_angle": shaped["geometry"]["min_free_angle_deg"],
            "slivers_left": shaped["slivers_left"], "emitted": traced["emitted"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--tons", type=int, default=300_000)
    # 30, as examples/erosion.gamma runs: later steps have eroded deeper and re-tile more
    ap.add_argument("--iterations", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    # The example is written for the 4 m arch scene (bounce 0.25 m, flow step 0.04 m, 1 mm per unit);
    # the bunny is 0.15 m across, so at scale 1 the same effect wears it ~15x deeper for its size.
    # --scale 15 makes the bunny about the arch's size (2.3 m), the example's own regime.
    ap.add_argument("--scale", type=float, default=1.0, help="scale the bunny by this factor first")
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()

    rt = runtime_module()
    mesh = rt.Mesh.load(str(SCENE))
    if args.scale != 1.0:
        import numpy as np

        mesh = rt.Mesh.from_arrays(np.asarray(mesh.vertices(), dtype=np.float32) * np.float32(args.scale),
                                   np.asarray(mesh.triangles(), dtype=np.int32))
    opts = RunOptions(scene=str(SCENE), out="", surfels=args.surfels, tons=args.tons, threads=args.threads)

    erosion = load(str(ROOT / "examples" / "erosion.gamma"))
    ek = JitKernels(erosion)
    sim = rt.Simulation(mesh, build_config(rt, erosion, ek, opts, mesh.bounds, (0.0, -1.0, 0.0)))
    runs = [iteration(sim, it) for it in range(1, args.iterations + 1)]
    best = min(runs[1:] or runs, key=lambda r: r["total"])

    paint = load(str(ROOT / "examples" / "patina.gamma"))
    pk = JitKernels(paint)
    psim = rt.Simulation(mesh, build_config(rt, paint, pk, opts, mesh.bounds, (0.0, -1.0, 0.0)))
    paint_runs = []
    for it in range(1, args.iterations + 1):
        t0 = time.perf_counter()
        psim.trace(it)
        psim.update(it)
        paint_runs.append(time.perf_counter() - t0)
    paint_best = min(paint_runs)

    header = ("| iteration | total s | trace | update | displace | re-tile | re-sample + transfer | rebuild "
              "| triangles re-tiled | paint-only s | ratio |\n|---|---|---|---|---|---|---|---|---|---|---|")
    later = runs[1:] or runs
    retiling = [r for r in later if r["retiled"]]
    riding = [r for r in later if not r["retiled"]]
    mean = sum(r["total"] for r in later) / len(later)
    rows = []
    # the slowest step too: the goal is every iteration under 1 s, not the mean
    for label, chosen, pick in (("surfels ride (best)", riding, min), ("re-tiled (best)", retiling, min),
                                ("slowest step", later, max)):
        if chosen:
            b = pick(chosen, key=lambda r: r["total"])
            rows.append(f"| {label} | {b['total']:.3f} | {b['trace']:.3f} | {b['update']:.3f} | "
                        f"{b['displace']:.3f} | {b['retile']:.3f} | {b['resample']:.3f} | {b['rebuild']:.3f} | "
                        f"{b['made']:,} | {paint_best:.3f} | {b['total'] / paint_best:.2f} |")
    phases = ("trace", "update", "displace", "retile", "resample", "rebuild")
    means = " | ".join(f"{sum(r[p] for r in later) / len(later):.3f}" for p in phases)
    made = sum(r["made"] for r in later) / len(later)
    rows.append(f"| mean of iterations 2..{args.iterations} ({len(retiling)} re-tiled) | {mean:.3f} | {means} | "
                f"{made:,.0f} | {paint_best:.3f} | {mean / paint_best:.2f} |")
    min_free = min(r["min_free_angle"] for r in later)
    min_all = min(r["min_angle"] for r in later)
    with_slivers = sum(1 for r in later if r["slivers_left"] > 0)
    over_goal = [i + 2 for i, r in enumerate(later) if r["total"] > 1.0]
    info = (f"bunny{f' scaled {args.scale:g}×' if args.scale != 1.0 else ''} {mesh.num_triangles:,} triangles re-tiled to {best['triangles']:,} "
            f"(smallest angle where the 15° bound applies {min_free:.1f}°, over all corners {min_all:.1f}°; "
            f"{with_slivers} of {len(later)} steps left slivers; steps over 1 s: "
            f"{len(over_goal)} of {len(later)}{' (' + ', '.join(map(str, over_goal)) + ')' if over_goal else ''}; "
            f"area {runs[0]['area']:.4g} m² after iteration 1, {runs[-1]['area']:.4g} m² "
            f"({runs[-1]['area'] / runs[0]['area']:.2f}×) after iteration {args.iterations}), {args.surfels:,} surfels, {best['emitted']:,} γ-tons "
            f"per iteration, {args.threads} threads, iterations 2..{args.iterations}, load {load_average():.1f}, "
            f"{cpu_name()}, {os.cpu_count()} cores")
    report("erosion iteration on the bunny", info, header, rows, args.record)


if __name__ == "__main__":
    main()
