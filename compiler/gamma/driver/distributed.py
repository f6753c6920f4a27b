"""``gammac run --ray`` / ``--ray-address``: each iteration's γ-tons traced
on Ray workers in the runtime's fixed chunks, merged in chunk order, so the
run is bit-identical to a local one.

The driver keeps the one authoritative ``Simulation`` (it merges, updates,
renders and writes).  What a worker needs to rebuild the same simulation is a
``TraceJob``, put once in Ray's object store: the effect's LLVM IR (compiled
by the worker for its own CPU, with the same optimisation and no fast-math),
the calls that configured the runtime (kernel addresses replaced by symbol
names), the assembled mesh and the triangles' surfaces.  A worker checks that
its surfels equal the driver's (a digest) before it traces anything.

Per iteration the driver puts the surfel rows in the object store once; each
task traces a contiguous range of chunks against them and returns the chunks'
surface deltas; the driver merges all chunks in chunk order, which is the
merge of a local run.  Tasks whose worker dies are retried by Ray; tracing a
chunk is a pure function of (job, rows, iteration, chunk), so a retry gives
the same bytes.
"""

from __future__ import annotations

import hashlib
import os
import time
import uuid
from dataclasses import dataclass

import numpy as np

#: Ray re-runs a chunk range whose worker died this many times.
TASK_RETRIES = 3
#: Tasks per worker and iteration: a little more than one, so a slow worker
#: does not hold up the iteration.
TASKS_PER_WORKER = 2
#: For tests: a path whose absence makes the first task that sees it kill
#: its own worker process (as a lost worker), once.
CRASH_MARKER: str | None = None


@dataclass
class TraceJob:
    """Everything a worker needs to build the driver's simulation."""
    key: str                        # identifies this run: a worker caches its simulation under it
    ir: str                         # LLVM IR of the effect's kernels
    symbols: list                   # kernel symbols, resolved by the worker's JIT
    config_calls: list              # ("set" | "call", name, args): replayed on a new rt.Config
    vertices: np.ndarray
    triangles: np.ndarray
    triangle_surface: np.ndarray
    surfel_digest: str              # sha256 of the driver's surfel positions

    def nbytes(self) -> int:
        return (len(self.ir) + self.vertices.nbytes + self.triangles.nbytes
                + self.triangle_surface.nbytes + 64 * len(self.config_calls))


class _Symbol(str):
    """A kernel address, named by its symbol so another process can resolve it."""


class _RecordingConfig:
    """Stands in for ``rt.Config`` while the runner's ``build_config`` runs a
    second time: records every attribute set and method call."""

    def __init__(self, symbol_of: dict):
        object.__setattr__(self, "_calls", [])
        object.__setattr__(self, "_symbol_of", symbol_of)

    def _arg(self, value):
        if isinstance(value, int) and not isinstance(value, bool) and value in self._symbol_of:
            return _Symbol(self._symbol_of[value])
        return value

    def __setattr__(self, name, value):
        self._calls.append(("set", name, value))

    def __getattr__(self, name):
        def call(*args, **kwargs):
            self._calls.append(("call", name, ([self._arg(a) for a in args],
                                               {k: self._arg(v) for k, v in kwargs.items()})))
        return call


def record_config(build_config, rt, effect, kernels, opts, bounds, down) -> list:
    """The calls ``build_config`` makes on a new Config, addresses as symbols."""
    symbol_of = {address: symbol for symbol, address in kernels.address.items()}

    class RecordingRuntime:
        def __getattr__(self, name):
            return getattr(rt, name)

        @staticmethod
        def Config():
            return recorder

    recorder = _RecordingConfig(symbol_of)
    build_config(RecordingRuntime(), effect, kernels, opts, bounds, down)
    return recorder._calls


def surfel_digest(sim) -> str:
    return hashlib.sha256(np.ascontiguousarray(sim.surfel_positions()).tobytes()).hexdigest()


def make_job(rt, effect, kernels, opts, scene, sim, build_config) -> TraceJob:
    return TraceJob(
        key=uuid.uuid4().hex, ir=str(kernels.ir), symbols=sorted(kernels.address),
        config_calls=record_config(build_config, rt, effect, kernels, opts, scene.bounds, scene.down),
        vertices=np.ascontiguousarray(scene.mesh.vertices()), triangles=np.ascontiguousarray(scene.mesh.triangles()),
        triangle_surface=np.ascontiguousarray(scene.triangle_surface, dtype=np.int32),
        surfel_digest=surfel_digest(sim))


# --- worker side -------------------------------------------------------------

_WORKER: dict = {}       # the one simulation this worker process holds: {key: (sim, engine)}


