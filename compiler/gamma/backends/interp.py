"""Reference interpreter: runs a kernel's rule bodies, the oracle the compiled
kernels are tested against.

It is a second, independent reading of the language.  It shares the IR with
the code generator but none of its shortcuts: it reads every name by what it
is (``Var.space`` and ``Var.name``), never by ``Var.slot``, and finds where
that name lives in the caller's arrays from the declarations themselves
(``abi.REFLECTANCE_SLOTS`` and the declaration order of properties and
carried attributes, as the ABI lays a row out); it numbers statements and
``random()`` sites by walking the bodies itself.  A wrong slot, number or
site assigned by the front end therefore shows up as a difference.  Every
operation is done in numpy float32, in source order, with the reference
semantics of ``ir.builtins``.
"""

from __future__ import annotations

import numpy as np

from .. import abi
from ..abi import random_value
from ..ir import effect as I
from ..ir.builtins import FUNCTIONS, ref_arith
from ..ir.effect import Kernel

f32 = np.float32


class Context:
    """Values of the read-only context (fields of ``abi.CONTEXT_FIELDS``)."""

    def __init__(self, iteration: int = 0, interactions: int = 0, height: float = 0.0,
                 position=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 0.0), direction=(0.0, 0.0, 0.0),
                 random_key: int = 0, up=(0.0, 1.0, 0.0), uv=(0.0, 0.0), accessibility: float = 0.0,
                 curvature: float = 0.0):
        self.random_key = random_key
        self.iteration = iteration
        self.interactions = interactions
        self.height = f32(height)
        self.position = np.asarray(position, np.float32)
        self.normal = np.asarray(normal, np.float32)
        self.direction = np.asarray(direction, np.float32)
        self.uv = np.asarray(uv, np.float32)
        self.up = np.asarray(up, np.float32)
        self.accessibility = f32(accessibility)
        self.curvature = f32(curvature)


def _row_layout(kernel: Kernel) -> dict[str, int]:
    """Where each name of the surface lives in a surfel row, from the ABI and
    the surface's declaration (properties in the order written, first of a name)."""
    layout = {f"reflectance.{n}": i for i, n in enumerate(abi.REFLECTANCE_SLOTS)}
    for init in kernel.surface.decl.properties:
        layout.setdefault(init.name, abi.ROW_HEADER + len(layout) - len(abi.REFLECTANCE_SLOTS))
    # mask() and attribute() values follow every surface's properties, in the effect's order
    for i, name in enumerate(kernel.inputs):
        layout[name] = kernel.inputs_base + i
    if kernel.event == "weight":        # a surface source's weight: the slot after the row
        layout["weight"] = kernel.inputs_base + len(kernel.inputs)
    return layout


def _ton_layout(kernel: Kernel) -> dict[str, int]:
    layout: dict[str, int] = {}
    if kernel.ton is not None:
        for init in kernel.ton.decl.carry:
            layout.setdefault(init.name, len(layout))
    return layout


_COMPARE = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal,
            "==": np.equal, "!=": np.not_equal}


class _Call:
    """One kernel call: the caller's arrays, addressed by name, and the
    bookkeeping a call needs (statement count, random() sites, first bad)."""

    def __init__(self, kernel: Kernel, ton, surf, delta, ctx: Context, textures=None, look=None):
        self.kernel, self.ton, self.surf, self.delta, self.ctx = kernel, ton, surf, delta, ctx
        self.row, self.carry = _row_layout(kernel), _ton_layout(kernel)
        self.transport = kernel.ton is not None
        self.textures, self.look = textures, look
        self.first_bad = 0
        self.statement = 0        # statements are numbered in source order, not run order
        self.sites: dict[int, int] = {}

    # -- what the reference semantics of ir.builtins ask for --

    def random(self, call: I.Call):
        return f32(random_value(self.ctx.random_key, self.sites[id(call)]))

    def texture(self, call: I.Call):
        base = 3 * call.texture
        return tuple(f32(self.textures[base + c]) for c in range(3))

    # -- names --

    def where(self, var: I.Var):
        """(array, index) of a ton attribute or a surfel value, by name."""
        if var.space == "ton":
            return self.ton, self.carry[var.name]
        return self.surf, self.row[var.name]

    def read(self, var: I.Var, lets: dict):
        if var.space == "let":
            return lets[var.name]
        if var.space == "look":
            if var.name == "color":
                return tuple(f32(self.look[var.slot + c]) for c in range(3))
            return f32(self.look[var.slot])
        if var.space == "ctx":
            value = getattr(self.ctx, var.name)
            if not np.ndim(value):
                return f32(value)
            # a vector (uv has 2 components in the context; its z is 0)
            whole = tuple(f32(value[c]) if c < len(value) else f32(0) for c in range(3))
            return whole if var.component is None else whole[var.component]
        array, index = self.where(var)
        return array[index]

    # -- evaluation --

    def eval(self, e, lets: dict):
        if isinstance(e, I.Const):
            return f32(e.value)
        if isinstance(e, I.Load):
            return self.read(e.var, lets)
        if isinstance(e, I.Neg):
            value = self.eval(e.operand, lets)
            return tuple(-c for c in value) if isinstance(value, tuple) else -value
        if isinstance(e, I.Arith):
            return ref_arith(e.op, self.eval(e.left, lets), self.eval(e.right, lets))
        if isinstance(e, I.Compare):
            a, b = self.eval(e.left, lets), self.eval(e.right, lets)
            return bool(_COMPARE[e.op](a, b))
        if isinstance(e, I.Logic):  # both sides evaluated, like the compiled code
            a = self.eval(e.left, lets)
            if e.op == "not":
                return not a
            b = self.eval(e.right, lets)
            return (a and b) if e.op == "and" else (a or b)
        if isinstance(e, I.Call):
            return FUNCTIONS[e.name].reference(self, e, [self.eval(a, lets) for a in e.args])
        if isinstance(e, I.MakeVector):
            return tuple(f32(self.eval(item, lets)) for item in e.items)
        if isinstance(e, I.Component):
            return self.eval(e.operand, lets)[e.index]
        raise AssertionError(f"unchecked expression {e!r}")

    def run(self, body: list, lets: dict, numbers: dict) -> None:
        lets = dict(lets)
        for st in body:
            if isinstance(st, I.Let):
                lets[st.name] = self.eval(st.value, lets)
            elif isinstance(st, I.If):
                branch = st.then if self.eval(st.cond, lets) else st.otherwise
                self.run(branch, lets, numbers)
            else:
                self.store(st, self.eval(st.value, lets), numbers[id(st)])

    def store(self, st: I.Store, value, number: int) -> None:
        if st.target.space == "look":
            values = value if isinstance(value, tuple) else (value,)
            for c, v in enumerate(values):
                if np.isfinite(v):
                    self.look[st.target.slot + c] = v
                elif not self.first_bad:
                    self.first_bad = number
            return
        array, index = self.where(st.target)
        if st.target.space == "surf" and self.transport:
            array = self.delta                       # transport rules add to a delta row
        old = array[index]
        new = {"=": value, "+=": f32(old + value), "-=": f32(old - value), "*=": f32(old * value)}[st.op]
        if np.isfinite(new):
            array[index] = new
        elif not self.first_bad:                    # not stored; the first such statement is reported
            self.first_bad = number


