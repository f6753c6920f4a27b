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

from .. import abi
from ..frontend import ast as A
from ..frontend.checker import Effect, Kernel, Scope

F32 = ir.FloatType()
I32 = ir.IntType(32)
PTR = ir.PointerType()

_CTYPES = {"float": F32, "int32_t": I32, "uint32_t": I32}
CONTEXT_TYPE = ir.LiteralStructType(
    [ir.ArrayType(_CTYPES[t], n) if n > 1 else _CTYPES[t] for _, t, n in abi.CONTEXT_FIELDS])
_CONTEXT_INDEX = {name: i for i, (name, _, _) in enumerate(abi.CONTEXT_FIELDS)}

I64 = ir.IntType(64)
TRANSPORT_FNTY = ir.FunctionType(I32, [PTR, PTR, PTR, PTR])
UPDATE_FNTY = ir.FunctionType(I32, [PTR, PTR])
APPEARANCE_FNTY = ir.FunctionType(I32, [PTR, PTR, PTR, PTR])
#: The colour of a surface whose appearance block never sets `color`.
DEFAULT_ALBEDO = 0.7


class _KernelBuilder:
    def __init__(self, module: ir.Module, kernel: Kernel):
        self.module = module
        self.kernel = kernel
        transport = kernel.ton is not None
        appearance = kernel.event == "appearance"
        fnty = TRANSPORT_FNTY if transport else APPEARANCE_FNTY if appearance else UPDATE_FNTY
        fn = ir.Function(module, fnty, kernel.symbol)
        fn.linkage = "external"
        self.ton = self.delta = self.textures = self.rgb = None
        if transport:
            self.ton, self.surf, self.delta, self.ctx = fn.args
            names = ("ton", "surf", "surf_delta", "ctx")
        elif appearance:
            self.surf, self.textures, self.rgb, self.ctx = fn.args
            names = ("surf", "textures", "rgb", "ctx")
        else:
            self.surf, self.ctx = fn.args
            names = ("surf", "ctx")
        for arg, name in zip(fn.args, names):
            arg.name = name
        for arg in fn.args:
            arg.add_attribute("noalias")
        self.kernel = kernel
        self.b = ir.IRBuilder(fn.append_basic_block("entry"))
        self.scope: Scope | None = None
        self.numbers = kernel.statement_numbers()
        self.sites = kernel.random_sites()
        self.first_bad = self.b.alloca(I32, name="first_bad")  # see abi.TRANSPORT_SIGNATURE
        self.b.store(ir.Constant(I32, 0), self.first_bad)
        self.random_key = None
        if appearance:
            for c in range(3):
                self.b.store(ir.Constant(F32, DEFAULT_ALBEDO), self.slot_ptr(self.rgb, c))

    def _intrinsic(self, name: str, arity: int = 2):
        return self.module.declare_intrinsic(name, [F32], ir.FunctionType(F32, [F32] * arity))

    def _libm(self, name: str, arity: int):
        """A C library function (expf, logf, powf): the interpreter calls the same one."""
        try:
            return self.module.get_global(name)
        except KeyError:
            return ir.Function(self.module, ir.FunctionType(F32, [F32] * arity), name)

    def slot_ptr(self, base, index: int):
        return self.b.gep(base, [ir.Constant(I32, index)], inbounds=True, source_etype=F32)

    def load_ref(self, ref: A.Ref, lets: dict):
        slot = self.scope.resolve(ref, lets)
        if slot.space == "let":
            return lets[slot.name]
        if slot.space == "color":
            return tuple(self.b.load(self.slot_ptr(self.rgb, c), typ=F32) for c in range(3))
        if slot.space == "param":
            return ir.Constant(F32, _f32(self.scope.params[slot.name]))
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

    def arith(self, op: str, left, right):
        """One float operation, folded when both operands are constants
        (in float32, exactly as the machine would compute it).  Colours
        (3-tuples) combine component by component; a number applies to each."""
        if isinstance(left, tuple) or isinstance(right, tuple):
            lefts = left if isinstance(left, tuple) else (left,) * 3
            rights = right if isinstance(right, tuple) else (right,) * 3
            return tuple(self.arith(op, a, b) for a, b in zip(lefts, rights))
        if isinstance(left, ir.Constant) and isinstance(right, ir.Constant):
            import numpy as np

            a, b = np.float32(left.constant), np.float32(right.constant)
            with np.errstate(all="ignore"):
                value = {"+": a + b, "-": a - b, "*": a * b, "/": a / b}[op]
            return ir.Constant(F32, float(np.float32(value)))
        b = self.b
        return {"+": b.fadd, "-": b.fsub, "*": b.fmul, "/": b.fdiv}[op](left, right)

    def pick(self, name: str, a, b):
        """min/max, defined exactly (and so in the interpreter): b if b is
        strictly smaller (larger) than a or a is NaN, else a.  A NaN operand is
        ignored and ties, +0 against -0 included, keep the first operand."""
        bld = self.b
        better = bld.fcmp_ordered("<" if name == "min" else ">", b, a)
        a_is_nan = bld.fcmp_unordered("uno", a, a)
        return bld.select(bld.or_(better, a_is_nan), b, a)

    def call(self, name: str, args: list):
        b = self.b
        if name in ("min", "max"):
            acc = args[0]
            for a in args[1:]:
                acc = self.pick(name, acc, a)
            return acc
        if name == "clamp":
            return self.pick("min", self.pick("max", args[0], args[1]), args[2])
        if name == "rgb":
            return tuple(args)
        if name == "mix":              # a + (b - a) * t
            a, b_, t = args
            return self.arith("+", a, self.arith("*", self.arith("-", b_, a), t))
        if name == "smoothstep":       # t = clamp((x - e0) / (e1 - e0), 0, 1); t * t * (3 - 2 * t)
            e0, e1, x = args
            t = self.call("clamp", [self.arith("/", self.arith("-", x, e0), self.arith("-", e1, e0)),
                                    ir.Constant(F32, 0.0), ir.Constant(F32, 1.0)])
            return self.arith("*", self.arith("*", t, t),
                              self.arith("-", ir.Constant(F32, 3.0), self.arith("*", ir.Constant(F32, 2.0), t)))
        if name in ("abs", "sqrt", "floor"):
            intrinsic = {"abs": "llvm.fabs", "sqrt": "llvm.sqrt", "floor": "llvm.floor"}[name]
            return b.call(self._intrinsic(intrinsic, 1), args)
        if name == "fract":            # x - floor(x)
            return self.arith("-", args[0], self.call("floor", args))
        if name in ("exp", "log", "pow"):
            return b.call(self._libm(name + "f", len(args)), args)
        raise AssertionError(f"unchecked function {name}")

    def key(self):
        """The context's 64-bit random() key, loaded once per kernel call."""
        if self.random_key is None:
            # in the entry block (before its terminator, if any): dominates every use
            with self.b.goto_block(self.b.function.entry_basic_block):
                index = _CONTEXT_INDEX["random_key"]
                words = []
                for k in range(2):
                    ptr = self.b.gep(self.ctx, [ir.Constant(I32, 0), ir.Constant(I32, index),
                                                ir.Constant(I32, k)], inbounds=True, source_etype=CONTEXT_TYPE)
                    words.append(self.b.zext(self.b.load(ptr, typ=I32), I64))
                high = self.b.shl(words[1], ir.Constant(I64, 32))
                self.random_key = self.b.or_(high, words[0])
        return self.random_key

    def random(self, site: int):
        """abi.random_value(key, site): splitmix64 of key ^ site * golden, top 24 bits."""
        b = self.b
        c = lambda v: ir.Constant(I64, v & 0xFFFFFFFFFFFFFFFF)
        z = b.xor(self.key(), c(site * abi.RANDOM_GOLDEN))
        z = b.add(z, c(abi.RANDOM_GOLDEN))
        z = b.mul(b.xor(z, b.lshr(z, c(30))), c(abi.RANDOM_MIX[0]))
        z = b.mul(b.xor(z, b.lshr(z, c(27))), c(abi.RANDOM_MIX[1]))
        z = b.xor(z, b.lshr(z, c(31)))
        bits = b.trunc(b.lshr(z, c(40)), I32)
        return b.fmul(b.uitofp(bits, F32), ir.Constant(F32, 2.0 ** -24))

    def expr(self, e: A.Expr, lets: dict):
        b = self.b
        if isinstance(e, A.Number):
            return ir.Constant(F32, _f32(e.value))
        if isinstance(e, A.Ref):
            return self.load_ref(e, lets)
        if isinstance(e, A.Unary):
            operand = self.expr(e.operand, lets)
            if isinstance(operand, tuple):
                return tuple(b.fneg(c) if not isinstance(c, ir.Constant) else ir.Constant(F32, -c.constant)
                             for c in operand)
            if isinstance(operand, ir.Constant):
                return ir.Constant(F32, -operand.constant)
            return b.fneg(operand)
        if isinstance(e, A.Binary):
            return self.arith(e.op, self.expr(e.left, lets), self.expr(e.right, lets))
        if isinstance(e, A.Compare):
            # ordered comparisons are false on NaN; != is true on NaN (IEEE, as in C)
            compare = b.fcmp_unordered if e.op == "!=" else b.fcmp_ordered
            return compare(e.op, self.expr(e.left, lets), self.expr(e.right, lets))
        if isinstance(e, A.Logic):     # both sides are evaluated (no short circuit)
            left = self.expr(e.left, lets)
            if e.op == "not":
                return b.not_(left)
            right = self.expr(e.right, lets)
            return b.and_(left, right) if e.op == "and" else b.or_(left, right)
        if isinstance(e, A.Call):
            if e.name == "random":
                return self.random(self.sites[id(e)])
            if e.name == "texture":
                base = 3 * self.kernel.textures[id(e)]
                return tuple(b.load(self.slot_ptr(self.textures, base + c), typ=F32) for c in range(3))
            return self.call(e.name, [self.expr(a, lets) for a in e.args])
        raise AssertionError(f"unchecked expression {e!r}")

    def store_finite(self, new, ptr, number: int) -> None:
        """Store unless NaN or infinite; else remember the first such statement."""
        b = self.b
        finite = b.fcmp_ordered("!=", b.call(self._intrinsic("llvm.fabs", 1), [new]),
                                ir.Constant(F32, float("inf")))
        with b.if_else(finite) as (store, skip):
            with store:
                b.store(new, ptr)
            with skip:
                seen = b.load(self.first_bad, typ=I32)
                first = b.icmp_signed("==", seen, ir.Constant(I32, 0))
                b.store(b.select(first, ir.Constant(I32, number), seen), self.first_bad)

    def assign(self, st: A.Assign, lets: dict) -> None:
        slot = self.scope.resolve(st.target, lets)
        value = self.expr(st.value, lets)
        b = self.b
        if slot.space == "color":
            for c in range(3):
                self.store_finite(value[c], self.slot_ptr(self.rgb, c), self.numbers[id(st)])
            return
        if slot.space == "surf" and self.delta is not None:
            ptr = self.slot_ptr(self.delta, slot.index)  # transport: accumulate a delta
        else:
            ptr = self.slot_ptr(self.ton if slot.space == "ton" else self.surf, slot.index)
        if st.op == "=":
            new = value
        else:
            old = b.load(ptr, typ=F32)
            new = {"+=": b.fadd, "-=": b.fsub, "*=": b.fmul}[st.op](old, value)
        # A NaN or infinite result is not stored; the first such statement is returned.
        self.store_finite(new, ptr, self.numbers[id(st)])

    def statements(self, body: list, lets: dict) -> None:
        lets = dict(lets)
        for st in body:
            if isinstance(st, A.Let):
                lets[st.name] = self.expr(st.value, lets)
            elif isinstance(st, A.If):
                cond = self.expr(st.cond, lets)
                with self.b.if_else(cond) as (then, otherwise):
                    with then:
                        self.statements(st.then, lets)
                    with otherwise:
                        self.statements(st.otherwise, lets)
            else:
                self.b.comment(f"{st.target.pos.line}:{st.target.pos.col}: "
                               f"{'.'.join(st.target.parts)} {st.op} ...")
                self.assign(st, lets)

    def build(self) -> None:
        for scope, body in self.kernel.bodies:
            self.scope = scope
            self.statements(body, {})
        self.b.ret(self.b.load(self.first_bad, typ=I32))


def _f32(value: float) -> float:
    import numpy as np

    with np.errstate(over="ignore"):
        return float(np.float32(value))


def generate(effect: Effect) -> ir.Module:
    """The whole effect as one LLVM module, one function per kernel."""
    module = ir.Module(name=effect.path)
    module.add_named_metadata("gamma.abi_version").add(
        module.add_metadata([ir.Constant(I32, abi.ABI_VERSION)]))
    for kernel in effect.kernels:
        _KernelBuilder(module, kernel).build()
    return module
