"""gammac run --ray on a local Ray (loopback, shared by the session): chunks
traced on workers and merged in chunk order give the bytes of a local run,
also when a worker is killed mid-task and Ray retries it."""

import json
from pathlib import Path

from conftest import GRIMY_COPPER
from gamma import cli
from gamma.driver.distributed import distributed

EFFECT = GRIMY_COPPER.replace("count 30000", "count 5000").replace("count 10000", "count 2500")
# Flow and parabolic flights, a source strength (weighted deposits), the
# splat, mass books of water and grime, and appearance renders.
FLOWING = """
ton Drop {
    motion parabolic = 0.3, flow = 0.7
    carry water = 1.0, grime = 0.0
    bounce 0.05
    step 0.02
}
surface Plaster {
    reflectance parabolic = 0.1, flow = 0.05
    property water = 0.0, grime = 0.2
}
source rain = directional(down) emits Drop count 4000 strength 0.5
on hit(t: Drop, s: Plaster) {
    s.water += 0.1 * t.water
    t.water -= 0.1 * t.water
    t.grime += 0.1 * s.grime
    s.grime -= 0.1 * s.grime
}
on settle(t: Drop, s: Plaster) { s.grime += t.grime }
update(s: Plaster) { s.water *= 0.5 }
appearance(s: Plaster) { color = mix(rgb(0.8, 0.8, 0.8), rgb(0.3, 0.2, 0.1), smoothstep(0.0, 1.0, s.grime)) }
"""
RUN = ["--surfels", "3000", "--iterations", "3", "--size", "48", "--seed", "5", "--quiet"]


def outputs(folder: Path) -> dict:
    """Every file a run wrote except summary.json (which holds timings)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != "summary.json"}


def run(tmp_path, mesh, name, *extra, effect=EFFECT) -> Path:
    (tmp_path / "e.gamma").write_text(effect)
    out = tmp_path / name
    assert cli.main(["run", str(tmp_path / "e.gamma"), "--scene", str(mesh), *RUN, "--out", str(out), *extra]) == 0
    return out


def test_ray_run_is_bit_identical_to_a_local_run(ray_local, tmp_path, bumpy_obj):
    local = run(tmp_path, bumpy_obj, "local", "--threads", "1")
    remote = run(tmp_path, bumpy_obj, "ray", "--ray")
    files = outputs(local)
    assert "maps/iter_0003.ply" in files
    assert outputs(remote) == files
    summary = json.loads((remote / "summary.json").read_text())
    local_summary = json.loads((local / "summary.json").read_text())
    for mine, theirs in zip(summary["iterations"], local_summary["iterations"]):
        assert mine["property_sums"] == theirs["property_sums"]
        assert mine["mass"] == theirs["mass"] and set(mine["mass"]) == {"patina", "grime"}
        assert mine["emitted"] == theirs["emitted"] == 7500
        moved = mine["ray"]
        assert moved["chunks"] == 8                     # 7,500 gamma-tons in chunks of 1,024
        width = moved["state"] // (4 * summary["surfels"])      # the float32 rows, sent once
        assert moved["state"] == 4 * summary["surfels"] * width and width >= 5   # 3 reflectance + 2 properties
        assert moved["deltas"] > 0
    assert summary["iterations"][0]["ray"]["job"] > 0 and summary["iterations"][1]["ray"]["job"] == 0
    # every worker process builds the simulation once, whenever Ray first gives it a task
    setups = [i["ray"]["worker_setups"] for i in summary["iterations"]]
    assert setups[0] >= 1 and sum(setups) <= summary["ray"]["workers"] * len(setups)
    assert all((i["ray"]["worker_setup_seconds"] > 0) == (i["ray"]["worker_setups"] > 0) for i in summary["iterations"])


def test_a_killed_worker_is_retried_and_the_run_is_unchanged(ray_local, tmp_path, box_obj, monkeypatch):
    marker = tmp_path / "crashed"
    monkeypatch.setattr(distributed, "CRASH_MARKER", str(marker))
    remote = run(tmp_path, box_obj, "ray", "--ray")
    assert marker.exists()                          # a worker did die mid-iteration
    monkeypatch.setattr(distributed, "CRASH_MARKER", None)
    local = run(tmp_path, box_obj, "local", "--threads", "2")
    assert outputs(remote) == outputs(local)


def test_ray_run_with_flow_strength_and_appearance_is_bit_identical(ray_local, tmp_path, box_obj):
    local = run(tmp_path, box_obj, "local", "--threads", "2", effect=FLOWING)
    remote = run(tmp_path, box_obj, "ray", "--ray", effect=FLOWING)
    files = outputs(local)
    assert "renders/iter_0003.png" in files
    assert outputs(remote) == files
    summary = json.loads((remote / "summary.json").read_text())
    local_summary = json.loads((local / "summary.json").read_text())
    for mine, theirs in zip(summary["iterations"], local_summary["iterations"], strict=True):
        assert mine["flow_steps"] == theirs["flow_steps"] > 0
        assert mine["mass"] == theirs["mass"] and mine["mass"]["grime"]["deposited"] > 0


def test_a_local_run_resumed_on_ray_equals_a_whole_local_run(ray_local, tmp_path, bumpy_obj):
    """Where the tracing happens does not change the results, so it is not
    part of the run's key: a run can be continued on Ray (or off it)."""
    whole = run(tmp_path, bumpy_obj, "whole", "--threads", "2")
    part = run(tmp_path, bumpy_obj, "part", "--iterations", "2")
    resumed = run(tmp_path, bumpy_obj, "part", "--ray", "--resume")
    assert resumed == part and json.loads((part / "summary.json").read_text())["resumed_at"] == 3
    assert outputs(part) == outputs(whole)