class _WorkerKernels:
    """The job's kernels compiled by this process's JIT."""

    def __init__(self, ir: str, symbols: list):
        import llvmlite.binding as llvm

        from ..backends.jit import _target_machine, compile_ir

        self.module = compile_ir(ir)
        self.engine = llvm.create_mcjit_compiler(self.module, _target_machine())
        self.engine.finalize_object()
        self.address = {s: self.engine.get_function_address(s) for s in symbols}


def worker_simulation(job: TraceJob, threads: int):
    """Build (once per worker and job) the simulation the driver has."""
    cached = _WORKER.get(job.key)
    if cached is not None:
        return cached[0]
    _WORKER.clear()
    from .runner import runtime_module

    rt = runtime_module()
    kernels = _WorkerKernels(job.ir, job.symbols)
    cfg = rt.Config()
    for kind, name, value in job.config_calls:
        if kind == "set":
            setattr(cfg, name, value)
        else:
            args, kwargs = value
            resolve = (lambda v: kernels.address[v] if isinstance(v, _Symbol) else v)
            getattr(cfg, name)(*map(resolve, args), **{k: resolve(v) for k, v in kwargs.items()})
    cfg.threads = threads
    cfg.triangle_surface = job.triangle_surface
    sim = rt.Simulation(rt.Mesh.from_arrays(job.vertices, job.triangles), cfg)
    if surfel_digest(sim) != job.surfel_digest:
        raise RuntimeError("this worker's surfels differ from the driver's: "
                           "is the same version of gamma installed on every node?")
    _WORKER[job.key] = (sim, kernels)
    return sim


# --- driver side -------------------------------------------------------------

class RayTracer:
    """``trace(iteration)`` with the work on Ray; same counters as
    ``Simulation.trace``, plus what was moved (``bytes_moved``)."""

    def __init__(self, sim, job: TraceJob, connection, workers: int | None = None):
        """``workers``: at most this many tasks at once (default: one per CPU
        of the cluster); each task traces on one thread."""
        ray = connection.ray
        self.sim, self.ray, self.connection = sim, ray, connection
        self.job_ref = ray.put(job)
        self.job_bytes = job.nbytes()
        self.key = job.key
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.workers = max(1, min(workers or cpus, cpus))
        self.threads = 1
        # Reserving cpus // workers CPUs per task caps how many run at once.
        self.task = ray.remote(_trace_task).options(num_cpus=cpus // self.workers, max_retries=TASK_RETRIES)
        self.sent_job = False
        self.bytes_moved: list[dict] = []

    def ranges(self, nchunks: int) -> list[tuple[int, int]]:
        parts = max(1, min(nchunks, self.workers * TASKS_PER_WORKER))
        bounds = [round(i * nchunks / parts) for i in range(parts + 1)]
        return [(a, b) for a, b in zip(bounds, bounds[1:]) if b > a]

    def trace(self, iteration: int) -> dict:
        t0 = time.perf_counter()
        nchunks = self.sim.num_chunks(iteration)
        rows = self.sim.rows()
        rows_ref = self.ray.put(rows)
        refs = [self.task.remote([self.job_ref], self.key, rows_ref, iteration, a, b, self.threads, CRASH_MARKER)
                for a, b in self.ranges(nchunks)]
        chunks = [chunk for part in self.ray.get(refs) for chunk in part]
        del rows_ref
        t_merge = time.perf_counter()
        stats = self.sim.merge_chunks(iteration, chunks)     # the splat spreads the deposits here
        merge_seconds = time.perf_counter() - t_merge
        moved = {"state": int(rows.nbytes), "deltas": int(sum(s.nbytes + d.nbytes for s, d, _ in chunks)),
                 "job": 0 if self.sent_job else self.job_bytes, "tasks": len(refs), "chunks": nchunks}
        self.sent_job = True
        self.bytes_moved.append(moved)
        stats["trace_seconds"] = time.perf_counter() - t0
        stats["merge_seconds"] = merge_seconds          # the driver's serial part of the trace
        stats["bytes_moved"] = moved
        return stats

    def close(self) -> None:
        self.connection.close()


def _trace_task(job_box: list, key: str, rows: np.ndarray, iteration: int, first: int, last: int,
                threads: int, crash_marker: str | None) -> list:
    if crash_marker and not os.path.exists(crash_marker):
        with open(crash_marker, "w") as f:
            f.write(str(os.getpid()))
        os._exit(1)
    if key in _WORKER:
        sim = _WORKER[key][0]
    else:
        import ray

        sim = worker_simulation(ray.get(job_box[0]), threads)
    sim.set_rows(rows)
    return sim.trace_chunks(iteration, first, last)


def start(rt, effect, kernels, opts, scene, sim, build_config) -> RayTracer:
    """Connect to Ray (local, or opts.ray_address) and share the job."""
    from .cluster import connect

    connection = connect(opts.ray_address)
    job = make_job(rt, effect, kernels, opts, scene, sim, build_config)
    return RayTracer(sim, job, connection)
