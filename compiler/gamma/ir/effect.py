"""The typed, resolved IR of an effect: what the front end produces and the
back ends and the driver consume.

Declarations (ton types, surfaces with their row layout, sources with
checked arguments) and the kernels: every rule body that runs for one
(event, ton type, surface), for one surface's update, or for its
appearance, in file order.  Rule bodies are trees of the nodes below, in
which every name is already bound (``Var``: which array, which slot, which
name), every expression has its kind (``float``, ``bool``, ``color``, ``vector``),
parameters are folded to constants, every assignment has its statement
number and every ``random()`` its site.  Nothing downstream looks a name up
or reads the AST; ``dump`` prints it (``gammac emit --effect``).

This module holds data only: no checking, no code generation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..frontend.ast import Pos
from ..records import Record, record


# ---- declarations --------------------------------------------------------------------

@dataclass(frozen=True)
class Length:
    """A length in scene units, or a fraction of the scene's bounding-box diagonal."""

    value: float
    relative: bool = False

    def resolve(self, diagonal: float) -> float:
        return self.value * diagonal if self.relative else self.value


@dataclass(frozen=True)
class Place:
    """A point in scene units, or as fractions of the bounding box (0 = min, 1 = max)."""

    value: tuple[float, float, float]
    relative: bool = False

    def resolve(self, lo, hi) -> tuple[float, float, float]:
        if not self.relative:
            return self.value
        return tuple(float(a + f * (b - a)) for f, a, b in zip(self.value, lo, hi))


@record
class TonType(Record):
    name: str
    index: int
    motion: tuple[float, float, float]
    carry: dict[str, int]          # attribute -> slot in the ton array
    initial: list[float]
    bounce: Length | None          # None: the runner's default
    step: Length | None
    drip: float | None             # drip angle in degrees (SPEC §4); None: the runner's default
    decl: object                   # ast.TonDecl (positions for warnings)


@record
class Surface(Record):
    name: str
    index: int
    properties: dict[str, int]     # property -> slot in the surfel row
    initial_row: list[float]       # reflectance then properties
    decl: object                   # ast.SurfaceDecl
    # `shape` (SPEC §19): property -> (slot, metres per unit, "FILE:LINE:COL" of the entry)
    shape: dict[str, tuple[int, float, str]] = field(default_factory=dict)


@record
class Source(Record):
    name: str
    kind: str                      # the runtime's kind (abi.SOURCE_KINDS)
    ton: int
    count: int
    params: dict                   # checked parameters (Place, Length, 'down'/'up' or a vector, ...)
    first: int                     # first iteration it emits in (1-based)
    last: int                      # last iteration it emits in; 0 = no end
    decl: object                   # ast.SourceDecl
    strength: float | None = None  # SPEC §13.2; None: every gamma-ton weighs 1


# ---- rule bodies ----------------------------------------------------------------------

@dataclass(frozen=True)
class Var:
    """A name of a rule body, bound.

    space: ``ton`` (a carried attribute), ``surf`` (a property or a
    reflectance component of the surfel row), ``ctx`` (a context value),
    ``let`` (a local), ``look`` (an appearance output: ``color``,
    ``roughness``, ... at ``slot`` in the look array, abi.APPEARANCE_OUTPUTS).
    ``slot`` is the index in the ton array / surfel row (the code
    generator's business); ``name`` says what it is by name (the reference
    interpreter's business): the attribute, the property, ``reflectance.X``,
    the context field, the local's name.  ``component``: of a context vector."""

    space: str
    name: str
    slot: int = 0
    component: int | None = None     # of a vector (context value or let): None is the whole vector
    writable: tuple[str, ...] = ()   # the assignment operators allowed on it here
    text: str = ""                   # as written (t.patina), for messages


@record
class Const(Record):
    value: float                   # already a float32 value
    pos: Pos
    kind = "float"


@record
class Load(Record):
    var: Var
    kind: str
    pos: Pos


@record
class Neg(Record):
    operand: "Expr"
    kind: str
    pos: Pos


@record
class Arith(Record):
    op: str                        # + - * /
    left: "Expr"
    right: "Expr"
    kind: str                      # float or color
    pos: Pos


@record
class Compare(Record):
    op: str
    left: "Expr"
    right: "Expr"
    pos: Pos
    kind = "bool"


@record
class Logic(Record):
    op: str                        # and, or, not (right None)
    left: "Expr"
    right: "Expr | None"
    pos: Pos
    kind = "bool"


@record
class Call(Record):
    """A built-in function (``ir.builtins``)."""

    name: str
    args: list["Expr"]
    kind: str
    pos: Pos
    site: int | None = None        # random(): its number in the kernel, 0, 1, ... in source order
    texture: int | None = None     # texture(): index in Effect.textures


@record
class MakeVector(Record):
    """``(x, y, z)`` in a rule: a vector of three numbers."""

    items: list["Expr"]
    pos: Pos
    kind = "vector"


