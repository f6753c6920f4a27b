"""Name and type checking: from the AST to a resolved ``Effect``.

Every error of the file is collected (never just the first) and raised
together as ``GammaError``.  The result, ``Effect``, is what the code
generator, the reference interpreter and the runner consume: ton types,
surfaces with their row layout, sources, and the transport/update rules
grouped per kernel.  Name lookup inside rule bodies is done by one function,
``Scope.resolve``, shared by all three consumers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from .. import abi
from . import ast as A
from .diagnostics import Diagnostic, GammaError, did_you_mean

MOTION_NAMES = abi.REFLECTANCE_SLOTS  # straight, parabolic, flow
EVENTS = tuple(abi.EVENTS)             # hit, reflect, bounce, flow, settle
#: Read-only context values: name -> (rules that may read it, components).
CONTEXT_VALUES = {
    "iteration": (("transport", "update", "appearance"), ()),
    "interactions": (("transport",), ()),
    "height": (("transport", "update", "appearance"), ()),
    "position": (("transport", "update", "appearance"), ("x", "y", "z")),
    "normal": (("transport", "update", "appearance"), ("x", "y", "z")),
    "direction": (("transport",), ("x", "y", "z")),
    "uv": (("appearance",), ("u", "v")),
}
#: Built-in functions: name -> (fewest, most arguments); all take and give numbers.
FUNCTIONS = {"min": (2, None), "max": (2, None), "clamp": (3, 3), "mix": (3, 3),
             "smoothstep": (3, 3), "abs": (1, 1), "sqrt": (1, 1), "exp": (1, 1), "log": (1, 1),
             "pow": (2, 2), "floor": (1, 1), "fract": (1, 1), "random": (0, 0),
             "rgb": (3, 3), "texture": (1, 1)}
#: Functions that are only meaningful in appearance blocks (they give colours).
COLOR_FUNCTIONS = ("rgb", "texture")
RESERVED_PROPERTY_NAMES = {"x", "y", "z", "nx", "ny", "nz", "surface", "reflectance", "motion"}
MAX_COUNT = 1e12  # gamma-tons per source and iteration
REQUIRED = object()
#: Parameters of each source kind, in positional order: (name, type, default).
SOURCE_PARAMS = {
    "point": (("position", "place", REQUIRED),),
    "spot": (("position", "place", REQUIRED), ("direction", "direction", "down"),
             ("angle", "angle", REQUIRED), ("falloff", "nonnegative", 0.0)),
    "area": (("shape", ("rect", "disk"), REQUIRED), ("position", "place", REQUIRED),
             ("normal", "direction", "down"), ("size", "size2", None), ("radius", "length", None),
             ("emission", ("parallel", "uniform", "cosine"), "parallel")),
    "directional": (("direction", "direction", "down"),),
    "environment": (("shape", ("sphere", "hemisphere"), REQUIRED),),
}
SOURCE_KINDS = tuple(SOURCE_PARAMS)


# ---- the checked effect -------------------------------------------------------

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


@dataclass
class TonType:
    name: str
    index: int
    motion: tuple[float, float, float]
    carry: dict[str, int]          # attribute -> slot in the ton array
    initial: list[float]
    bounce: Length | None          # None: the runner's default
    step: Length | None
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
    kind: str                      # the runtime's kind: point spot rect disk directional sphere hemisphere
    ton: int
    count: int
    params: dict                   # checked parameters (Place, Length, 'down'/'up' or a vector, ...)
    first: int                     # first iteration it emits in (1-based)
    last: int                      # last iteration it emits in; 0 = no end
    decl: A.SourceDecl


@dataclass
class Slot:
    """Where a name in a rule body lives."""

    space: str      # 'ton' | 'surf' | 'ctx'
    index: int      # slot in the ton array / surfel row; ctx: vector component (0 for scalars)
    name: str       # ctx: the context field
    writable_ops: tuple[str, ...]


@dataclass
class Scope:
    """The names visible in one rule body."""

    kind: str                      # 'transport' | 'update'
    ton_param: str | None
    ton: TonType | None
    surf_param: str
    surface: Surface
    params: dict = field(default_factory=dict)   # parameters of the rule's file
    origin: str = ""                             # path of the rule's file

    def resolve(self, ref: A.Ref, lets=()) -> Slot | str:
        """A Slot, or an error message (only the checker ever sees those).
        ``lets`` holds the names of the ``let`` bindings in scope."""
        parts = ref.parts
        head = parts[0]
        transport = self.kind == "transport"
        if head in lets:
            if len(parts) > 1:
                return f"'{head}' is a local value and has no fields"
            return Slot("let", 0, head, ())
        if head == "color" and self.kind == "appearance" and head not in self.params:
            if len(parts) > 1:
                return "'color' has no fields"
            return Slot("color", 0, "color", ("=",))
        if head in self.params and head not in (self.ton_param, self.surf_param):
            if len(parts) > 1:
                return f"'{head}' is a parameter and has no fields"
            return Slot("param", 0, head, ())
        if head in CONTEXT_VALUES and head not in (self.ton_param, self.surf_param):
            kinds, components = CONTEXT_VALUES[head]
            if self.kind not in kinds:
                return f"'{head}' is not available in {self.kind} rules"
            if not components:
                if len(parts) > 1:
                    return f"'{head}' is a number and has no fields"
                return Slot("ctx", 0, head, ())
            if len(parts) != 2 or parts[1] not in components:
                return f"'{head}' is a vector: write {head}.x, {head}.y or {head}.z"
            return Slot("ctx", components.index(parts[1]), head, ())
        if len(parts) == 1:
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
                ops = ("=", "+=", "-=", "*=") if self.kind == "update" else ()
                return Slot("surf", MOTION_NAMES.index(parts[2]), ".".join(parts), ops)
            if len(parts) == 2 and attr in self.surface.properties:
                ops = {"transport": ("+=", "-="), "update": ("=", "+=", "-=", "*=")}.get(self.kind, ())
                return Slot("surf", self.surface.properties[attr], f"{head}.{attr}", ops)
            if len(parts) == 2 and self.ton is not None and attr in self.ton.carry:
                return (f"surface {self.surface.name} has no property '{attr}'; '{attr}' is carried "
                        f"by ton {self.ton.name} (did you mean '{self.ton_param}.{attr}'?)")
            if len(parts) > 2:
                return f"'{head}.{attr}' has no fields"
            return (f"surface {self.surface.name} has no property '{attr}'"
                    f"{did_you_mean(attr, self.surface.properties)}")
        names = [n for n in (self.ton_param, self.surf_param) if n] + list(CONTEXT_VALUES)
        return f"unknown name '{head}'{did_you_mean(head, names)}"


@dataclass
class Kernel:
    """All rule bodies that run for one (event, ton type, surface), in file order."""

    event: str                     # an event of abi.EVENTS, 'update' or 'appearance'
    ton: TonType | None
    surface: Surface
    bodies: list[tuple[Scope, list[A.Assign]]] = field(default_factory=list)
    textures: dict = field(default_factory=dict)  # id(texture() call) -> index in Effect.textures

    @property
    def label(self) -> str:
        if self.ton is None:
            return f"{self.event}({self.surface.name})"
        return f"on {self.event}({self.ton.name}, {self.surface.name})"

    @property
    def symbol(self) -> str:
        # '.' cannot occur in a name, so symbols never collide
        if self.ton is None:
            return f"gamma.{self.event}.{self.surface.name}"
        return f"gamma.{self.event}.{self.ton.name}.{self.surface.name}"

    def statement_numbers(self) -> dict[int, int]:
        """id(Assign) -> its 1-based number, the one a kernel returns when the
        statement's result is NaN or infinite.  A body shared by several
        kernels (a wildcard rule) is numbered per kernel, in the same order."""
        return {id(st): n for n, st in enumerate(
            (st for _, body in self.bodies for st in assignments(body)), start=1)}

    def statement_at(self, number: int) -> tuple[Scope, A.Assign]:
        found = [(scope, st) for scope, body in self.bodies for st in assignments(body)]
        return found[number - 1]

    def random_sites(self) -> dict[int, int]:
        """id(Call random()) -> its site number (0, 1, ...) in source order."""
        sites: dict[int, int] = {}

        def walk(node):
            if isinstance(node, A.Call) and node.name == "random":
                sites[id(node)] = len(sites)
            for child in _children(node):
                walk(child)

        for _, body in self.bodies:
            walk_statements(body, walk)
        return sites

    @property
    def writes_surface(self) -> bool:
        return any(scope.resolve(st.target).space == "surf"
                   for scope, body in self.bodies for st in assignments(body))


def _children(node) -> list:
    if isinstance(node, (A.Unary,)):
        return [node.operand]
    if isinstance(node, (A.Binary, A.Compare)):
        return [node.left, node.right]
    if isinstance(node, A.Logic):
        return [node.left] + ([node.right] if node.right is not None else [])
    if isinstance(node, A.Call):
        return list(node.args)
    return []


def walk_statements(body: list, visit) -> None:
    """Call ``visit`` on every top-level expression of the body, in execution order
    (a condition, then its branches; a statement's value before its target)."""
    for st in body:
        if isinstance(st, A.Let):
            visit(st.value)
        elif isinstance(st, A.If):
            visit(st.cond)
            walk_statements(st.then, visit)
            walk_statements(st.otherwise, visit)
        else:
            visit(st.value)


def assignments(body: list) -> list[A.Assign]:
    """Every assignment of a rule body, in nested blocks too."""
    found = []
    for st in body:
        if isinstance(st, A.Assign):
            found.append(st)
        elif isinstance(st, A.If):
            found += assignments(st.then) + assignments(st.otherwise)
    return found


@dataclass
class Effect:
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
    textures: list = field(default_factory=list) # image files read by texture(), in index order

    def transport_kernels(self) -> list[Kernel]:
        return [k for k in self.kernels if k.ton is not None]

    def update_kernels(self) -> list[Kernel]:
        return [k for k in self.kernels if k.event == "update"]

    def appearance_kernels(self) -> list[Kernel]:
        return [k for k in self.kernels if k.event == "appearance"]


# ---- constant evaluation ----------------------------------------------------------

class UsageError(Exception):
    """A mistake on the command line rather than in the file (exit status 2)."""


class NotConstant(Exception):
    def __init__(self, pos: A.Pos):
        self.pos = pos


def const_value(expr: A.Expr, params: dict | None = None, used: set | None = None) -> float:
    """Fold a constant expression: numbers, parameters and arithmetic, in float32."""
    import numpy as np

    f32 = np.float32
    if isinstance(expr, A.Number):
        with np.errstate(over="ignore"):  # 1e99 becomes inf; the checker reports it
            return float(f32(expr.value))
    if isinstance(expr, A.Ref) and len(expr.parts) == 1 and params and expr.parts[0] in params:
        if used is not None:
            used.add(expr.parts[0])
        return params[expr.parts[0]]
    if isinstance(expr, A.Unary):
        return float(-f32(const_value(expr.operand, params, used)))
    if isinstance(expr, A.Binary):
        a = f32(const_value(expr.left, params, used))
        b = f32(const_value(expr.right, params, used))
        with np.errstate(all="ignore"):
            return float({"+": a + b, "-": a - b, "*": a * b, "/": a / b}[expr.op])
    raise NotConstant(expr.pos)


@dataclass
class Unit:
    """One file of the program: its text, its parameters' values and which were read."""

    path: str
    source: str
    module: A.Module
    main: bool
    params: dict[str, float] = field(default_factory=dict)
    param_pos: dict[str, A.Pos] = field(default_factory=dict)
    used: set[str] = field(default_factory=set)

    @property
    def file(self):
        from .diagnostics import SourceFile

        return None if self.main else SourceFile(self.path, self.source)


def _display_path(path: Path) -> str:
    """A path as a user would write it: relative to the working folder when inside it."""
    import os

    try:
        rel = os.path.relpath(path)
    except ValueError:
        return str(path)
    return str(path) if rel.startswith("..") else rel


def stdlib_dir() -> Path:
    package = Path(__file__).resolve().parent.parent   # installed: gamma/stdlib
    for candidate in (package / "stdlib", package.parent.parent / "stdlib"):
        if candidate.is_dir():
            return candidate
    return package / "stdlib"


# ---- the checker ---------------------------------------------------------------------

class _Checker:
    def __init__(self, module: A.Module, overrides: dict[str, float]):
        self.module = module
        self.overrides = overrides
        self.diags: list[Diagnostic] = []
        self.warnings: list[Diagnostic] = []
        self.unit = Unit(module.path, module.source, module, main=True)
        self.unknown_overrides: list[str] = []
        self.textures: dict[str, int] = {}      # resolved path -> index
        self.kernel: Kernel | None = None       # the kernel whose body is being checked

    def error(self, pos: A.Pos, message: str) -> None:
        diag = Diagnostic(pos, message, file=self.unit.file)
        if diag not in self.diags:  # a wildcard rule is checked once per expansion
            self.diags.append(diag)

    def warn(self, unit: Unit, pos: A.Pos, message: str) -> None:
        diag = Diagnostic(pos, message, "warning", unit.file)
        if diag not in self.warnings:
            self.warnings.append(diag)

    # -- files, imports and parameters --

    def load_units(self, unit: Unit, overrides: dict, chain: tuple, units: list) -> None:
        """Imported files first (depth first, in import order), then ``unit``."""
        from .parser import parse

        self.unit = unit
        self.evaluate_params(unit, overrides)   # first: import arguments may use them
        for d in unit.module.decls:
            if not isinstance(d, A.ImportDecl):
                continue
            self.unit = unit
            found = self.resolve_import(unit, d)
            if found is None:
                continue
            if str(found) in chain:
                self.error(d.pos, f"'{d.path}' imports itself (through {' -> '.join(Path(c).name for c in chain)})")
                continue
            if any(u.path == _display_path(found) for u in units):
                self.error(d.pos, f"'{d.path}' is imported twice")
                continue
            args = {}
            for init in d.args:
                value = self.constant(init.value, f"the value of parameter '{init.name}'")
                if init.name in args:
                    self.error(init.pos, f"parameter '{init.name}' is given twice")
                elif value is not None:
                    args[init.name] = (value, init.pos)
            try:
                text = found.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as err:
                self.error(d.pos, f"cannot read '{d.path}': {err}")
                continue
            try:
                module = parse(text, _display_path(found))
            except GammaError as err:
                from .diagnostics import SourceFile

                self.diags += [Diagnostic(x.pos, x.message, x.severity, SourceFile(_display_path(found), text))
                               for x in err.diagnostics]
                continue
            child = Unit(_display_path(found), text, module, main=False)
            self.load_units(child, args, chain + (str(found),), units)
            self.unit = unit
        self.unit = unit
        units.append(unit)

    def resolve_import(self, unit: Unit, d: A.ImportDecl) -> Path | None:
        for base in (Path(unit.path).resolve().parent, stdlib_dir()):
            candidate = (base / d.path).resolve()
            if candidate.is_file():
                return candidate
        self.error(d.pos, f"cannot find '{d.path}' next to {Path(unit.path).name} or in the "
                   "standard library")
        return None

    def evaluate_params(self, unit: Unit, overrides: dict) -> None:
        for d in unit.module.decls:
            if not isinstance(d, A.ParamDecl):
                continue
            if d.name in unit.params:
                self.error(d.pos, f"parameter '{d.name}' is already declared at line "
                           f"{unit.param_pos[d.name].line}")
                continue
            if d.name in CONTEXT_VALUES or d.name in FUNCTIONS or d.name in ("down", "up"):
                self.error(d.pos, f"'{d.name}' is a built-in name; a parameter needs another")
                continue
            value = self.constant(d.value, f"the value of parameter '{d.name}'")
            if d.name in overrides:
                value = overrides[d.name][0]
            if value is not None:
                unit.params[d.name] = value
                unit.param_pos[d.name] = d.pos
        for name, (_, pos) in overrides.items():
            if name not in unit.params:
                where = Path(unit.path).name
                if unit.main:
                    self.unknown_overrides.append(f"--param {name}: {where} has no parameter "
                                                  f"'{name}'{did_you_mean(name, unit.params)}")
                else:
                    self.diags.append(Diagnostic(pos, f"{where} has no parameter '{name}'"
                                                 f"{did_you_mean(name, unit.params)}"))

    def constant(self, expr: A.Expr, what: str) -> float | None:
        try:
            value = const_value(expr, self.unit.params, self.unit.used)
        except NotConstant as nc:
            self.error(nc.pos, f"{what} must be a constant number")
            return None
        if not math.isfinite(value):
            self.error(expr.pos, f"{what} is not a finite number")
            return None
        return value

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
        units: list[Unit] = []
        main = self.unit
        self.load_units(main, {n: (v, A.Pos(1, 1)) for n, v in self.overrides.items()},
                        (str(Path(main.path).resolve()),), units)
        decls = [(u, d) for u in units for d in u.module.decls]
        names: dict[str, tuple[A.Pos, Unit]] = {}
        tons: dict[str, TonType] = {}
        surfaces: dict[str, Surface] = {}

        def declare(name: str, pos: A.Pos, what: str) -> bool:
            if name in names:
                where, unit = names[name]
                other = "" if unit is self.unit else f" of {Path(unit.path).name}"
                self.error(pos, f"{what} '{name}' is already declared at line {where.line}{other}")
                return False
            names[name] = (pos, self.unit)
            return True

        for unit, d in decls:
            self.unit = unit
            if isinstance(d, A.TonDecl) and declare(d.name, d.pos, "ton"):
                tons[d.name] = self.ton(d, len(tons))
            elif isinstance(d, A.SurfaceDecl) and declare(d.name, d.pos, "surface"):
                surfaces[d.name] = self.surface(d, len(surfaces))
        sources = []
        for unit, d in decls:
            self.unit = unit
            if isinstance(d, A.SourceDecl) and declare(d.name, d.pos, "source"):
                src = self.source(d, tons, surfaces)
                if src is not None:
                    sources.append(src)
        assign = []
        for unit, d in decls:
            self.unit = unit
            if isinstance(d, A.AssignDecl):
                if d.surface in surfaces:
                    assign.append((d.pattern, d.surface))
                elif d.surface in tons:
                    self.error(d.surface_pos, f"'{d.surface}' is a ton type; assign binds parts to a surface")
                else:
                    self.error(d.surface_pos, f"unknown surface '{d.surface}'{did_you_mean(d.surface, surfaces)}")
        kernels: dict[tuple, Kernel] = {}
        for unit, d in decls:
            self.unit = unit
            if isinstance(d, A.RuleDecl):
                self.rule(d, tons, surfaces, kernels)
            elif isinstance(d, A.UpdateDecl):
                self.update(d, surfaces, tons, kernels)
            elif isinstance(d, A.AppearanceDecl):
                self.appearance(d, surfaces, tons, kernels)
        self.unit = main
        if self.unknown_overrides:
            raise UsageError(self.unknown_overrides[0])
        width = abi.ROW_HEADER + max((len(s.properties) for s in surfaces.values()), default=0)
        if self.diags:
            raise GammaError(self.module.path, self.module.source, self.diags)
        effect = Effect(self.module.path, self.module.source, tons, surfaces, sources,
                        list(kernels.values()), width)
        self.collect_warnings(effect, units)
        effect.warnings = self.warnings
        effect.params = dict(main.params)
        effect.assign = assign
        effect.textures = list(self.textures)
        return effect

    def collect_warnings(self, effect: Effect, units: list[Unit]) -> None:
        by_decl = {id(d): u for u in units for d in u.module.decls}
        emitted = {s.ton for s in effect.sources}
        for kernel in effect.transport_kernels():
            if kernel.ton.index not in emitted:
                for scope, body in kernel.bodies:
                    rule = next(d for u in units for d in u.module.decls if isinstance(d, A.RuleDecl)
                                and d.body is body)
                    self.warn(by_decl[id(rule)], rule.event_pos,
                              f"this rule never fires for ton {kernel.ton.name}: no source emits it")
        written = {(k.surface.index, scope.resolve(st.target).index)
                   for k in effect.kernels for scope, body in k.bodies for st in assignments(body)
                   if scope.resolve(st.target).space == "surf"}
        for surface in effect.surfaces.values():
            unit = by_decl[id(surface.decl)]
            for init in surface.decl.properties:
                slot = surface.properties.get(init.name)
                if slot is not None and (surface.index, slot) not in written:
                    self.warn(unit, init.pos, f"property '{init.name}' of {surface.name} is never "
                              "changed by any rule")
        for unit in units:
            for name, pos in unit.param_pos.items():
                if name not in unit.used:
                    self.warn(unit, pos, f"parameter '{name}' is never used")

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
        bounce = self.length(d.bounce, "the bounce distance") if d.bounce is not None else None
        step = self.length(d.step, "the flow step") if d.step is not None else None
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

    # -- scene values (source arguments, bounce distance, flow step) --

    def relative_args(self, e: A.Expr, n: int, what: str) -> tuple | None:
        """The constants of ``relative(...)`` with n arguments, else None."""
        if len(e.args) != n:
            self.error(e.pos, f"relative() takes {n} argument{'s' if n > 1 else ''} for {what}")
            return None
        values = [self.constant(a, f"an argument of relative()") for a in e.args]
        return None if None in values else tuple(values)

    def length(self, e: A.Expr, what: str) -> Length | None:
        if isinstance(e, A.Call) and e.name == "relative":
            values = self.relative_args(e, 1, what)
            result = Length(values[0], True) if values else None
        else:
            value = self.constant(e, what)
            result = Length(value) if value is not None else None
        if result is not None and result.value <= 0:
            self.error(e.pos, f"{what} must be positive, not {result.value:g}")
            return None
        return result

    def place(self, e: A.Expr, what: str) -> Place | None:
        if isinstance(e, A.Call) and e.name == "relative":
            values = self.relative_args(e, 3, what)
            return Place(values, True) if values else None
        if isinstance(e, A.Vector) and len(e.items) == 3:
            values = [self.constant(a, what) for a in e.items]
            return None if None in values else Place(tuple(values))
        self.error(e.pos, f"{what} must be a point (x, y, z) or relative(fx, fy, fz)")
        return None

    def direction(self, e: A.Expr, what: str):
        if isinstance(e, A.Ref) and e.parts in (["down"], ["up"]):
            return e.parts[0]
        if isinstance(e, A.Vector) and len(e.items) == 3:
            values = [self.constant(a, what) for a in e.items]
            if None in values:
                return None
            if not any(values):
                self.error(e.pos, f"{what} must not be the zero vector")
                return None
            return tuple(values)
        self.error(e.pos, f"{what} must be a direction (x, y, z), down or up")
        return None

    def source_value(self, kind_of_value, e: A.Expr, what: str):
        if isinstance(kind_of_value, tuple):  # one of a few words
            if isinstance(e, A.Ref) and len(e.parts) == 1 and e.parts[0] in kind_of_value:
                return e.parts[0]
            word = e.parts[0] if isinstance(e, A.Ref) else ""
            self.error(e.pos, f"{what} must be one of {', '.join(kind_of_value)}"
                       f"{did_you_mean(word, kind_of_value) if word else ''}")
            return None
        if kind_of_value == "place":
            return self.place(e, what)
        if kind_of_value == "direction":
            return self.direction(e, what)
        if kind_of_value == "length":
            return self.length(e, what)
        if kind_of_value == "size2":
            if isinstance(e, A.Vector) and len(e.items) == 2:
                sizes = [self.length(a, what) for a in e.items]
                return None if None in sizes else tuple(sizes)
            self.error(e.pos, f"{what} must be (width, height)")
            return None
        value = self.constant(e, what)
        if value is None:
            return None
        if kind_of_value == "angle" and not 0 < value <= 180:
            self.error(e.pos, f"{what} must be in (0, 180] degrees, not {value:g}")
            return None
        if kind_of_value == "nonnegative" and value < 0:
            self.error(e.pos, f"{what} must not be negative, not {value:g}")
            return None
        return value

    def source_params(self, d: A.SourceDecl) -> dict | None:
        spec = SOURCE_PARAMS[d.kind]
        names = [name for name, _, _ in spec]
        args = list(d.args)
        positional = [a for a in args if a.name is None]
        if d.kind == "point" and len(positional) == 3 and len(args) == 3:  # point(x, y, z)
            args = [A.SourceArg(None, A.Vector([a.value for a in args], args[0].pos), args[0].pos)]
        given: dict[str, A.SourceArg] = {}
        ok = True
        misspelt = None  # set to False by an unknown name: then "needs" errors are noise
        for i, arg in enumerate(args):
            name = arg.name
            if name is None:
                if any(a.name for a in args[:i]):
                    self.error(arg.pos, "a positional argument cannot follow a named one")
                    ok = False
                    continue
                if i >= len(spec):
                    self.error(arg.pos, f"{d.kind}() takes at most {len(spec)} "
                               f"argument{'s' if len(spec) > 1 else ''}")
                    ok = False
                    continue
                name = names[i]
            elif name not in names:
                self.error(arg.pos, f"{d.kind}() has no parameter '{name}'; it takes "
                           f"{', '.join(names)}{did_you_mean(name, names)}")
                ok = misspelt = False
                continue
            if name in given:
                self.error(arg.pos, f"'{name}' is given twice")
                ok = False
                continue
            given[name] = arg
        params = {}
        for name, kind_of_value, default in spec:
            if name in given:
                value = self.source_value(kind_of_value, given[name].value, f"'{name}' of {d.kind}()")
                ok = ok and value is not None
                params[name] = value
            elif default is REQUIRED:
                if misspelt is None:
                    self.error(d.kind_pos, f"{d.kind}() needs '{name}'")
                ok = False
            else:
                params[name] = default
        if ok and d.kind == "area":
            shape = params["shape"]
            need, forbid = ("size", "radius") if shape == "rect" else ("radius", "size")
            if params[need] is None:
                self.error(d.kind_pos, f"area({shape}) needs '{need}'")
                ok = False
            if forbid in given:
                self.error(given[forbid].pos, f"area({shape}) takes '{need}', not '{forbid}'")
                ok = False
        return params if ok else None

    def iteration_number(self, e: A.Expr | None, what: str) -> int | None:
        if e is None:
            return 0
        value = self.constant(e, what)
        if value is None:
            return None
        if value < 1 or value != int(value) or value > 2**31 - 1:
            self.error(e.pos, f"{what} must be an iteration number (1, 2, ...), not {value:g}")
            return None
        return int(value)

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
        if count is not None and not (math.isfinite(count) and 1 <= count <= MAX_COUNT
                                      and count == int(count)):
            self.error(d.count.pos, f"the count of a source must be a whole number from 1 to "
                       f"{MAX_COUNT:g}, not {count:g}")
            ok = False
        for extra in d.repeated_window:
            self.error(extra.pos, "'from' or 'until' is given twice")
        first = self.iteration_number(d.first, "'from'")
        last = self.iteration_number(d.last, "'until'")
        if first and last and last < first:
            self.error(d.last.pos, f"'until {last}' is before 'from {first}'")
            ok = False
        if d.kind not in SOURCE_PARAMS:
            self.error(d.kind_pos, f"unknown source kind '{d.kind}'; expected one of "
                       f"{', '.join(SOURCE_KINDS)}{did_you_mean(d.kind, SOURCE_KINDS)}")
            return None
        params = self.source_params(d)
        if not ok or params is None or count is None or first is None or last is None:
            return None
        kind = params.get("shape", d.kind) if d.kind in ("area", "environment") else d.kind
        return Source(d.name, kind, ton.index, int(count), params, first or 1, last, d)

    def param(self, p: A.Param, table: dict, other: dict, want: str, other_kind: str) -> list:
        """The declarations a rule parameter stands for ('*' = all of them)."""
        if p.type_name == "*":
            return list(table.values())
        found = table.get(p.type_name)
        if found is None:
            if p.type_name in other:
                self.error(p.type_pos, f"'{p.type_name}' is a {other_kind}; expected a {want} here")
            else:
                self.error(p.type_pos, f"unknown {want} '{p.type_name}'"
                           f"{did_you_mean(p.type_name, table)}")
            return []
        return [found]

    def rule(self, d: A.RuleDecl, tons, surfaces, kernels) -> None:
        if d.event not in EVENTS:
            self.error(d.event_pos, f"unknown event '{d.event}'; expected one of "
                       f"{', '.join(EVENTS)}{did_you_mean(d.event, EVENTS)}")
        ton_types = self.param(d.ton, tons, surfaces, "ton type", "surface")
        surfs = self.param(d.surface, surfaces, tons, "surface", "ton type")
        if d.ton.name == d.surface.name:
            self.error(d.surface.pos, f"both parameters are named '{d.ton.name}'")
            return
        for ton in ton_types:
            for surf in surfs:
                scope = Scope("transport", d.ton.name, ton, d.surface.name, surf, self.unit.params,
                              self.unit.path)
                self.body(scope, d.body)
                key = (d.event, ton.index, surf.index)
                kernels.setdefault(key, Kernel(d.event, ton, surf)).bodies.append((scope, d.body))

    def appearance(self, d: A.AppearanceDecl, surfaces, tons, kernels) -> None:
        for surf in self.param(d.surface, surfaces, tons, "surface", "ton type"):
            scope = Scope("appearance", None, None, d.surface.name, surf, self.unit.params, self.unit.path)
            kernel = kernels.setdefault(("appearance", surf.index), Kernel("appearance", None, surf))
            self.kernel = kernel
            self.body(scope, d.body)
            self.kernel = None
            kernel.bodies.append((scope, d.body))

    def texture(self, call: A.Call) -> None:
        arg = call.args[0] if call.args else None
        if not isinstance(arg, A.String):
            self.error(call.pos, 'texture() takes a file name in quotes: texture("rust.png")')
            return
        path = (Path(self.unit.path).resolve().parent / arg.value).resolve()
        if not path.is_file():
            self.error(arg.pos, f"cannot find texture '{arg.value}' next to {Path(self.unit.path).name}")
            return
        index = self.textures.setdefault(str(path), len(self.textures))
        if self.kernel is not None:
            self.kernel.textures[id(call)] = index

    def update(self, d: A.UpdateDecl, surfaces, tons, kernels) -> None:
        for surf in self.param(d.surface, surfaces, tons, "surface", "ton type"):
            scope = Scope("update", None, None, d.surface.name, surf, self.unit.params, self.unit.path)
            self.body(scope, d.body)
            kernels.setdefault(("update", surf.index), Kernel("update", None, surf)).bodies.append(
                (scope, d.body))

    def body(self, scope: Scope, body: list, lets: dict | None = None) -> None:
        """Check statements; ``lets`` maps the let names in scope to their types."""
        lets = dict(lets or {})
        for st in body:
            if isinstance(st, A.Let):
                kind = self.expr(scope, st.value, lets)
                taken = (st.name in lets or st.name in (scope.ton_param, scope.surf_param)
                         or st.name in CONTEXT_VALUES or st.name in FUNCTIONS
                         or st.name in scope.params)
                if taken:
                    self.error(st.pos, f"'{st.name}' is already a name here; choose another")
                lets[st.name] = kind
            elif isinstance(st, A.If):
                self.want(scope, st.cond, lets, "bool")
                self.body(scope, st.then, lets)
                self.body(scope, st.otherwise, lets)
            else:
                slot = scope.resolve(st.target, lets)
                if isinstance(slot, str):
                    self.error(st.target.pos, slot)
                elif slot.space in ("let", "param"):
                    what = "a let value" if slot.space == "let" else "a parameter"
                    self.error(st.target.pos, f"'{slot.name}' is {what} and cannot be changed")
                elif st.op not in slot.writable_ops:
                    self.error(st.pos if slot.writable_ops else st.target.pos,
                               self.write_error(scope, slot, st.op))
                target = slot if not isinstance(slot, str) else None
                self.want(scope, st.value, lets,
                          "color" if target is not None and target.space == "color" else "float")

    KIND_NAMES = {"float": "a number", "bool": "a truth value (a comparison)", "color": "a colour"}

    def want(self, scope: Scope, e: A.Expr, lets: dict, kind: str) -> str | None:
        got = self.expr(scope, e, lets)
        if got is not None and got != kind:
            self.error(e.pos, f"expected {self.KIND_NAMES[kind]} here, but this is "
                       f"{self.KIND_NAMES[got].split(' (')[0]}")
        return got

    @staticmethod
    def write_error(scope: Scope, slot: Slot, op: str) -> str:
        if slot.space == "ctx":
            return f"'{slot.name}' is read-only"
        if not slot.writable_ops:
            where = "appearance blocks" if scope.kind == "appearance" else "transport rules"
            return f"'{slot.name}' is read-only in {where}; change it in an update rule"
        if slot.space == "surf":
            return (f"'{op}' on a surface property in a transport rule: surface writes during "
                    f"tracing are additive, use += or -=")
        return f"'{op}' is not allowed on '{slot.name}'"

    def expr(self, scope: Scope, e: A.Expr, lets: dict) -> str | None:
        """The type of ``e``: 'float', 'bool', or None after an error."""
        if isinstance(e, A.Number):
            return "float"
        if isinstance(e, A.Ref):
            slot = scope.resolve(e, lets)
            if isinstance(slot, str):
                self.error(e.pos, slot)
                return None
            if slot.space == "param":
                self.unit.used.add(slot.name)
            if slot.space == "color":
                return "color"
            return lets[slot.name] if slot.space == "let" else "float"
        if isinstance(e, A.String):
            self.error(e.pos, 'a string is only the file name of texture("...")')
            return None
        if isinstance(e, A.Unary):
            got = self.expr(scope, e.operand, lets)
            if got == "bool":
                self.error(e.operand.pos, "expected a number here, but this is a truth value")
            return got if got in ("float", "color") else None
        if isinstance(e, A.Binary):
            left, right = self.expr(scope, e.left, lets), self.expr(scope, e.right, lets)
            if left is None or right is None:
                return None
            if left == right == "float":
                return "float"
            # colours: colour +- colour, colour * number, number * colour, colour / number
            if (left, right) == ("color", "color") and e.op in "+-" \
                    or (left, right) == ("color", "float") and e.op in "*/" \
                    or (left, right) == ("float", "color") and e.op == "*":
                return "color"
            self.error(e.pos, f"'{e.op}' cannot combine {self.KIND_NAMES[left].split(' (')[0]} and "
                       f"{self.KIND_NAMES[right].split(' (')[0]}")
            return None
        if isinstance(e, A.Compare):
            self.want(scope, e.left, lets, "float")
            self.want(scope, e.right, lets, "float")
            return "bool"
        if isinstance(e, A.Logic):
            self.want(scope, e.left, lets, "bool")
            if e.right is not None:
                self.want(scope, e.right, lets, "bool")
            return "bool"
        if isinstance(e, A.Vector):
            self.error(e.pos, "a vector is not a value in a rule; use its components")
            return None
        if isinstance(e, A.Call):
            if e.name == "relative":
                self.error(e.pos, "relative() describes a place or length in the scene; "
                           "it is not a value in a rule")
                return None
            if e.name not in FUNCTIONS:
                self.error(e.pos, f"unknown function '{e.name}'{did_you_mean(e.name, FUNCTIONS)}")
                for a in e.args:
                    self.expr(scope, a, lets)
                return None
            lo, hi = FUNCTIONS[e.name]
            n = len(e.args)
            if n < lo or (hi is not None and n > hi):
                want = f"{lo}" if lo == hi else f"at least {lo}"
                plural = "s" if (hi or lo) != 1 else ""
                self.error(e.pos, f"{e.name}() takes {want} argument{plural}, not {n}")
                return None
            if e.name in COLOR_FUNCTIONS and scope.kind != "appearance":
                self.error(e.pos, f"{e.name}() gives a colour: it belongs in appearance blocks")
                return None
            if e.name == "texture":
                self.texture(e)
                return "color"
            if e.name == "mix" and len(e.args) == 3:
                first = self.expr(scope, e.args[0], lets)
                if first == "color":
                    self.want(scope, e.args[1], lets, "color")
                    self.want(scope, e.args[2], lets, "float")
                    return "color"
                if first == "bool":
                    self.error(e.args[0].pos, "expected a number here, but this is a truth value")
                self.want(scope, e.args[1], lets, "float")
                self.want(scope, e.args[2], lets, "float")
                return "float"
            for a in e.args:
                self.want(scope, a, lets, "float")
            return "color" if e.name == "rgb" else "float"
        raise AssertionError(f"unknown expression {e!r}")


def check(module: A.Module, overrides: dict[str, float] | None = None) -> Effect:
    """Check a parsed file and everything it imports; ``overrides`` replaces the
    values of the file's own parameters (``gammac run --param``)."""
    from .parser import too_deep

    try:
        return _Checker(module, overrides or {}).run()
    except RecursionError:
        raise too_deep(module.path, module.source) from None


def load(path: str, overrides: dict[str, float] | None = None) -> Effect:
    """Read, parse and check a file (OSError for an unreadable file)."""
    from .parser import parse

    with open(path, encoding="utf-8") as f:
        source = f.read()
    return check(parse(source, path), overrides)
