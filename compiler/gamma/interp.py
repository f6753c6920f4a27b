"""Reference interpreter: runs a kernel's rule bodies over the same AST.

Deliberately simple and independent of the code generator (it shares only
name resolution, ``Scope.resolve``).  It is the oracle the compiled kernels
are tested against: every operation is done in numpy float32, in source
order, with the same semantics as ``codegen.py`` (min/max ignore NaN like
``llvm.minnum``/``maxnum``).
"""

from __future__ import annotations

import numpy as np

from . import ast as A
from .checker import Kernel, Scope

f32 = np.float32


class Context:
    """Values of the read-only context (fields of ``abi.CONTEXT_FIELDS``)."""

    def __init__(self, iteration: int = 0, interactions: int = 0, height: float = 0.0,
                 position=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 0.0), direction=(0.0, 0.0, 0.0)):
        self.iteration = iteration
        self.interactions = interactions
        self.height = f32(height)
        self.position = np.asarray(position, np.float32)
        self.normal = np.asarray(normal, np.float32)
        self.direction = np.asarray(direction, np.float32)


def _eval(e: A.Expr, scope: Scope, ton, surf, ctx: Context):
    if isinstance(e, A.Number):
        return f32(e.value)
    if isinstance(e, A.Ref):
        slot = scope.resolve(e)
        if slot.space == "ctx":
            value = getattr(ctx, slot.name)
            return f32(value[slot.index] if np.ndim(value) else value)
        return (ton if slot.space == "ton" else surf)[slot.index]
    if isinstance(e, A.Unary):
        return -_eval(e.operand, scope, ton, surf, ctx)
    if isinstance(e, A.Binary):
        a = _eval(e.left, scope, ton, surf, ctx)
        b = _eval(e.right, scope, ton, surf, ctx)
        if e.op == "+":
            return f32(a + b)
        if e.op == "-":
            return f32(a - b)
        if e.op == "*":
            return f32(a * b)
        return f32(a / b)
    if isinstance(e, A.Call):
        args = [_eval(a, scope, ton, surf, ctx) for a in e.args]
        if e.name == "min":
            acc = args[0]
            for a in args[1:]:
                acc = np.fmin(acc, a)
            return f32(acc)
        if e.name == "max":
            acc = args[0]
            for a in args[1:]:
                acc = np.fmax(acc, a)
            return f32(acc)
        if e.name == "clamp":
            return f32(np.fmin(np.fmax(args[0], args[1]), args[2]))
    raise AssertionError(f"unchecked expression {e!r}")


def run_kernel(kernel: Kernel, ton, surf, delta, ctx: Context) -> None:
    """Run in place, like the compiled kernel: ``ton`` and ``delta`` (transport)
    or ``surf`` (update) are float32 arrays that get modified."""
    transport = kernel.ton is not None
    with np.errstate(all="ignore"):
        for scope, body in kernel.bodies:
            for st in body:
                slot = scope.resolve(st.target)
                value = _eval(st.value, scope, ton, surf, ctx)
                if slot.space == "ton":
                    dest = ton
                elif transport:
                    dest = delta
                else:
                    dest = surf
                old = dest[slot.index]
                dest[slot.index] = {"=": value, "+=": f32(old + value), "-=": f32(old - value),
                                    "*=": f32(old * value)}[st.op]
