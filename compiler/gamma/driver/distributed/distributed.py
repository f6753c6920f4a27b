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
task traces a contiguous range of at most ``TASK_CHUNKS`` chunks against them
and returns the chunks' surface deltas; the driver adds each task's chunks to
the runtime's batched merge (``merge_begin`` / ``merge_add`` / ``merge_end``)
in chunk order as the tasks complete, which sums exactly as a local run does.
At most ``workers × TASKS_PER_WORKER`` tasks are outstanding (submitted and
not yet merged), so the chunk logs that exist at once — in workers, Ray's
object store and the driver together — are bounded by
``workers × TASKS_PER_WORKER × TASK_CHUNKS`` whatever the pass's size, as a
local run's batches bound its logs.  Tasks whose worker dies are retried by
Ray; tracing a chunk is a pure function of (job, rows, iteration, chunk), so a
retry gives the same bytes.
"""

from __future__ import annotations

import hashlib
import os
from collections import deque
import time
import uuid
from dataclasses import dataclass

import numpy as np

#: Ray re-runs a chunk range whose worker died this many times.
TASK_RETRIES = 3
#: Tasks outstanding per worker (submitted and not yet merged): a little
#: more than one, so a worker has its next task while the driver merges.
#: A small pass is split into this many tasks per worker.
TASKS_PER_WORKER = 2
#: Most chunks (of CHUNK_SIZE γ-tons) one task traces and returns: with the
#: window above, it bounds the chunk logs that exist at once during a pass
#: (the local tracer's batch is max(64, 8 × threads) chunks).
TASK_CHUNKS = 64
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
        if name != "code_owner":        # a worker compiles its own kernels and owns them
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
        key=uuid.uuid4().hex, ir=kernels.ir_text, symbols=sorted(kernels.address),
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

        from ...backends.jit import target_machine, compile_ir

        self.module = compile_ir(ir)
        self.engine = llvm.create_mcjit_compiler(self.module, target_machine())
        self.engine.finalize_object()
        self.address = {s: self.engine.get_function_address(s) for s in symbols}


def worker_simulation(job: TraceJob, threads: int):
    """Build (once per worker and job) the simulation the driver has."""
    cached = _WORKER.get(job.key)
    if cached is not None:
        return cached[0]
    _WORKER.clear()
    from ..running.common import runtime_module

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
    cfg.code_owner = kernels
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

    @property
    def window(self) -> int:
        """Most tasks outstanding (submitted, not yet merged) at once."""
        return self.workers * TASKS_PER_WORKER

    def chunk_logs_bound(self) -> int:
        """Most chunk logs that exist at once during a pass."""
        return self.window * TASK_CHUNKS

    def ranges(self, nchunks: int) -> list[tuple[int, int]]:
        """The pass's chunks as contiguous ranges, one per task: at least
        ``window`` of them (fewer if there are fewer chunks), each at most
        TASK_CHUNKS chunks, as even as possible."""
        parts = max(1, min(nchunks, self.window), -(-nchunks // TASK_CHUNKS))
        bounds = [round(i * nchunks / parts) for i in range(parts + 1)]
        return [(a, b) for a, b in zip(bounds, bounds[1:]) if b > a]

    def trace(self, iteration: int) -> dict:
        t0 = time.perf_counter()
        nchunks = self.sim.num_chunks(iteration)
        rows = self.sim.rows()
        rows_ref = self.ray.put(rows)
        ranges = self.ranges(nchunks)
        pending: deque = deque()        # (first, last, ref) submitted and not yet merged, in chunk order
        peak = 0                        # most chunk logs of pending tasks at once
        setups: list[float] = []
        delta_bytes = 0
        merge_seconds = 0.0
        self.sim.merge_begin(iteration)
        try:
            for a, b in ranges:
                if len(pending) == self.window:
                    merge_seconds, delta_bytes = self._merge_next(pending, setups, merge_seconds, delta_bytes)
                pending.append((a, b, self._submit(rows_ref, iteration, a, b)))
                peak = max(peak, sum(last - first for first, last, _ in pending))
            while pending:
                merge_seconds, delta_bytes = self._merge_next(pending, setups, merge_seconds, delta_bytes)
        except BaseException:
            for _, _, ref in pending:   # a failed or interrupted pass leaves no work behind
                self.ray.cancel(ref, force=False)
            raise
        finally:
            del rows_ref
        t_end = time.perf_counter()
        stats = self.sim.merge_end()    # the splat spreads the deposits here
        merge_seconds += time.perf_counter() - t_end
        moved = {"state": int(rows.nbytes), "deltas": delta_bytes,
                 "job": 0 if self.sent_job else self.job_bytes, "tasks": len(ranges), "chunks": nchunks,
                 # chunk logs of tasks submitted and not yet merged, at most at once (bounded by
                 # chunk_logs_bound(), whatever the number of chunks)
                 "chunk_logs_peak": peak, "chunk_logs_bound": self.chunk_logs_bound(),
                 # worker processes that built the simulation in this iteration (Ray starts
                 # them when it first needs them, not only in the first iteration)
                 "worker_setups": len(setups), "worker_setup_seconds": float(sum(setups))}
        self.sent_job = True
        self.bytes_moved.append(moved)
        stats["trace_seconds"] = time.perf_counter() - t0
        stats["merge_seconds"] = merge_seconds          # the driver's serial part of the trace
        stats["bytes_moved"] = moved
        return stats

    def _submit(self, rows_ref, iteration: int, first: int, last: int):
        return self.task.remote([self.job_ref], self.key, rows_ref, iteration, first, last, self.threads,
                                CRASH_MARKER)

    def _merge_next(self, pending: deque, setups: list, merge_seconds: float,
                    delta_bytes: int) -> tuple[float, int]:
        """Wait for the first pending task and add its chunks to the merge
        (the later tasks keep running meanwhile)."""
        first, last, ref = pending[0]
        chunks, setup = self.ray.get(ref)
        if len(chunks) != last - first:
            raise RuntimeError(f"a Ray task returned {len(chunks)} chunks for chunks [{first}, {last})")
        if setup is not None:
            setups.append(setup)
        t = time.perf_counter()
        self.sim.merge_add(chunks)
        merge_seconds += time.perf_counter() - t
        delta_bytes += int(sum(s.nbytes + d.nbytes for s, d, _ in chunks))
        pending.popleft()
        return merge_seconds, delta_bytes

    def close(self) -> None:
        self.connection.close()


def _trace_task(job_box: list, key: str, rows: np.ndarray, iteration: int, first: int, last: int,
                threads: int, crash_marker: str | None) -> tuple[list, float | None]:
    """The chunk logs of [first, last), and the seconds this worker process
    spent building its simulation first (None when it had it already)."""
    if crash_marker and not os.path.exists(crash_marker):
        with open(crash_marker, "w") as f:
            f.write(str(os.getpid()))
        os._exit(1)
    setup = None
    if key in _WORKER:
        sim = _WORKER[key][0]
    else:
        import ray

        t0 = time.perf_counter()
        sim = worker_simulation(ray.get(job_box[0]), threads)
        setup = time.perf_counter() - t0
    sim.set_rows(rows)
    return sim.trace_chunks(iteration, first, last), setup


def start(rt, effect, kernels, opts, scene, sim, build_config) -> RayTracer:
    """Connect to Ray (local, or opts.ray_address) and share the job."""
    from .cluster import connect

    connection = connect(opts.ray_address)
    job = make_job(rt, effect, kernels, opts, scene, sim, build_config)
    return RayTracer(sim, job, connection)