def _number(kernel: Kernel) -> tuple[dict, dict]:
    """Statement numbers (id -> 1, 2, ...) and random() sites (id -> 0, 1, ...)
    in source order across the kernel's bodies: a condition before its
    branches, a statement's value before its target (SPEC §11)."""
    numbers: dict[int, int] = {}
    sites: dict[int, int] = {}

    def expr(e):
        if isinstance(e, I.Call) and e.name == "random":
            sites[id(e)] = len(sites)
        for child in ([e.operand] if isinstance(e, I.Neg) else
                      [e.left, e.right] if isinstance(e, (I.Arith, I.Compare)) else
                      [e.left] + ([e.right] if e.right is not None else []) if isinstance(e, I.Logic) else
                      list(e.args) if isinstance(e, I.Call) else
                      list(e.items) if isinstance(e, I.MakeVector) else
                      [e.operand] if isinstance(e, I.Component) else []):
            expr(child)

    def body(stmts):
        for st in stmts:
            if isinstance(st, I.Let):
                expr(st.value)
            elif isinstance(st, I.If):
                expr(st.cond)
                body(st.then)
                body(st.otherwise)
            else:
                expr(st.value)

    def count(stmts):
        for st in stmts:
            if isinstance(st, I.If):
                count(st.then)
                count(st.otherwise)
            elif isinstance(st, I.Store):
                numbers[id(st)] = len(numbers) + 1

    for b in kernel.bodies:
        body(b)
        count(b)
    return numbers, sites


def run_kernel(kernel: Kernel, ton, surf, delta, ctx: Context, *, textures=None, look=None) -> int:
    """Run in place, like the compiled kernel: ``ton`` and ``delta`` (transport)
    or ``surf`` (update) are float32 arrays that get modified.  Returns 0 or the
    number of the first statement whose result was NaN or infinite."""
    call = _Call(kernel, ton, surf, delta, ctx, textures, look)
    numbers, call.sites = _number(kernel)
    with np.errstate(all="ignore"):
        for body in kernel.bodies:
            call.run(body, {}, numbers)
    return call.first_bad


def start_look(base_colour, roughness: float | None = None, metallic: float | None = None) -> np.ndarray:
    """The look array an appearance kernel starts from (abi.APPEARANCE_OUTPUTS):
    the scene's base colour and material there, the other outputs' defaults."""
    look = np.zeros(abi.APPEARANCE_WIDTH, np.float32)
    at = abi.appearance_offsets()
    look[0:3] = np.asarray(base_colour, np.float32)[:3]
    for name, value in abi.APPEARANCE_DEFAULTS.items():
        look[at[name]] = value
    if roughness is not None:
        look[at["roughness"]] = roughness
    if metallic is not None:
        look[at["metallic"]] = metallic
    return look


def run_appearance(kernel: Kernel, surf, textures, ctx: Context, look=None):
    """What an appearance kernel gives: (look float32[abi.APPEARANCE_WIDTH]:
    colour, roughness, ..., as assigned and unclamped; first non-finite
    statement).  ``textures``: 3 floats per texture of the effect, then 3 for
    the scene's base colour (SPEC §8a).  ``look``: the outputs' starting
    values, as the runtime passes them (default: ``start_look`` of that base
    colour)."""
    textures = np.asarray(textures, np.float32).reshape(-1)
    base = 3 * kernel.base_slot
    if len(textures) != base + 3:
        raise ValueError(f"run_appearance: {len(textures)} texture values, not {base + 3}")
    look = start_look(textures[base:base + 3]) if look is None else np.array(look, np.float32)
    bad = run_kernel(kernel, None, surf, None, ctx, textures=textures, look=look)
    return look.copy(), bad
