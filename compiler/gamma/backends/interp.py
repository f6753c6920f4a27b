"""Reference interpreter: runs a kernel's rule bodies over the same AST.

Deliberately simple and independent of the code generator (it shares only
name resolution, ``Scope.resolve``).  It is the oracle the compiled kernels
are tested against: every operation is done in numpy float32, in source
order, with the same semantics as ``codegen.py`` (min/max ignore NaN like
``llvm.minnum``/``maxnum``).
"""

from __future__ import annotations

import numpy as np

from ..frontend import ast as A
from ..abi import random_value
from ..frontend.checker import Kernel, Scope

f32 = np.float32


class Context:
    """Values of the read-only context (fields of ``abi.CONTEXT_FIELDS``)."""

    def __init__(self, iteration: int = 0, interactions: int = 0, height: float = 0.0,
                 position=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 0.0), direction=(0.0, 0.0, 0.0),
                 random_key: int = 0):
        self.random_key = random_key
        self.iteration = iteration
        self.interactions = interactions
        self.height = f32(height)
        self.position = np.asarray(position, np.float32)
        self.normal = np.asarray(normal, np.float32)
        self.direction = np.asarray(direction, np.float32)
        self.uv = np.zeros(2, np.float32)


def _libm():
    """The C library's expf/logf/powf: the compiled kernels call the same ones
    (numpy's own float32 exp/log differ from libm in the last bit)."""
    import ctypes
    import ctypes.util

    lib = ctypes.CDLL(ctypes.util.find_library("m"))
    fns = {}
    for name, arity in (("expf", 1), ("logf", 1), ("powf", 2)):
        fn = getattr(lib, name)
        fn.restype = ctypes.c_float
        fn.argtypes = [ctypes.c_float] * arity
        fns[name] = fn
    return fns


_LIBM = _libm()


