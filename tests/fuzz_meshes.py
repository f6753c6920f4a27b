"""The fuzzer of the mesh readers: mutants of the valid files of
tests/mesh_corpus.py (bytes flipped, header lines edited, counts changed,
bodies cut or repeated) loaded by ``gamma._runtime.Mesh.load`` in a child
process with a memory limit and a time limit.  A child that is killed, times
out or raises anything but the reader's ValueError is a failure; the files of
that batch that fail alone are saved to tests/mesh_regressions/, which
tests/test_robust_input.py loads on every ``make test``.

    python tests/fuzz_meshes.py --seconds 300 [--seed N]
"""

from __future__ import annotations

import argparse
import hashlib
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mesh_corpus

REGRESSIONS = Path(__file__).resolve().parent / "mesh_regressions"
MEMORY_LIMIT = 3 << 30
LOADER = f"""
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({MEMORY_LIMIT}, {MEMORY_LIMIT}))
import gamma._runtime as rt
for path in sys.argv[1:]:
    try:
        rt.Mesh.load(path)
    except ValueError:
        pass
"""


def bases() -> list[tuple[str, bytes]]:
    return [(name, data) for name, data, expected in mesh_corpus.cases() if expected == "ok"]


def mutate(rng: random.Random, name: str, data: bytes) -> bytes:
    data = bytearray(data)
    for _ in range(rng.randint(1, 5)):
        kind = rng.random()
        at = rng.randrange(len(data) + 1)
        if kind < 0.3 and data:
            data[min(at, len(data) - 1)] = rng.randrange(256)
        elif kind < 0.45:
            del data[at:at + rng.randint(1, 40)]
        elif kind < 0.6:
            data[at:at] = rng.choice([b"\n", b" ", b"-1 ", b"4294967295 ", b"99999999999 ", b"nan ",
                                      b"end_header\n", b"element face 7\n", b"3 0 1 2\n", b"\0",
                                      b"property list uchar int vertex_indices\n", b"f 1 2 3\n",
                                      b"v 1e38 0 0\n", b"g \xff\n"])
        elif kind < 0.75:
            j = min(len(data), at + rng.randint(1, 200))
            data[at:at] = data[at:j] * rng.randint(1, 20)   # repeat a span
        elif kind < 0.9:
            text = bytes(data)
            for word in (b"element vertex ", b"element face "):
                k = text.find(word)
                if k >= 0 and rng.random() < 0.5:
                    end = text.find(b"\n", k)
                    count = rng.choice([0, 1, 3, 2 ** 31, 2 ** 32 + 1, 10 ** 11, 10 ** 19])
                    data[k + len(word):end] = str(count).encode()
                    break
        else:
            del data[at:]
    return bytes(data)


def batch_fails(paths: list[Path], timeout: float) -> str | None:
    try:
        r = subprocess.run([sys.executable, "-c", LOADER, *map(str, paths)], capture_output=True,
                           text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timed out"
    if r.returncode != 0:
        return f"exit {r.returncode}: {r.stderr[-500:]}"
    return None


def fuzz(seconds: float, seed: int, folder: Path, save: Path | None, batch: int = 40) -> list[str]:
    rng = random.Random(seed)
    seeds = bases()
    failures = []
    deadline = time.monotonic() + seconds
    cases = 0
    while time.monotonic() < deadline:
        paths = []
        for k in range(batch):
            name, data = rng.choice(seeds)
            path = folder / f"{k}_{name}"
            path.write_bytes(mutate(rng, name, data))
            paths.append(path)
        cases += batch
        if batch_fails(paths, timeout=120) is None:
            continue
        for path in paths:                          # find the culprits
            problem = batch_fails([path], timeout=60)
            if problem:
                data = path.read_bytes()
                failures.append(problem)
                if save is not None:
                    save.mkdir(parents=True, exist_ok=True)
                    out = save / f"crash-{hashlib.sha256(data).hexdigest()[:12]}{path.suffix}"
                    out.write_bytes(data)
                    print(f"FAIL {out.name}: {problem.splitlines()[0] if problem else ''}", file=sys.stderr)
    print(f"{cases} meshes, {len(failures)} failures", file=sys.stderr)
    return failures


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=300)
    p.add_argument("--seed", type=int, default=int(time.time()))
    p.add_argument("--save", type=Path, default=REGRESSIONS)
    args = p.parse_args()
    print(f"fuzzing the mesh readers for {args.seconds:g} s, seed {args.seed}", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        failures = fuzz(args.seconds, args.seed, Path(tmp), args.save)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
