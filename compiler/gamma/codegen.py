"""LLVM IR generation for the kernels of a checked ``Effect``.

One C-ABI function per kernel (``Kernel.symbol``), with the signatures
declared in ``abi.py``.  All arithmetic is 32-bit float, in source order,
without fast-math flags, so results match the reference interpreter
(``interp.py``) bit for bit.  ``min``/``max`` are ``llvm.minnum``/``maxnum``
(a NaN operand is ignored), ``clamp(x, lo, hi)`` is ``min(max(x, lo), hi)``.

Each statement's instructions are preceded by a comment naming the user's
``line:col``, so the output of ``gammac emit --ir`` reads back to the source.
"""

from __future__ import annotations

from llvmlite import ir

from . import abi
from . import ast as A
from .checker import Effect, Kernel, Scope

F32 = ir.FloatType()
I32 = ir.IntType(32)
PTR = ir.PointerType()

_CTYPES = {"float": F32, "int32_t": I32}
CONTEXT_TYPE = ir.LiteralStructType(
    [ir.ArrayType(_CTYPES[t], n) if n > 1 else _CTYPES[t] for _, t, n in abi.CONTEXT_FIELDS])
_CONTEXT_INDEX = {name: i for i, (name, _, _) in enumerate(abi.CONTEXT_FIELDS)}

TRANSPORT_FNTY = ir.FunctionType(ir.VoidType(), [PTR, PTR, PTR, PTR])
UPDATE_FNTY = ir.FunctionType(ir.VoidType(), [PTR, PTR])


class _KernelBuilder:
    def __init__(self, module: ir.Module, kernel: Kernel):
        self.module = module
        self.kernel = kernel
        transport = kernel.ton is not None
        fn = ir.Function(module, TRANSPORT_FNTY if transport else UPDATE_FNTY, kernel.symbol)
        fn.linkage = "external"
        if transport:
            self.ton, self.surf, self.delta, self.ctx = fn.args
            for arg, name in zip(fn.args, ("ton", "surf", "surf_delta", "ctx")):
                arg.name = name
        else:
            self.surf, self.ctx = fn.args
            self.ton = self.delta = None
            self.surf.name, self.ctx.name = "surf", "ctx"
        for arg in fn.args:
            arg.add_attribute("noalias")
        self.b = ir.IRBuilder(fn.append_basic_block("entry"))
        self.scope: Scope | None = None

    def _intrinsic(self, name: str):
        return self.module.declare_intrinsic(name, [F32], ir.FunctionType(F32, [F32, F32]))

    def slot_ptr(self, base, index: int):
        return self.b.gep(base, [ir.Constant(I32, index)], inbounds=True, source_etype=F32)

    def load_ref(self, ref: A.Ref):
        slot = self.scope.resolve(ref)
        if slot.space == "ctx":
            index = _CONTEXT_INDEX[slot.name]
            _, ctype, count = abi.CONTEXT_FIELDS[index]
            path = [ir.Constant(I32, 0), ir.Constant(I32, index)]
            if count > 1:
                path.append(ir.Constant(I32, slot.index))
            field = self.b.gep(self.ctx, path, inbounds=True, source_etype=CONTEXT_TYPE)
            value = self.b.load(field, typ=_CTYPES[ctype])
            return value if ctype == "float" else self.b.sitofp(value, F32)
        base = self.ton if slot.space == "ton" else self.surf
        return self.b.load(self.slot_ptr(base, slot.index), typ=F32)

    def expr(self, e: A.Expr):
        b = self.b
        if isinstance(e, A.Number):
            return ir.Constant(F32, _f32(e.value))
        if isinstance(e, A.Ref):
            return self.load_ref(e)
        if isinstance(e, A.Unary):
            return b.fneg(self.expr(e.operand))
        if isinstance(e, A.Binary):
            left, right = self.expr(e.left), self.expr(e.right)
            return {"+": b.fadd, "-": b.fsub, "*": b.fmul, "/": b.fdiv}[e.op](left, right)
        if isinstance(e, A.Call):
            args = [self.expr(a) for a in e.args]
            if e.name in ("min", "max"):
                fn = self._intrinsic(f"llvm.{e.name}num")
                acc = args[0]
                for a in args[1:]:
                    acc = b.call(fn, [acc, a])
                return acc
            if e.name == "clamp":
                lo = b.call(self._intrinsic("llvm.maxnum"), [args[0], args[1]])
                return b.call(self._intrinsic("llvm.minnum"), [lo, args[2]])
        raise AssertionError(f"unchecked expression {e!r}")

    def assign(self, st: A.Assign) -> None:
        slot = self.scope.resolve(st.target)
        value = self.expr(st.value)
        b = self.b
        if slot.space == "surf" and self.delta is not None:
            ptr = self.slot_ptr(self.delta, slot.index)  # transport: accumulate a delta
        else:
            ptr = self.slot_ptr(self.ton if slot.space == "ton" else self.surf, slot.index)
        if st.op == "=":
            new = value
        else:
            old = b.load(ptr, typ=F32)
            new = {"+=": b.fadd, "-=": b.fsub, "*=": b.fmul}[st.op](old, value)
        b.store(new, ptr)

    def build(self) -> None:
        for scope, body in self.kernel.bodies:
            self.scope = scope
            for st in body:
                self.b.comment(f"{st.target.pos.line}:{st.target.pos.col}: "
                               f"{'.'.join(st.target.parts)} {st.op} ...")
                self.assign(st)
        self.b.ret_void()


def _f32(value: float) -> float:
    import numpy as np

    return float(np.float32(value))


def generate(effect: Effect) -> ir.Module:
    """The whole effect as one LLVM module, one function per kernel."""
    module = ir.Module(name=effect.path)
    module.add_named_metadata("gamma.abi_version").add(
        module.add_metadata([ir.Constant(I32, abi.ABI_VERSION)]))
    for kernel in effect.kernels:
        _KernelBuilder(module, kernel).build()
    return module