@record
class Component(Record):
    """Component ``index`` (0, 1, 2: x, y, z) of a vector expression."""

    operand: "Expr"
    index: int
    pos: Pos
    kind = "float"


Expr = Const | Load | Neg | Arith | Compare | Logic | Call | MakeVector | Component


@record
class Let(Record):
    name: str
    value: Expr
    pos: Pos


@record
class If(Record):
    cond: Expr
    then: list["Stmt"]
    otherwise: list["Stmt"]
    pos: Pos


@record
class Store(Record):
    """``target op value``; a NaN or infinite result is not stored and the
    kernel returns ``number`` (1-based, per kernel, in execution order of
    the source) if it is the first such statement."""

    target: Var
    op: str                        # = += -= *=
    value: Expr
    number: int
    pos: Pos                       # of the target (what a warning points at)
    origin: str                    # path of the file the rule is in


Stmt = Let | If | Store


def children(e) -> list:
    """The operands of an expression, in source order."""
    if isinstance(e, Neg):
        return [e.operand]
    if isinstance(e, (Arith, Compare)):
        return [e.left, e.right]
    if isinstance(e, Logic):
        return [e.left] + ([e.right] if e.right is not None else [])
    if isinstance(e, Call):
        return list(e.args)
    if isinstance(e, MakeVector):
        return list(e.items)
    if isinstance(e, Component):
        return [e.operand]
    return []


def expressions(body: list):
    """Every expression of a body, nested ones too (a parent before its operands)."""
    stack = []
    for st in body:
        if isinstance(st, (Let, Store)):
            stack.append(st.value)
        elif isinstance(st, If):
            stack.append(st.cond)
            yield from expressions(st.then)
            yield from expressions(st.otherwise)
    while stack:
        e = stack.pop()
        yield e
        stack.extend(children(e))


def stores(body: list) -> list[Store]:
    """Every assignment of a body, nested ones too, in source order."""
    found = []
    for st in body:
        if isinstance(st, Store):
            found.append(st)
        elif isinstance(st, If):
            found += stores(st.then) + stores(st.otherwise)
    return found


@record
class Kernel(Record):
    """All rule bodies that run for one (event, ton type, surface), in file order."""

    event: str                     # an event of abi.EVENTS, 'update' or 'appearance'
    ton: TonType | None
    surface: Surface
    bodies: list[list[Stmt]] = field(default_factory=list)
    rules: list = field(default_factory=list)   # the AST declaration of each body (warnings)
    random_sites: int = 0          # random() calls in all bodies (their sites are 0 .. this - 1)
    base_slot: int = 0             # appearance: the textures slot of the scene's base colour
    inputs: list = field(default_factory=list)   # the effect's Input names ("mask:PATH", ...), row order
    inputs_base: int = 0           # the row slot of the first input (after every surface's properties)
    source: str | None = None      # a surface source's weight kernel (event "weight"): the source's name

    @property
    def label(self) -> str:
        if self.event == "weight":
            return f"weight of source {self.source}"
        if self.ton is None:
            return f"{self.event}({self.surface.name})"
        return f"on {self.event}({self.ton.name}, {self.surface.name})"

    @property
    def symbol(self) -> str:
        # '.' cannot occur in a name, so symbols never collide
        if self.event == "weight":
            return f"gamma.weight.{self.source}"
        if self.ton is None:
            return f"gamma.{self.event}.{self.surface.name}"
        return f"gamma.{self.event}.{self.ton.name}.{self.surface.name}"

    def statements(self) -> list[Store]:
        """Every assignment, in statement-number order."""
        return [st for body in self.bodies for st in stores(body)]

    def statement_at(self, number: int) -> Store:
        return self.statements()[number - 1]

    @property
    def writes_surface(self) -> bool:
        return any(st.target.space == "surf" for st in self.statements())

    def writes_look(self, name: str) -> bool:
        """Whether an appearance kernel assigns the output ``name`` somewhere."""
        return any(st.target.space == "look" and st.target.name == name for st in self.statements())


@record
class Input(Record):
    """A value a surfel reads from the scene once, at setup (SPEC §12a):
    ``mask("file.png")`` (an image's luminance at the surfel's texture
    coordinates) or ``attribute("NAME")`` (a vertex attribute of the mesh
    interpolated at the surfel).  It is kept in the surfel's row at ``slot``,
    after every surface's properties; rules read it there."""

    kind: str                      # "mask" or "attribute"
    key: str                       # the image's resolved path, or the attribute's name
    slot: int
    uses: list = field(default_factory=list)   # (Pos, SourceFile, surface name, as written)

    @property
    def name(self) -> str:
        return f"{self.kind}:{self.key}"