MANY_CHUNKS = GRIMY_COPPER


def test_a_pass_of_many_chunks_holds_a_bounded_number_of_chunk_logs(ray_local, tmp_path, bumpy_obj, monkeypatch):
    """The driver keeps at most workers × TASKS_PER_WORKER tasks of at most
    TASK_CHUNKS chunks outstanding and merges each task's chunks, in chunk
    order, as it completes: the chunk logs that exist at once stay within
    that bound however many chunks the pass has, and the run still gives a
    local run's bytes.  Counted here by watching every task submitted and
    every task merged."""
    monkeypatch.setattr(distributed, "TASK_CHUNKS", 3)
    events = []
    submit, merge_next = distributed.RayTracer._submit, distributed.RayTracer._merge_next

    def watched_submit(self, rows_ref, iteration, first, last):
        events.append(("submit", iteration, first, last))
        return submit(self, rows_ref, iteration, first, last)

    def watched_merge_next(self, pending, *args):
        first, last, _ = pending[0]
        result = merge_next(self, pending, *args)
        events.append(("merge", None, first, last))
        return result

    monkeypatch.setattr(distributed.RayTracer, "_submit", watched_submit)
    monkeypatch.setattr(distributed.RayTracer, "_merge_next", watched_merge_next)
    remote = run(tmp_path, bumpy_obj, "ray", "--ray", "--iterations", "2", effect=MANY_CHUNKS)
    local = run(tmp_path, bumpy_obj, "local", "--threads", "2", "--iterations", "2", effect=MANY_CHUNKS)
    assert outputs(remote) == outputs(local)
    summary = json.loads((remote / "summary.json").read_text())
    workers = summary["ray"]["workers"]
    bound = workers * distributed.TASKS_PER_WORKER * 3
    outstanding, peak, merged_to, iteration = {}, 0, 0, 0
    for kind, it, first, last in events:
        assert last - first <= 3
        if kind == "submit":
            if it != iteration:                     # a new pass: the last one merged every chunk
                assert not outstanding and merged_to in (0, 40)
                iteration, merged_to = it, 0
            outstanding[first] = last
            peak = max(peak, sum(b - a for a, b in outstanding.items()))
        else:
            assert first == merged_to               # merged in chunk order, none skipped
            merged_to = outstanding.pop(first)
    assert iteration == 2 and merged_to == 40 and not outstanding
    for record in summary["iterations"]:
        moved = record["ray"]
        assert moved["chunks"] == 40                # 40,000 gamma-tons in chunks of 1,024
        assert moved["tasks"] == 14                 # ceil(40 / 3)
        assert moved["chunk_logs_bound"] == bound < 40
        assert 0 < moved["chunk_logs_peak"] <= bound
    assert peak == max(r["ray"]["chunk_logs_peak"] for r in summary["iterations"]) <= bound
