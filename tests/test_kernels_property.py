"""Property-based differential test (hypothesis): random well-typed rule
bodies with let, if/else, comparisons, boolean operators and every built-in,
compiled with llvmlite and run through ctypes, against the reference
interpreter.  Agreement is bit for bit (float32 in source order, no
fast-math, the runtime's own exp/log/pow on both sides); only a NaN's payload may differ.
Inputs include the IEEE special values (+-0, +-inf, NaN, subnormals)."""

import ctypes

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gamma.backends.jit import JitKernels
from gamma.frontend.checker import check
from gamma.ir.builtins import FUNCTIONS
from gamma.backends.interp import Context
from gamma.frontend.parser import parse
from test_kernels import HEADER, TRANSPORT, UPDATE, GammaContext, assert_hit_and_update_agree, set_key

READS = ["t.a", "t.b", "s.p", "s.q", "s.reflectance.straight", "iteration", "interactions",
         "height", "position.y", "normal.x", "direction.z", 'attribute("w")', 'attribute("flow.x")']
SPECIAL = [0.0, -0.0, 1.0, -1.0, 0.5, 2.0, 1e-42, -1e-42, 3.4e38, float("inf"), float("-inf"),
           float("nan"), 1e-7, 123.25]


def numbers():
    return st.sampled_from(["0", "1", "2", "0.5", "3.25", "1e-3", "100"])


def floats(names):
    leaf = st.one_of(numbers(), st.sampled_from(names))

    def grow(inner):
        most = lambda name: 3 if FUNCTIONS[name].max_args is None else FUNCTIONS[name].max_args
        # built-ins of numbers (the vector ones have their own test, test_vectors.py)
        fn = st.sampled_from(sorted(n for n, f in FUNCTIONS.items()
                                    if not f.appearance_only and f.args is None
                                    and not f.string_arg)).flatmap(
            lambda name: st.lists(inner, min_size=FUNCTIONS[name].min_args, max_size=most(name)).map(
                lambda args: f"{name}({', '.join(args)})"))
        binary = st.tuples(inner, st.sampled_from("+-*/"), inner).map(lambda t: f"({t[0]} {t[1]} {t[2]})")
        return st.one_of(binary, inner.map(lambda x: f"-{x}"), fn)

    return st.recursive(leaf, grow, max_leaves=8)


def bools(names):
    compare = st.tuples(floats(names), st.sampled_from(["<", "<=", ">", ">=", "==", "!="]),
                        floats(names)).map(lambda t: f"{t[0]} {t[1]} {t[2]}")
    return st.recursive(compare, lambda inner: st.one_of(
        st.tuples(inner, st.sampled_from(["and", "or"]), inner).map(lambda t: f"({t[0]} {t[1]} {t[2]})"),
        inner.map(lambda x: f"not ({x})")), max_leaves=3)


@st.composite
def bodies(draw, targets, ops, names, depth=0):
    lines, lets = [], list(names)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["assign", "assign", "let", "if"] if depth < 2 else ["assign", "let"]))
        if kind == "let":
            name = f"v{depth}_{len(lines)}"
            lines.append(f"let {name} = {draw(floats(lets))}")
            lets.append(name)
        elif kind == "if":
            then = draw(bodies(targets, ops, lets, depth + 1))
            other = draw(st.one_of(st.just(""), bodies(targets, ops, lets, depth + 1).map(
                lambda b: f" else {{\n{b}\n}}")))
            lines.append(f"if {draw(bools(lets))} {{\n{then}\n}}{other}")
        else:
            target = draw(st.sampled_from(targets))
            op = draw(st.sampled_from(ops[target]))
            lines.append(f"{target} {op} {draw(floats(lets))}")
    return "\n".join(lines)


TRANSPORT_TARGETS = {"t.a": ["=", "+=", "-=", "*="], "t.b": ["=", "+="], "s.p": ["+=", "-="],
                     "s.q": ["+=", "-="]}
UPDATE_TARGETS = {"s.p": ["=", "+=", "-=", "*="], "s.q": ["=", "*="],
                  "s.reflectance.straight": ["=", "-="]}
UPDATE_READS = ["s.p", "s.q", "s.reflectance.straight", "iteration", "height", "position.z", 'attribute("w")']


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(hit=bodies(list(TRANSPORT_TARGETS), TRANSPORT_TARGETS, READS),
       upd=bodies(list(UPDATE_TARGETS), UPDATE_TARGETS, UPDATE_READS),
       seed=st.integers(0, 2**32 - 1))
def test_random_bodies_agree(hit, upd, seed):
    text = HEADER + f"on hit(t: T, s: S) {{\n{hit}\n}}\nupdate(s: S) {{\n{upd}\n}}\n"
    effect = check(parse(text, "random.gamma"))
    jit = JitKernels(effect)
    hit_k = next(k for k in effect.kernels if k.event == "hit")
    upd_k = next(k for k in effect.kernels if k.event == "update")
    hit_fn, upd_fn = TRANSPORT(jit.address[hit_k.symbol]), UPDATE(jit.address[upd_k.symbol])
    rng = np.random.default_rng(seed)
    for _ in range(20):
        pick = lambda n: np.where(rng.random(n) < 0.3, rng.choice(SPECIAL, n),
                                  rng.standard_normal(n) * 10.0 ** rng.integers(-3, 4, n)).astype(np.float32)
        ton, surf, vec = pick(2), pick(effect.row_width), pick(10)
        it, n = int(rng.integers(1, 50)), int(rng.integers(1, 10))
        ctx = GammaContext(iteration=it, interactions=n, height=float(vec[9]),
                           position=(ctypes.c_float * 3)(*vec[0:3]), normal=(ctypes.c_float * 3)(*vec[3:6]),
                           direction=(ctypes.c_float * 3)(*vec[6:9]))
        key = int(rng.integers(0, 2**63))
        set_key(ctx, key)
        ictx = Context(iteration=it, interactions=n, height=vec[9], position=vec[0:3],
                       normal=vec[3:6], direction=vec[6:9], random_key=key)
        assert_hit_and_update_agree(hit_fn, upd_fn, hit_k, upd_k, ton, surf, ctx, ictx, text)