@record
class Effect(Record):
    path: str
    source: str
    tons: dict[str, TonType]
    surfaces: dict[str, Surface]
    sources: list[Source]
    kernels: list[Kernel]
    row_width: int
    warnings: list = field(default_factory=list)
    params: dict = field(default_factory=dict)
    assign: list = field(default_factory=list)   # (pattern, surface) from `assign` declarations
    textures: list = field(default_factory=list) # image files read by texture() and mask(), in index order
    texture_kinds: list = field(default_factory=list)  # per texture: "color" (texture()) or "mask"
    inputs: list = field(default_factory=list)   # Input: what surfels read from the scene at setup
    mask_uses: list = field(default_factory=list)  # (Pos, SourceFile, surface name, path) of every mask()
    files: list = field(default_factory=list)    # the effect file and every file it imports
    overrides: dict = field(default_factory=dict) # --param values it was checked with (NAME or RECIPE.NAME)

    def context_reads(self, events=None) -> set[str]:
        """The context values the kernels read (of the given events: 'transport',
        'update', 'appearance'; None: all)."""
        names = set()
        for k in self.kernels:
            kind = "transport" if k.ton is not None else k.event
            if events is not None and kind not in events:
                continue
            for body in k.bodies:
                names |= {e.var.name for e in expressions(body) if isinstance(e, Load) and e.var.space == "ctx"}
        return names

    def transport_kernels(self) -> list[Kernel]:
        return [k for k in self.kernels if k.ton is not None]

    def update_kernels(self) -> list[Kernel]:
        return [k for k in self.kernels if k.event == "update"]

    def appearance_kernels(self) -> list[Kernel]:
        return [k for k in self.kernels if k.event == "appearance"]

    def weight_kernels(self) -> list[Kernel]:
        """Surface sources' weights: update-shaped kernels that store the
        surfel's weight in the slot after its row (``row_width``)."""
        return [k for k in self.kernels if k.event == "weight"]


# ---- printing -------------------------------------------------------------------------

def _expr(e) -> str:
    if isinstance(e, Const):
        import numpy as np

        return str(np.float32(e.value))
    if isinstance(e, Load):
        var = e.var
        return (f"{var.space}:{var.name}" + (f"[{var.slot}]" if var.space in ("ton", "surf") else "")
                + (f".{'xyz'[var.component]}" if var.component is not None else ""))
    if isinstance(e, MakeVector):
        return f"({', '.join(_expr(a) for a in e.items)})"
    if isinstance(e, Component):
        return f"{_expr(e.operand)}.{'xyz'[e.index]}"
    if isinstance(e, Neg):
        return f"(-{_expr(e.operand)})"
    if isinstance(e, (Arith, Compare)):
        return f"({_expr(e.left)} {e.op} {_expr(e.right)})"
    if isinstance(e, Logic):
        return f"(not {_expr(e.left)})" if e.right is None else f"({_expr(e.left)} {e.op} {_expr(e.right)})"
    if isinstance(e, Call):
        extra = f"#{e.site}" if e.site is not None else f"<{e.texture}>" if e.texture is not None else ""
        return f"{e.name}{extra}({', '.join(_expr(a) for a in e.args)})"
    raise AssertionError(e)


def _body(body: list, pad: str) -> list[str]:
    lines = []
    for st in body:
        if isinstance(st, Let):
            lines.append(f"{pad}let {st.name}: {st.value.kind} = {_expr(st.value)}")
        elif isinstance(st, If):
            lines.append(f"{pad}if {_expr(st.cond)}")
            lines += _body(st.then, pad + "  ")
            if st.otherwise:
                lines.append(f"{pad}else")
                lines += _body(st.otherwise, pad + "  ")
        else:
            lines.append(f"{pad}#{st.number} {st.target.space}:{st.target.name}"
                         + (f"[{st.target.slot}]" if st.target.space in ("ton", "surf") else "")
                         + f" {st.op} {_expr(st.value)}    ; {st.origin}:{st.pos.line}:{st.pos.col}")
    return lines


def dump(effect: Effect) -> str:
    """The IR as text: declarations, then every kernel's bodies."""
    lines = [f"effect {effect.path}  (row width {effect.row_width})"]
    for t in effect.tons.values():
        lines.append(f"ton {t.name} #{t.index} motion {t.motion} carry {t.carry} initial {t.initial}")
    for s in effect.surfaces.values():
        lines.append(f"surface {s.name} #{s.index} properties {s.properties} initial row {s.initial_row}")
    for src in effect.sources:
        params = {k: (v.symbol if isinstance(v, Kernel) else v) for k, v in src.params.items()}
        lines.append(f"source {src.name} {src.kind} ton #{src.ton} count {src.count} "
                     f"iterations {src.first}..{src.last or 'end'} {params}")
    for i, path in enumerate(effect.textures):
        kind = effect.texture_kinds[i] if i < len(effect.texture_kinds) else "color"
        lines.append(f"texture <{i}> {path}" + ("  (mask: luminance)" if kind == "mask" else ""))
    for item in effect.inputs:
        lines.append(f"input {item.name} -> row slot {item.slot}")
    for k in effect.kernels:
        lines.append(f"kernel {k.label} -> {k.symbol}")
        for n, body in enumerate(k.bodies):
            lines.append(f"  body {n}")
            lines += _body(body, "    ")
    return "\n".join(lines) + "\n"
