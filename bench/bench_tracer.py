"""Benchmark: tracer efficiency on the Stanford bunny, per motion mode, against
Embree casting the tracer's own rays.

    .venv/bin/python bench/bench_tracer.py [--tons 1000000] [--modes straight,parabolic,flow] [--record]

For each motion mode (an effect whose gamma-tons only reflect, only bounce,
or only flow; environment source, 100,000 surfels) and each thread count:

1. ``record_rays`` replays the iteration's trace on a copy of the state and
   keeps every ray it casts (environment primaries, reflections, parabola
   chords, flow probes: the same count, order, origins, lengths);
2. ``trace`` runs the iteration for real (timed inside the runtime);
3. ``cast_rays`` casts the recorded rays with ``rtcIntersect1`` and nothing
   else (converted before the clock starts): Embree's raw rate for the
   same rays.

**efficiency** = Embree's time for the tracer's rays / the tracer's time:
the share of the ceiling the tracer reaches (1 would mean emission, surfel
lookup, roulette, kernels and the deposit merge cost nothing).  **hitting
gamma-tons/s** counts the gamma-tons whose emission ray reached the mesh
(a spherical source's misses cost one ray each and are left out);
**interactions/s** counts every interaction with the surface.  Best of ``--repeats`` for each timing, trace
and raw cast alternating so both see the same load.  ``--record`` appends
the table to bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from report import SCENE, cpu_name, load_average, report

from gamma.backends.jit import JitKernels
from gamma.frontend.checker import load
from gamma.driver.running.runner import RunOptions, build_config, runtime_module


# One effect per motion mode: patina's rules, the gamma-tons moving one way.
# Bounce and flow distances are in the bunny's units (about 0.2 across).
EFFECTS = {
    "straight": ("motion straight = 1.0", "reflectance straight = 0.5", ""),
    "parabolic": ("motion parabolic = 1.0", "reflectance parabolic = 0.5", "bounce 0.01"),
    "flow": ("motion flow = 1.0", "reflectance flow = 0.1", "step 0.002"),
}


def effect_text(mode: str) -> str:
    motion, reflectance, extra = EFFECTS[mode]
    return f"""
ton Weather {{
    {motion}
    carry patina = 1.0
    {extra}
}}
surface Copper {{
    {reflectance}
    property patina = 0.0
}}
source air = environment(sphere) emits Weather count 1000000
on settle(t: Weather, s: Copper) {{
    s.patina += 0.05 * t.patina
}}
"""


def measure(rt, mesh, mode: str, tons: int, surfels: int, threads: int, repeats: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{mode}.gamma"
        path.write_text(effect_text(mode))
        effect = load(str(path))
    kernels = JitKernels(effect)
    opts = RunOptions(scene=str(SCENE), out="", surfels=surfels, tons=tons, threads=threads)
    cfg = build_config(rt, effect, kernels, opts, mesh.bounds, (0.0, -1.0, 0.0))
    sim = rt.Simulation(mesh, cfg)
    best_trace = best_raw = None
    for rep in range(repeats):
        iteration = rep + 1
        rays = sim.record_rays(iteration)
        stats = sim.trace(iteration)
        if stats["rays"] != len(rays):
            raise SystemExit(f"{mode}: recorded {len(rays)} rays, the trace cast {stats['rays']}")
        raw = sim.cast_rays(rays, threads)
        del rays
        if best_trace is None or stats["trace_seconds"] < best_trace["trace_seconds"]:
            best_trace = stats
        if best_raw is None or raw["seconds"] < best_raw["seconds"]:
            best_raw = raw
    t, r = best_trace, best_raw
    return {
        "mode": mode, "threads": threads,
        "hitting_tons_per_s": (t["emitted"] - t["missed"]) / t["trace_seconds"],
        "hits_per_s": t["interactions"] / t["trace_seconds"],
        "rays_per_hit": t["rays"] / max(t["interactions"], 1),
        "miss_fraction": t["missed"] / max(t["emitted"], 1),
        "tracer_rays_per_s": t["rays"] / t["trace_seconds"],
        "raw_rays_per_s": r["rays"] / r["seconds"],
        "efficiency": (r["seconds"] / r["rays"]) / (t["trace_seconds"] / t["rays"]),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tons", type=int, default=1_000_000)
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--modes", default="straight,parabolic,flow")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()

    rt = runtime_module()
    mesh = rt.Mesh.load(str(SCENE))
    load_before = load_average()
    rows = []
    for mode in args.modes.split(","):
        for threads in (int(t) for t in args.threads.split(",")):
            m = measure(rt, mesh, mode, args.tons, args.surfels, threads, args.repeats)
            rows.append(m)
            print(f"  {mode} {threads} thread(s): efficiency {m['efficiency']:.0%}", flush=True)
    header = ("| motion | threads | hitting γ-tons/s | interactions/s | rays per interaction | "
              "γ-tons missing the mesh | tracer rays/s | Embree rays/s (same rays) | efficiency |\n"
              "|---|---|---|---|---|---|---|---|---|")
    table = [f"| {m['mode']} | {m['threads']} | {m['hitting_tons_per_s']:,.0f} | {m['hits_per_s']:,.0f} | "
             f"{m['rays_per_hit']:.2f} | "
             f"{m['miss_fraction']:.0%} | {m['tracer_rays_per_s']:,.0f} | {m['raw_rays_per_s']:,.0f} | "
             f"{m['efficiency']:.0%} |" for m in rows]
    info = (f"bunny {mesh.num_triangles:,} triangles, {args.surfels:,} surfels, environment source, "
            f"{args.tons:,} γ-tons per trace, best of {args.repeats}; efficiency = Embree's time for the "
            f"tracer's own rays / the tracer's time; {cpu_name()}, {os.cpu_count()} cores, "
            f"load average {load_before:.1f} → {load_average():.1f}")
    report("tracer efficiency on the bunny (same rays)", info, header, table, args.record)


if __name__ == "__main__":
    main()