def _arith(op: str, a, b):
    """A float32 operation; colours (3-tuples) component by component."""
    if isinstance(a, tuple) or isinstance(b, tuple):
        a = a if isinstance(a, tuple) else (a,) * 3
        b = b if isinstance(b, tuple) else (b,) * 3
        return tuple(_arith(op, x, y) for x, y in zip(a, b))
    return f32({"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide}[op](a, b))


def _pick(name: str, a, b):
    """b if b is strictly smaller (min) / larger (max) than a, or a is NaN; else a."""
    better = b < a if name == "min" else b > a
    return f32(b if better or np.isnan(a) else a)


def _call(name: str, args: list):
    if name in ("min", "max"):
        acc = args[0]
        for a in args[1:]:
            acc = _pick(name, acc, a)
        return acc
    if name == "clamp":
        return _pick("min", _pick("max", args[0], args[1]), args[2])
    if name == "rgb":
        return tuple(args)
    if name == "mix":
        a, b, t = args
        return _arith("+", a, _arith("*", _arith("-", b, a), t))
    if name == "smoothstep":
        e0, e1, x = args
        t = _call("clamp", [f32(f32(x - e0) / f32(e1 - e0)), f32(0), f32(1)])
        return f32(f32(t * t) * f32(f32(3) - f32(f32(2) * t)))
    if name == "abs":
        return f32(np.abs(args[0]))
    if name == "sqrt":
        return f32(np.sqrt(args[0]))
    if name == "floor":
        return f32(np.floor(args[0]))
    if name == "fract":
        return f32(args[0] - np.floor(args[0]))
    if name in ("exp", "log", "pow"):
        return f32(_LIBM[name + "f"](*[float(a) for a in args]))
    raise AssertionError(f"unchecked function {name}")


_COMPARE = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal,
            "==": np.equal, "!=": np.not_equal}


def _eval(e: A.Expr, scope: Scope, ton, surf, ctx: Context, lets: dict):
    if isinstance(e, A.Number):
        return f32(e.value)
    if isinstance(e, A.Ref):
        slot = scope.resolve(e, lets)
        if slot.space == "let":
            return lets[slot.name]
        if slot.space == "color":
            return tuple(f32(c) for c in _STATE.rgb)
        if slot.space == "param":
            return f32(scope.params[slot.name])
        if slot.space == "ctx":
            value = getattr(ctx, slot.name)
            return f32(value[slot.index] if np.ndim(value) else value)
        return (ton if slot.space == "ton" else surf)[slot.index]
    if isinstance(e, A.Unary):
        value = _eval(e.operand, scope, ton, surf, ctx, lets)
        return tuple(-c for c in value) if isinstance(value, tuple) else -value
    if isinstance(e, A.Binary):
        a = _eval(e.left, scope, ton, surf, ctx, lets)
        b = _eval(e.right, scope, ton, surf, ctx, lets)
        return _arith(e.op, a, b)
    if isinstance(e, A.Compare):
        a = _eval(e.left, scope, ton, surf, ctx, lets)
        b = _eval(e.right, scope, ton, surf, ctx, lets)
        return bool(_COMPARE[e.op](a, b))
    if isinstance(e, A.Logic):  # both sides evaluated, like the compiled code
        a = _eval(e.left, scope, ton, surf, ctx, lets)
        if e.op == "not":
            return not a
        b = _eval(e.right, scope, ton, surf, ctx, lets)
        return (a and b) if e.op == "and" else (a or b)
    if isinstance(e, A.Call):
        if e.name == "random":
            return f32(random_value(ctx.random_key, _STATE.sites[id(e)]))
        if e.name == "texture":
            base = 3 * _STATE.kernel.textures[id(e)]
            return tuple(f32(_STATE.textures[base + c]) for c in range(3))
        return _call(e.name, [_eval(a, scope, ton, surf, ctx, lets) for a in e.args])
    raise AssertionError(f"unchecked expression {e!r}")


def _run(body: list, scope: Scope, ton, surf, delta, ctx: Context, lets: dict, transport: bool):
    lets = dict(lets)
    for st in body:
        if isinstance(st, A.Let):
            lets[st.name] = _eval(st.value, scope, ton, surf, ctx, lets)
        elif isinstance(st, A.If):
            branch = st.then if _eval(st.cond, scope, ton, surf, ctx, lets) else st.otherwise
            _run(branch, scope, ton, surf, delta, ctx, lets, transport)
        else:
            slot = scope.resolve(st.target, lets)
            value = _eval(st.value, scope, ton, surf, ctx, lets)
            if slot.space == "color":
                for c in range(3):
                    if np.isfinite(value[c]):
                        _STATE.rgb[c] = value[c]
                    elif not _STATE.first_bad:
                        _STATE.first_bad = _STATE.numbers[id(st)]
                continue
            dest = ton if slot.space == "ton" else (delta if transport else surf)
            old = dest[slot.index]
            new = {"=": value, "+=": f32(old + value), "-=": f32(old - value),
                   "*=": f32(old * value)}[st.op]
            if np.isfinite(new):
                dest[slot.index] = new
            elif not _STATE.first_bad:          # not stored; the first such statement is reported
                _STATE.first_bad = _STATE.numbers[id(st)]


class _State:
    """Per-call bookkeeping shared by the helpers above (statement and random()
    site numbers of the running kernel, the first non-finite statement)."""

    numbers: dict = {}
    sites: dict = {}
    first_bad = 0
    kernel = None
    textures = None
    rgb = None


_STATE = _State()


def run_kernel(kernel: Kernel, ton, surf, delta, ctx: Context) -> int:
    """Run in place, like the compiled kernel: ``ton`` and ``delta`` (transport)
    or ``surf`` (update) are float32 arrays that get modified.  Returns 0 or the
    number of the first statement whose result was NaN or infinite."""
    _STATE.numbers, _STATE.sites, _STATE.first_bad = kernel.statement_numbers(), kernel.random_sites(), 0
    _STATE.kernel = kernel
    with np.errstate(all="ignore"):
        for scope, body in kernel.bodies:
            _run(body, scope, ton, surf, delta, ctx, {}, kernel.ton is not None)
    return _STATE.first_bad


def run_appearance(kernel: Kernel, surf, textures, ctx: Context):
    """The colour an appearance kernel gives: (rgb float32[3], first non-finite statement)."""
    from .codegen import DEFAULT_ALBEDO

    _STATE.textures = np.asarray(textures, np.float32).reshape(-1)
    _STATE.rgb = np.full(3, DEFAULT_ALBEDO, np.float32)
    bad = run_kernel(kernel, None, surf, None, ctx)
    return _STATE.rgb.copy(), bad
