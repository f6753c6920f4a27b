"""LLVM IR generation for the kernels of an effect's IR (``ir.effect``).

One C-ABI function per kernel (``Kernel.symbol``), with the signatures
declared in ``abi.py``.  It reads the IR only: names are already bound to
slots, built-ins are lowered by their entry in ``ir.builtins``.  All arithmetic is 32-bit float, in source order,
without fast-math flags, so results match the reference interpreter
(``interp.py``) bit for bit.  ``min``/``max`` are ``llvm.minnum``/``maxnum``
(a NaN operand is ignored), ``clamp(x, lo, hi)`` is ``min(max(x, lo), hi)``.

Each statement's instructions are preceded by a comment naming the user's
``line:col``, so the output of ``gammac emit --ir`` reads back to the source.
"""

from __future__ import annotations

from llvmlite import ir

from .. import abi
from ..ir import effect as I
from ..ir.builtins import FUNCTIONS, NOISE_BITS, NOISE_CLAMP, noise_salt
from ..ir.effect import Effect, Kernel
from ..ir.float32 import arith_f32

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


class _KernelBuilder:
    def __init__(self, module: ir.Module, kernel: Kernel):
        self.module = module
        self.kernel = kernel
        transport = kernel.ton is not None
        appearance = kernel.event == "appearance"
        fnty = TRANSPORT_FNTY if transport else APPEARANCE_FNTY if appearance else UPDATE_FNTY
        fn = ir.Function(module, fnty, kernel.symbol)
        fn.linkage = "external"
        self.ton = self.delta = self.textures = self.look = None
        if transport:
            self.ton, self.surf, self.delta, self.ctx = fn.args
            names = ("ton", "surf", "surf_delta", "ctx")
        elif appearance:
            self.surf, self.textures, self.look, self.ctx = fn.args
            names = ("surf", "textures", "look", "ctx")
        else:
            self.surf, self.ctx = fn.args
            names = ("surf", "ctx")
        for arg, name in zip(fn.args, names):
            arg.name = name
        for arg in fn.args:
            arg.add_attribute("noalias")
        self.kernel = kernel
        self.b = ir.IRBuilder(fn.append_basic_block("entry"))
        self.first_bad = self.b.alloca(I32, name="first_bad")  # see abi.TRANSPORT_SIGNATURE
        self.b.store(ir.Constant(I32, 0), self.first_bad)
        self.random_key = None

    def _intrinsic(self, name: str, arity: int = 2):
        return self.module.declare_intrinsic(name, [F32], ir.FunctionType(F32, [F32] * arity))

    def _own_math(self, name: str, arity: int):
        """A function of the runtime's own math (gamma_expf, ...: ``ownmath``);
        the interpreter calls the same one."""
        try:
            return self.module.get_global(name)
        except KeyError:
            return ir.Function(self.module, ir.FunctionType(F32, [F32] * arity), name)

    def slot_ptr(self, base, index: int):
        return self.b.gep(base, [ir.Constant(I32, index)], inbounds=True, source_etype=F32)

    def load(self, var: I.Var, lets: dict):
        if var.space == "let":
            return lets[var.name]
        if var.space == "look":
            if var.name == "color":
                return tuple(self.b.load(self.slot_ptr(self.look, var.slot + c), typ=F32) for c in range(3))
            return self.b.load(self.slot_ptr(self.look, var.slot), typ=F32)
        if var.space == "ctx":
            index = _CONTEXT_INDEX[var.name]
            _, ctype, count = abi.CONTEXT_FIELDS[index]
            if count > 1 and var.component is None:    # a whole vector (uv: z = 0)
                return tuple(self.context_float(index, c) if c < count else ir.Constant(F32, 0.0)
                             for c in range(3))
            if count > 1:
                return self.context_float(index, var.component) if var.component < count \
                    else ir.Constant(F32, 0.0)
            field = self.b.gep(self.ctx, [ir.Constant(I32, 0), ir.Constant(I32, index)], inbounds=True,
                               source_etype=CONTEXT_TYPE)
            value = self.b.load(field, typ=_CTYPES[ctype])
            return value if ctype == "float" else self.b.sitofp(value, F32)
        base = self.ton if var.space == "ton" else self.surf
        return self.b.load(self.slot_ptr(base, var.slot), typ=F32)

    def context_float(self, index: int, component: int):
        field = self.b.gep(self.ctx, [ir.Constant(I32, 0), ir.Constant(I32, index), ir.Constant(I32, component)],
                           inbounds=True, source_etype=CONTEXT_TYPE)
        return self.b.load(field, typ=F32)

    # -- the emitter interface the lowerings of ir.builtins use --

    def if_zero(self, x, when_zero, otherwise):
        """``when_zero`` if x == 0 (+0 or -0), else ``otherwise``."""
        return self.b.select(self.b.fcmp_ordered("==", x, ir.Constant(F32, 0.0)), when_zero, otherwise)

    def gradient_noise(self, p, octave: int):
        """The signed gradient noise at the vector ``p`` (ir.builtins.ref_gradient_noise)."""
        return self.b.call(_noise_function(self.module), [*p, ir.Constant(I64, noise_salt(octave))])

    def const(self, value: float):
        return ir.Constant(F32, value)

    def arith(self, op: str, left, right):
        """One float operation, folded when both operands are constants
        (in float32, exactly as the machine would compute it).  Colours
        (3-tuples) combine component by component; a number applies to each."""
        if isinstance(left, tuple) or isinstance(right, tuple):
            lefts = left if isinstance(left, tuple) else (left,) * 3
            rights = right if isinstance(right, tuple) else (right,) * 3
            return tuple(self.arith(op, a, b) for a, b in zip(lefts, rights))
        if isinstance(left, ir.Constant) and isinstance(right, ir.Constant):
            return ir.Constant(F32, arith_f32(op, left.constant, right.constant))
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

    def intrinsic(self, name: str, args: list):
        return self.b.call(self._intrinsic(name, len(args)), args)

    def own_math(self, name: str, args: list):
        return self.b.call(self._own_math(name, len(args)), args)

    def texture(self, index: int):
        base = 3 * index
        return tuple(self.b.load(self.slot_ptr(self.textures, base + c), typ=F32) for c in range(3))

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

    def expr(self, e: I.Expr, lets: dict):
        b = self.b
        if isinstance(e, I.Const):
            return ir.Constant(F32, e.value)
        if isinstance(e, I.Load):
            return self.load(e.var, lets)
        if isinstance(e, I.Neg):
            operand = self.expr(e.operand, lets)
            if isinstance(operand, tuple):
                return tuple(b.fneg(c) if not isinstance(c, ir.Constant) else ir.Constant(F32, -c.constant)
                             for c in operand)
            if isinstance(operand, ir.Constant):
                return ir.Constant(F32, -operand.constant)
            return b.fneg(operand)
        if isinstance(e, I.Arith):
            return self.arith(e.op, self.expr(e.left, lets), self.expr(e.right, lets))
        if isinstance(e, I.Compare):
            # ordered comparisons are false on NaN; != is true on NaN (IEEE, as in C)
            compare = b.fcmp_unordered if e.op == "!=" else b.fcmp_ordered
            return compare(e.op, self.expr(e.left, lets), self.expr(e.right, lets))
        if isinstance(e, I.Logic):     # both sides are evaluated (no short circuit)
            left = self.expr(e.left, lets)
            if e.op == "not":
                return b.not_(left)
            right = self.expr(e.right, lets)
            return b.and_(left, right) if e.op == "and" else b.or_(left, right)
        if isinstance(e, I.Call):
            return FUNCTIONS[e.name].lower(self, e, [self.expr(a, lets) for a in e.args])
        if isinstance(e, I.MakeVector):
            return tuple(self.expr(item, lets) for item in e.items)
        if isinstance(e, I.Component):
            return self.expr(e.operand, lets)[e.index]
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

    def assign(self, st: I.Store, lets: dict) -> None:
        var = st.target
        value = self.expr(st.value, lets)
        b = self.b
        if var.space == "look":   # the look array holds the outputs' starting values (abi)
            values = value if isinstance(value, tuple) else (value,)
            for c, v in enumerate(values):
                self.store_finite(v, self.slot_ptr(self.look, var.slot + c), st.number)
            return
        if var.space == "surf" and self.delta is not None:
            ptr = self.slot_ptr(self.delta, var.slot)  # transport: accumulate a delta
        else:
            ptr = self.slot_ptr(self.ton if var.space == "ton" else self.surf, var.slot)
        if st.op == "=":
            new = value
        else:
            old = b.load(ptr, typ=F32)
            new = {"+=": b.fadd, "-=": b.fsub, "*=": b.fmul}[st.op](old, value)
        # A NaN or infinite result is not stored; the first such statement is returned.
        self.store_finite(new, ptr, st.number)

    def statements(self, body: list, lets: dict) -> None:
        lets = dict(lets)
        for st in body:
            if isinstance(st, I.Let):
                lets[st.name] = self.expr(st.value, lets)
            elif isinstance(st, I.If):
                cond = self.expr(st.cond, lets)
                with self.b.if_else(cond) as (then, otherwise):
                    with then:
                        self.statements(st.then, lets)
                    with otherwise:
                        self.statements(st.otherwise, lets)
            else:
                self.b.comment(f"{st.pos.line}:{st.pos.col}: {st.target.text} {st.op} ...")
                self.assign(st, lets)

    def build(self) -> None:
        for body in self.kernel.bodies:
            self.statements(body, {})
        self.b.ret(self.b.load(self.first_bad, typ=I32))


