"""The fuzzer of the mesh readers: mutants of the valid files of
tests/mesh_corpus.py (bytes flipped, header lines edited, counts changed,
bodies cut or repeated; for glTF also the JSON's numbers, indices and URIs
replaced or deleted) loaded as ``gammac run --scene`` loads them
(``mesh_corpus.load``: PLY and OBJ by ``gamma._runtime.Mesh.load``, glTF by
the driver's reader) in a child process with a memory limit and a time limit.
A child that is killed, times out, prints a warning or raises anything but
the one-line ValueError / SceneError is a failure; the files of that batch
that fail alone are saved to tests/mesh_regressions/, which
tests/test_robust_input.py loads on every ``make test``.  ``make test`` also
runs a fixed number of mutants (tests/test_fuzz.py).

    python tests/fuzz_meshes.py --seconds 300 [--seed N]
"""

from __future__ import annotations

import argparse
import hashlib
import json
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
sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})
from mesh_corpus import load
for path in sys.argv[1:]:
    outcome = load(path)
    if outcome[0] == "error" and (chr(10) in outcome[1] or path not in outcome[1]):
        sys.exit("not one line naming the file: " + outcome[1])
"""


def bases() -> list[tuple[str, bytes]]:
    return [(name, data) for name, data, expected in mesh_corpus.cases() if expected == "ok"]


def companions() -> list[tuple[str, bytes]]:
    """Files the bases refer to (a glTF's external buffer), written once."""
    return [(name, data) for name, data, expected in mesh_corpus.cases() if expected == "companion"]


#: Values a glTF mutant puts in place of a JSON item.
GLTF_VALUES = [-1, 0, 1, 3, 2 ** 31, 2 ** 32 + 1, 10 ** 12, 10 ** 19, 1e39, 0.5, "x", "", None, [], {}, [0],
               "data:application/octet-stream;base64,AAAA", "data:,x", "missing.bin", "../..", "VEC3", 5126]


def mutate_gltf_json(rng: random.Random, name: str, data: bytes) -> bytes | None:
    """The file with one item of its JSON replaced or deleted (None if the
    JSON cannot be found)."""
    try:
        if name.endswith(".glb"):
            text_len = int.from_bytes(data[12:16], "little")
            doc = json.loads(data[20:20 + text_len])
            bin_chunk = data[20 + text_len + 8:] if len(data) > 20 + text_len + 8 else None
        else:
            doc = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        return None
    for _ in range(rng.randint(1, 3)):
        places = []

        def walk(node):
            items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
            for key, value in items:
                places.append((node, key))
                walk(value)

        walk(doc)
        if not places:
            break
        node, key = rng.choice(places)
        if isinstance(node, dict) and rng.random() < 0.2:
            del node[key]
        else:
            node[key] = rng.choice(GLTF_VALUES)
    if name.endswith(".glb"):
        return mesh_corpus.glb(doc, bin_chunk)
    return json.dumps(doc).encode()


def mutate(rng: random.Random, name: str, data: bytes) -> bytes:
    if name.endswith((".gltf", ".glb")) and rng.random() < 0.6:
        mutant = mutate_gltf_json(rng, name, data)
        if mutant is not None:
            return mutant
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
    if r.stderr:
        return f"printed to stderr: {r.stderr[-500:]}"
    return None


def fuzz(seconds: float | None, seed: int, folder: Path, save: Path | None, batch: int = 40,
         cases: int | None = None) -> list[str]:
    """Mutants for ``seconds``, or ``cases`` of them; the failures found."""
    rng = random.Random(seed)
    seeds = bases()
    for name, data in companions():
        (folder / name).write_bytes(data)
    failures = []
    deadline = time.monotonic() + seconds if seconds is not None else None
    done = 0
    while (time.monotonic() < deadline) if deadline is not None else done < cases:
        paths = []
        for k in range(batch):
            name, data = rng.choice(seeds)
            path = folder / f"{k}_{name}"
            path.write_bytes(mutate(rng, name, data))
            paths.append(path)
        done += batch
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
    print(f"{done} meshes, {len(failures)} failures", file=sys.stderr)
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
