"""Name and type checking: from the AST to a resolved ``Effect``.

Every error of the file is collected (never just the first) and raised
together as ``GammaError``.  The result, ``Effect``, is what the code
generator, the reference interpreter and the runner consume: ton types,
surfaces with their row layout, sources, and the transport/update rules
grouped per kernel.  Name lookup inside rule bodies is done by one function,
``Scope.resolve``, shared by all three consumers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from . import abi
from . import ast as A
from .diagnostics import Diagnostic, GammaError, did_you_mean

MOTION_NAMES = abi.REFLECTANCE_SLOTS  # straight, parabolic, flow
TRACED_EVENTS = tuple(abi.EVENTS)      # events this runtime fires
FUTURE_EVENTS = ("reflect", "bounce", "flow")
CONTEXT_VALUES = {"iteration": "update", "interactions": "transport"}  # name -> narrowest rule kind
FUNCTIONS = {"min": (2, None), "max": (2, None), "clamp": (3, 3)}  # name -> (min args, max args)
RESERVED_PROPERTY_NAMES = {"x", "y", "z", "nx", "ny", "nz", "reflectance", "motion"}
SOURCE_KINDS = ("environment", "point")
ENVIRONMENT_SHAPES = ("sphere", "hemisphere")


# ---- the checked effect -------------------------------------------------------

@dataclass
class TonType:
    name: str
    index: int
    motion: tuple[float, float, float]
    carry: dict[str, int]          # attribute -> slot in the ton array
    initial: list[float]
    bounce: float | None
    step: float | None
    decl: A.TonDecl


@dataclass
class Surface:
    name: str
    index: int
    properties: dict[str, int]     # property -> slot in the surfel row
    initial_row: list[float]       # reflectance then properties
    decl: A.SurfaceDecl


@dataclass
class Source:
    name: str
    kind: str                      # 'sphere' | 'hemisphere' | 'point' (runtime kinds)
    ton: int
    count: int
    position: tuple[float, float, float]
    decl: A.SourceDecl


@dataclass
class Slot:
    """Where a name in a rule body lives."""

    space: str      # 'ton' | 'surf' | 'ctx'
    index: int      # slot in the ton array / surfel row; ctx: unused
    name: str
    writable_ops: tuple[str, ...]


@dataclass
class Scope:
    """The names visible in one rule body."""

    kind: str                      # 'transport' | 'update'
    ton_param: str | None
    ton: TonType | None
    surf_param: str
    surface: Surface

    def resolve(self, ref: A.Ref) -> Slot | str:
        """A Slot, or an error message (only the checker ever sees those)."""
        parts = ref.parts
        head = parts[0]
        transport = self.kind == "transport"
        if len(parts) == 1:
            if head in CONTEXT_VALUES and (transport or CONTEXT_VALUES[head] == "update"):
                return Slot("ctx", 0, head, ())
            if head in CONTEXT_VALUES:
                return f"'{head}' is not available in update rules"
            if head in (self.ton_param, self.surf_param):
                what = "gamma-ton" if head == self.ton_param else "surfel"
                return f"'{head}' is a {what}, not a value; write {head}.NAME"
            names = list(CONTEXT_VALUES) + [n for n in (self.ton_param, self.surf_param) if n]
            return f"unknown name '{head}'{did_you_mean(head, names)}"
        if head == self.ton_param and self.ton is not None:
            attr = parts[1]
            if attr == "motion":
                return "motion probabilities are managed by the runtime and not visible to rules"
            if len(parts) == 2 and attr in self.ton.carry:
                return Slot("ton", self.ton.carry[attr], f"{head}.{attr}", ("=", "+=", "-=", "*="))
            if len(parts) == 2 and attr in self.surface.properties:
                return (f"ton {self.ton.name} carries no '{attr}'; '{attr}' is a property of "
                        f"surface {self.surface.name} (did you mean '{self.surf_param}.{attr}'?)")
            if len(parts) > 2:
                return f"'{head}.{attr}' has no fields"
            return (f"ton {self.ton.name} carries no attribute '{attr}'"
                    f"{did_you_mean(attr, self.ton.carry)}")
        if head == self.surf_param:
            attr = parts[1]
            if attr == "reflectance":
                if len(parts) != 3 or parts[2] not in MOTION_NAMES:
                    return ("reflectance has the components " + ", ".join(MOTION_NAMES)
                            + "; write " + f"{head}.reflectance.straight")
                ops = () if transport else ("=", "+=", "-=", "*=")
                return Slot("surf", MOTION_NAMES.index(parts[2]), ".".join(parts), ops)
            if len(parts) == 2 and attr in self.surface.properties:
                ops = ("+=", "-=") if transport else ("=", "+=", "-=", "*=")
                return Slot("surf", self.surface.properties[attr], f"{head}.{attr}", ops)
            if len(parts) == 2 and self.ton is not None and attr in self.ton.carry:
                return (f"surface {self.surface.name} has no property '{attr}'; '{attr}' is carried "
                        f"by ton {self.ton.name} (did you mean '{self.ton_param}.{attr}'?)")
            if len(parts) > 2:
                return f"'{head}.{attr}' has no fields"
            return (f"surface {self.surface.name} has no property '{attr}'"
                    f"{did_you_mean(attr, self.surface.properties)}")
        names = [n for n in (self.ton_param, self.surf_param) if n]
        if head in CONTEXT_VALUES:
            return f"'{head}' is a number and has no fields"
        return f"unknown name '{head}'{did_you_mean(head, names)}"


@dataclass
class Kernel:
    """All rule bodies that run for one (event, ton type, surface), in file order."""

    event: str                     # 'hit' | 'settle' | 'update'
    ton: TonType | None
    surface: Surface
    bodies: list[tuple[Scope, list[A.Assign]]] = field(default_factory=list)

    @property
    def symbol(self) -> str:
        if self.ton is None:
            return f"gamma_update__{self.surface.name}"
        return f"gamma_{self.event}__{self.ton.name}__{self.surface.name}"

    @property
    def writes_surface(self) -> bool:
        return any(scope.resolve(st.target).space == "surf"
                   for scope, body in self.bodies for st in body)


@dataclass
class Effect:
    path: str
    source: str
    tons: dict[str, TonType]
    surfaces: dict[str, Surface]
    sources: list[Source]
    kernels: list[Kernel]
    row_width: int

    def transport_kernels(self) -> list[Kernel]:
        return [k for k in self.kernels if k.ton is not None]

    def update_kernels(self) -> list[Kernel]:
        return [k for k in self.kernels if k.ton is None]


# ---- constant evaluation ----------------------------------------------------------

class NotConstant(Exception):
    def __init__(self, pos: A.Pos):
        self.pos = pos


def const_value(expr: A.Expr) -> float:
    """Fold a constant expression (numbers and arithmetic only)."""
    import numpy as np

    f32 = np.float32
    if isinstance(expr, A.Number):
        return float(f32(expr.value))
    if isinstance(expr, A.Unary):
        return float(-f32(const_value(expr.operand)))
    if isinstance(expr, A.Binary):
        a, b = f32(const_value(expr.left)), f32(const_value(expr.right))
        with np.errstate(all="ignore"):
            return float({"+": a + b, "-": a - b, "*": a * b, "/": a / b}[expr.op])
    raise NotConstant(expr.pos)


# ---- the checker ---------------------------------------------------------------------

class _Checker:
    def __init__(self, module: A.Module):
        self.module = module
        self.diags: list[Diagnostic] = []

    def error(self, pos: A.Pos, message: str) -> None:
        self.diags.append(Diagnostic(pos, message))

    def constant(self, expr: A.Expr, what: str) -> float | None:
        try:
            return const_value(expr)
        except NotConstant as nc:
            self.error(nc.pos, f"{what} must be a constant number")
            return None

    def inits(self, inits: list[A.Init], what: str, allowed=None, unit=False):
        """Check a list of `name = value`; return {name: (value, Init)}."""
        seen: dict[str, tuple[float, A.Init]] = {}
        for init in inits:
            if init.name in seen:
                self.error(init.pos, f"{what} '{init.name}' is given twice")
                continue
            if allowed is not None and init.name not in allowed:
                self.error(init.pos, f"unknown {what} '{init.name}'; expected one of "
                           f"{', '.join(allowed)}{did_you_mean(init.name, allowed)}")
                continue
            value = self.constant(init.value, f"the value of {what} '{init.name}'")
            if value is None:
                continue
            if unit and not 0.0 <= value <= 1.0:
                self.error(init.value.pos, f"{what} '{init.name}' = {value:g} is outside [0, 1]")
            seen[init.name] = (value, init)
        return seen

    def run(self) -> Effect:
        decls = self.module.decls
        names: dict[str, A.Pos] = {}
        tons: dict[str, TonType] = {}
        surfaces: dict[str, Surface] = {}

        def declare(name: str, pos: A.Pos, what: str) -> bool:
            if name in names:
                self.error(pos, f"{what} '{name}' is already declared at line {names[name].line}")
                return False
            names[name] = pos
            return True

        for d in decls:
            if isinstance(d, A.TonDecl) and declare(d.name, d.pos, "ton"):
                tons[d.name] = self.ton(d, len(tons))
            elif isinstance(d, A.SurfaceDecl) and declare(d.name, d.pos, "surface"):
                surfaces[d.name] = self.surface(d, len(surfaces))
        sources = []
        for d in decls:
            if isinstance(d, A.SourceDecl) and declare(d.name, d.pos, "source"):
                src = self.source(d, tons, surfaces)
                if src is not None:
                    sources.append(src)
        kernels: dict[tuple, Kernel] = {}
        for d in decls:
            if isinstance(d, A.RuleDecl):
                self.rule(d, tons, surfaces, kernels)
            elif isinstance(d, A.UpdateDecl):
                self.update(d, surfaces, tons, kernels)
        width = abi.ROW_HEADER + max((len(s.properties) for s in surfaces.values()), default=0)
        if self.diags:
            raise GammaError(self.module.path, self.module.source, self.diags)
        return Effect(self.module.path, self.module.source, tons, surfaces, sources,
                      list(kernels.values()), width)

    def ton(self, d: A.TonDecl, index: int) -> TonType:
        motion = self.inits(d.motion, "motion probability", MOTION_NAMES, unit=True)
        values = tuple(motion.get(n, (0.0, None))[0] for n in MOTION_NAMES)
        if all(0.0 <= v <= 1.0 for v in values) and sum(values) > 1.0 + 1e-6:
            first = d.motion[0].pos if d.motion else d.pos
            self.error(first, f"motion probabilities of ton {d.name} sum to {sum(values):g}, "
                       "more than 1 (settling takes 1 - straight - parabolic - flow)")
        carry = self.inits(d.carry, "carried attribute")
        for name, (_, init) in carry.items():
            if name in ("motion",):
                self.error(init.pos, f"'{name}' is reserved")
        for key, expr in d.repeated:
            self.error(expr.pos, f"'{key}' is given twice in ton {d.name}")
        bounce = self.constant(d.bounce, "bounce distance") if d.bounce is not None else None
        step = self.constant(d.step, "flow step") if d.step is not None else None
        for what, v, e in (("bounce distance", bounce, d.bounce), ("flow step", step, d.step)):
            if v is not None and v <= 0:
                self.error(e.pos, f"{what} must be positive, not {v:g}")
        return TonType(d.name, index, values, {n: i for i, n in enumerate(carry)},
                       [v for v, _ in carry.values()], bounce, step, d)

    def surface(self, d: A.SurfaceDecl, index: int) -> Surface:
        refl = self.inits(d.reflectance, "reflectance", MOTION_NAMES, unit=True)
        props = self.inits(d.properties, "property")
        for name, (_, init) in props.items():
            if name in RESERVED_PROPERTY_NAMES or name.startswith("reflectance_"):
                self.error(init.pos, f"property name '{name}' is reserved "
                           "(it names a column of the output maps or a built-in field)")
        row = [refl.get(n, (0.0, None))[0] for n in MOTION_NAMES] + [v for v, _ in props.values()]
        slots = {n: abi.ROW_HEADER + i for i, n in enumerate(props)}
        return Surface(d.name, index, slots, row, d)

    def source(self, d: A.SourceDecl, tons, surfaces) -> Source | None:
        ok = True
        ton = tons.get(d.ton)
        if ton is None:
            ok = False
            if d.ton in surfaces:
                self.error(d.ton_pos, f"'{d.ton}' is a surface; a source emits a ton type")
            else:
                self.error(d.ton_pos, f"unknown ton type '{d.ton}'{did_you_mean(d.ton, tons)}")
        count = self.constant(d.count, "the count of a source")
        if count is not None and (count < 1 or count != int(count)):
            self.error(d.count.pos, f"the count of a source must be a positive whole number, "
                       f"not {count:g}")
            ok = False
        kind, position = None, (0.0, 0.0, 0.0)
        if d.kind == "environment":
            shape = d.args[0] if len(d.args) == 1 else None
            if isinstance(shape, A.Ref) and len(shape.parts) == 1 \
                    and shape.parts[0] in ENVIRONMENT_SHAPES:
                kind = shape.parts[0]
            else:
                self.error(shape.pos if shape is not None else d.kind_pos,
                           "environment takes one argument: sphere or hemisphere")
        elif d.kind == "point":
            if len(d.args) != 3:
                self.error(d.kind_pos, f"point takes three coordinates (x, y, z), "
                           f"not {len(d.args)} arguments")
            else:
                coords = [self.constant(a, "a point source coordinate") for a in d.args]
                if None not in coords:
                    kind, position = "point", tuple(coords)
        else:
            self.error(d.kind_pos, f"unknown source kind '{d.kind}'; expected one of "
                       f"{', '.join(SOURCE_KINDS)}{did_you_mean(d.kind, SOURCE_KINDS)}")
        if not ok or kind is None or count is None:
            return None
        return Source(d.name, kind, ton.index, int(count), position, d)

    def param(self, p: A.Param, table: dict, other: dict, want: str, other_kind: str):
        found = table.get(p.type_name)
        if found is None:
            if p.type_name in other:
                self.error(p.type_pos, f"'{p.type_name}' is a {other_kind}; expected a {want} here")
            else:
                self.error(p.type_pos, f"unknown {want} '{p.type_name}'"
                           f"{did_you_mean(p.type_name, table)}")
        return found

    def rule(self, d: A.RuleDecl, tons, surfaces, kernels) -> None:
        if d.event not in TRACED_EVENTS:
            if d.event in FUTURE_EVENTS:
                self.error(d.event_pos, f"event '{d.event}' is not supported yet "
                           f"(supported: {', '.join(TRACED_EVENTS)})")
            else:
                self.error(d.event_pos, f"unknown event '{d.event}'; expected one of "
                           f"{', '.join(TRACED_EVENTS)}{did_you_mean(d.event, TRACED_EVENTS)}")
        ton = self.param(d.ton, tons, surfaces, "ton type", "surface")
        surf = self.param(d.surface, surfaces, tons, "surface", "ton type")
        if d.ton.name == d.surface.name:
            self.error(d.surface.pos, f"both parameters are named '{d.ton.name}'")
            return
        if ton is None or surf is None:
            return
        scope = Scope("transport", d.ton.name, ton, d.surface.name, surf)
        self.body(scope, d.body)
        key = (d.event, ton.index, surf.index)
        kernels.setdefault(key, Kernel(d.event, ton, surf)).bodies.append((scope, d.body))

    def update(self, d: A.UpdateDecl, surfaces, tons, kernels) -> None:
        surf = self.param(d.surface, surfaces, tons, "surface", "ton type")
        if surf is None:
            return
        scope = Scope("update", None, None, d.surface.name, surf)
        self.body(scope, d.body)
        kernels.setdefault(("update", surf.index), Kernel("update", None, surf)).bodies.append(
            (scope, d.body))

    def body(self, scope: Scope, body: list[A.Assign]) -> None:
        for st in body:
            slot = scope.resolve(st.target)
            if isinstance(slot, str):
                self.error(st.target.pos, slot)
            elif st.op not in slot.writable_ops:
                self.error(st.pos if slot.writable_ops else st.target.pos,
                           self.write_error(scope, slot, st.op))
            self.expr(scope, st.value)

    @staticmethod
    def write_error(scope: Scope, slot: Slot, op: str) -> str:
        if slot.space == "ctx":
            return f"'{slot.name}' is read-only"
        if not slot.writable_ops:
            return f"'{slot.name}' is read-only in transport rules; change it in an update rule"
        if slot.space == "surf":
            return (f"'{op}' on a surface property in a transport rule: surface writes during "
                    f"tracing are additive, use += or -=")
        return f"'{op}' is not allowed on '{slot.name}'"

    def expr(self, scope: Scope, e: A.Expr) -> None:
        if isinstance(e, A.Ref):
            slot = scope.resolve(e)
            if isinstance(slot, str):
                self.error(e.pos, slot)
        elif isinstance(e, A.Unary):
            self.expr(scope, e.operand)
        elif isinstance(e, A.Binary):
            self.expr(scope, e.left)
            self.expr(scope, e.right)
        elif isinstance(e, A.Call):
            if e.name not in FUNCTIONS:
                self.error(e.pos, f"unknown function '{e.name}'{did_you_mean(e.name, FUNCTIONS)}")
            else:
                lo, hi = FUNCTIONS[e.name]
                n = len(e.args)
                if n < lo or (hi is not None and n > hi):
                    want = f"{lo}" if lo == hi else f"at least {lo}"
                    self.error(e.pos, f"{e.name}() takes {want} arguments, not {n}")
            for a in e.args:
                self.expr(scope, a)


def check(module: A.Module) -> Effect:
    return _Checker(module).run()


def load(path: str) -> Effect:
    """Read, parse and check a file (OSError for an unreadable file)."""
    from .parser import parse

    with open(path, encoding="utf-8") as f:
        source = f.read()
    return check(parse(source, path))