NOISE_SYMBOL = "gamma.noise"


def _noise_function(module: ir.Module) -> ir.Function:
    """``float gamma.noise(float x, float y, float z, i64 salt)``: the signed gradient
    noise of SPEC §11, defined once per module (internal), operation for operation
    as ``ir.builtins.ref_gradient_noise``."""
    try:
        return module.get_global(NOISE_SYMBOL)
    except KeyError:
        pass
    fn = ir.Function(module, ir.FunctionType(F32, [F32, F32, F32, I64]), NOISE_SYMBOL)
    fn.linkage = "internal"
    b = ir.IRBuilder(fn.append_basic_block("entry"))
    f = lambda v: ir.Constant(F32, v)
    i64 = lambda v: ir.Constant(I64, v & 0xFFFFFFFFFFFFFFFF)
    floor = module.declare_intrinsic("llvm.floor", [F32], ir.FunctionType(F32, [F32]))

    def pick(name, a, c):                     # as _KernelBuilder.pick
        better = b.fcmp_ordered("<" if name == "min" else ">", c, a)
        return b.select(b.or_(better, b.fcmp_unordered("uno", a, a)), c, a)

    cells, fracs = [], []
    for x in fn.args[:3]:
        fl = b.call(floor, [x])
        fracs.append(b.fsub(x, fl))
        clamped = pick("min", pick("max", fl, f(-NOISE_CLAMP)), f(NOISE_CLAMP))
        cells.append(b.fptosi(clamped, I32))
    salt = fn.args[3]
    mask = ir.Constant(I32, (1 << NOISE_BITS) - 1)

    def mix64(z):
        z = b.add(z, i64(abi.RANDOM_GOLDEN))
        z = b.mul(b.xor(z, b.lshr(z, i64(30))), i64(abi.RANDOM_MIX[0]))
        z = b.mul(b.xor(z, b.lshr(z, i64(27))), i64(abi.RANDOM_MIX[1]))
        return b.xor(z, b.lshr(z, i64(31)))

    def coord(axis, offset):
        return b.zext(b.and_(b.add(cells[axis], ir.Constant(I32, offset)), mask), I64)

    corner = {}
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                key = b.or_(b.or_(b.shl(coord(0, cx), i64(2 * NOISE_BITS)), b.shl(coord(1, cy), i64(NOISE_BITS))),
                            coord(2, cz))
                g = b.trunc(b.lshr(mix64(b.xor(key, salt)), i64(60)), I32)
                dx, dy, dz = (b.fsub(t, f(float(c))) for t, c in zip(fracs, (cx, cy, cz)))
                ig = lambda v: ir.Constant(I32, v)
                u = b.select(b.icmp_unsigned("<", g, ig(8)), dx, dy)
                dx_wins = b.or_(b.icmp_unsigned("==", g, ig(12)), b.icmp_unsigned("==", g, ig(14)))
                v = b.select(b.icmp_unsigned("<", g, ig(4)), dy, b.select(dx_wins, dx, dz))
                u = b.select(b.icmp_unsigned("!=", b.and_(g, ig(1)), ig(0)), b.fneg(u), u)
                v = b.select(b.icmp_unsigned("!=", b.and_(g, ig(2)), ig(0)), b.fneg(v), v)
                corner[cx, cy, cz] = b.fadd(u, v)

    def fade(t):
        return b.fmul(b.fmul(b.fmul(t, t), t), b.fadd(b.fmul(t, b.fsub(b.fmul(t, f(6.0)), f(15.0))), f(10.0)))

    def lerp(a, c, w):
        return b.fadd(a, b.fmul(w, b.fsub(c, a)))

    fx, fy, fz = (fade(t) for t in fracs)
    x00 = lerp(corner[0, 0, 0], corner[1, 0, 0], fx)
    x10 = lerp(corner[0, 1, 0], corner[1, 1, 0], fx)
    x01 = lerp(corner[0, 0, 1], corner[1, 0, 1], fx)
    x11 = lerp(corner[0, 1, 1], corner[1, 1, 1], fx)
    b.ret(lerp(lerp(x00, x10, fy), lerp(x01, x11, fy), fz))
    return fn


def generate(effect: Effect) -> ir.Module:
    """The whole effect as one LLVM module, one function per kernel."""
    module = ir.Module(name=effect.path)
    module.add_named_metadata("gamma.abi_version").add(
        module.add_metadata([ir.Constant(I32, abi.ABI_VERSION)]))
    for kernel in effect.kernels:
        _KernelBuilder(module, kernel).build()
    return module
