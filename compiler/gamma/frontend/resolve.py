"""Name resolution: the one place where a name of a .gamma file is looked up.

- Files: ``Program.load`` reads the main file's imports (next to the file,
  then the standard library), depth first, and evaluates each file's
  parameters (with the importer's or the command line's overrides).
- Rule bodies: ``bind`` walks a body once, for one expansion of its rule
  (a ton type and a surface), and binds every name to an ``ir.Var``: a
  carried attribute, a property or reflectance component, a context value,
  a parameter, a ``let``, or ``color``.  It reports unknown and misused
  names and assignments a name does not allow.

The checker (``checker.py``) types the body with these bindings; nothing
after it looks a name up again.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from .. import abi
from ..ir.builtins import CONTEXT_VALUES, FUNCTIONS, component_index
from ..ir.effect import Surface, TonType, Var
from . import ast as A
from .diagnostics import Diagnostic, GammaError, Report, SourceFile, UsageError, did_you_mean
from .filefacts import is_file, read_text, resolved

#: The outputs an appearance block assigns (SPEC §8a): name -> offset in the look array.
LOOK_OUTPUTS = abi.appearance_offsets()

MOTION_NAMES = abi.REFLECTANCE_SLOTS  # straight, parabolic, flow


class NotConstant(Exception):
    def __init__(self, pos: A.Pos):
        self.pos = pos


def const_value(expr: A.Expr, params: dict | None = None, used: set | None = None) -> float:
    """Fold a constant expression: numbers, parameters and arithmetic, in float32."""
    from ..ir.float32 import arith_f32, round_f32

    if isinstance(expr, A.Number):
        return round_f32(expr.value)     # 1e99 becomes inf; the checker reports it
    if isinstance(expr, A.Ref) and len(expr.parts) == 1 and params and expr.parts[0] in params:
        if used is not None:
            used.add(expr.parts[0])
        return params[expr.parts[0]]
    if isinstance(expr, A.Unary):
        return -round_f32(const_value(expr.operand, params, used))
    if isinstance(expr, A.Binary):
        return arith_f32(expr.op, const_value(expr.left, params, used), const_value(expr.right, params, used))
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
    def file(self) -> SourceFile | None:
        return None if self.main else SourceFile(self.path, self.source)


def constant(report: Report, unit: Unit, expr: A.Expr, what: str) -> float | None:
    """The value of a constant expression of ``unit``, or None after an error."""
    try:
        value = const_value(expr, unit.params, unit.used)
    except NotConstant as nc:
        report.error(nc.pos, f"{what} must be a constant number", unit.file)
        return None
    if not math.isfinite(value):
        report.error(expr.pos, f"{what} is not a finite number", unit.file)
        return None
    return value


def path_problem(text: str) -> str | None:
    """Why a file name written in an effect cannot name a file, or None."""
    if "\0" in text:
        return "a file name cannot contain a NUL character"
    if any(len(part.encode("utf-8", "surrogatepass")) > 255 for part in text.split("/")) \
            or len(text.encode("utf-8", "surrogatepass")) > 4095:
        return "the file name is too long"
    return None


def shown_path(text: str) -> str:
    """A file name as it may be printed: control characters escaped, long ones cut."""
    shown = text.encode("unicode_escape").decode("ascii") if not text.isprintable() else text
    return shown if len(shown) <= 80 else shown[:77] + "..."


def display_path(path: Path) -> str:
    """A path as a user would write it: relative to the working folder when inside it."""
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


# ---- files, imports and parameters ------------------------------------------------------

class Program:
    """The files of an effect: imported files first (depth first, in import
    order), then the main file, each with its parameters evaluated."""

    def __init__(self, report: Report, module: A.Module, overrides: dict[str, float]):
        self.report = report
        self.main = Unit(module.path, module.source, module, main=True)
        self.unknown_overrides: list[str] = []
        self.units: list[Unit] = []
        # "recipe.name" overrides (--param RECIPE.NAME=VALUE) go to the imported file recipe.gamma
        self.recipe_overrides: dict[str, dict[str, float]] = {}
        for key, value in overrides.items():
            recipe, dot, name = key.partition(".")
            if dot:
                self.recipe_overrides.setdefault(recipe, {})[name] = value
        recipes_seen: set[str] = set()
        self._recipes_seen = recipes_seen
        self._load(self.main, {n: (v, A.Pos(1, 1)) for n, v in overrides.items() if "." not in n},
                   (str(resolved(Path(module.path))),))
        for recipe, names in self.recipe_overrides.items():
            if recipe not in recipes_seen:
                imported = ", ".join(Path(u.path).stem for u in self.units if not u.main) or "none"
                self.unknown_overrides.append(f"--param {recipe}.{next(iter(names))}: "
                                              f"{Path(module.path).name} imports no recipe '{recipe}' "
                                              f"(imported: {imported})")

    def _load(self, unit: Unit, overrides: dict, chain: tuple) -> None:
        from .parser import parse

        error = lambda pos, message: self.report.error(pos, message, unit.file)
        self._evaluate_params(unit, overrides)   # first: import arguments may use them
        for d in unit.module.decls:
            if not isinstance(d, A.ImportDecl):
                continue
            found = self._find_import(unit, d)
            if found is None:
                continue
            if str(found) in chain:
                error(d.pos, f"'{d.path}' imports itself (through {' -> '.join(Path(c).name for c in chain)})")
                continue
            if any(u.path == display_path(found) for u in self.units):
                error(d.pos, f"'{d.path}' is imported twice")
                continue
            args = {}
            for init in d.args:
                value = constant(self.report, unit, init.value, f"the value of parameter '{init.name}'")
                if init.name in args:
                    error(init.pos, f"parameter '{init.name}' is given twice")
                elif value is not None:
                    args[init.name] = (value, init.pos)
            try:
                text = read_text(found)
            except (OSError, UnicodeDecodeError) as err:
                error(d.pos, f"cannot read '{d.path}': {err}")
                continue
            try:
                module = parse(text, display_path(found))
            except GammaError as err:
                self.report.extend(Diagnostic(x.pos, x.message, x.severity,
                                              SourceFile(display_path(found), text))
                                   for x in err.diagnostics)
                continue
            child = Unit(display_path(found), text, module, main=False)
            # the command line's RECIPE.NAME (pos None) wins over the import's own arguments
            if found.stem in self.recipe_overrides:
                self._recipes_seen.add(found.stem)
                args.update({name: (value, None) for name, value in self.recipe_overrides[found.stem].items()})
            self._load(child, args, chain + (str(found),))
        self.units.append(unit)

    def _find_import(self, unit: Unit, d: A.ImportDecl) -> Path | None:
        problem = path_problem(d.path)
        if problem:
            self.report.error(d.pos, f"cannot import '{shown_path(d.path)}': {problem}", unit.file)
            return None
        for base in (resolved(Path(unit.path)).parent, stdlib_dir()):
            candidate = resolved(base / d.path)
            if is_file(candidate):
                return candidate
        self.report.error(d.pos, f"cannot find '{d.path}' next to {Path(unit.path).name} or in the "
                          "standard library", unit.file)
        return None

    def _evaluate_params(self, unit: Unit, overrides: dict) -> None:
        error = lambda pos, message: self.report.error(pos, message, unit.file)
        for d in unit.module.decls:
            if not isinstance(d, A.ParamDecl):
                continue
            if d.name in unit.params:
                error(d.pos, f"parameter '{d.name}' is already declared at line "
                      f"{unit.param_pos[d.name].line}")
                continue
            if d.name in CONTEXT_VALUES or d.name in FUNCTIONS or d.name in ("down", "up"):
                error(d.pos, f"'{d.name}' is a built-in name; a parameter needs another")
                continue
            value = constant(self.report, unit, d.value, f"the value of parameter '{d.name}'")
            if d.name in overrides:
                value = overrides[d.name][0]
            if value is not None:
                unit.params[d.name] = value
                unit.param_pos[d.name] = d.pos
        for name, (_, pos) in overrides.items():
            if name not in unit.params:
                where = Path(unit.path).name
                if unit.main or pos is None:
                    option = name if unit.main else f"{Path(unit.path).stem}.{name}"
                    self.unknown_overrides.append(f"--param {option}: {where} has no parameter "
                                                  f"'{name}'{did_you_mean(name, unit.params)}; "
                                                  f"its parameters: {', '.join(unit.params) or 'none'}")
                else:
                    self.report.extend([Diagnostic(pos, f"{where} has no parameter '{name}'"
                                                   f"{did_you_mean(name, unit.params)}")])


# ---- names in rule bodies ----------------------------------------------------------------------

@dataclass
class Scope:
    """The names visible in one rule body, for one expansion of its rule."""

    kind: str                      # 'transport' | 'update' | 'appearance'
    ton_param: str | None
    ton: TonType | None
    surf_param: str
    surface: Surface
    unit: Unit                     # the rule's file (its parameters)

    def resolve(self, ref: A.Ref, lets=()) -> Var | str:
        """The name's binding, or an error message.  ``lets``: the ``let`` names in scope."""
        parts = ref.parts
        head = parts[0]
        params = self.unit.params
        if head in lets:
            if len(parts) == 2 and component_index(None, parts[1]) is not None:
                # a component of a vector let; the checker says so if the let is not a vector
                return Var("let", head, component=component_index(None, parts[1]), text=".".join(parts))
            if len(parts) > 1:
                return f"'{head}' is a local value and has no fields"
            return Var("let", head, text=head)
        if head in LOOK_OUTPUTS and head not in params:
            if self.kind != "appearance":
                return f"'{head}' is an output of appearance blocks; it is not available in {self.kind} rules"
            if len(parts) > 1:
                return f"'{head}' has no fields"
            return Var("look", head, LOOK_OUTPUTS[head], writable=("=",), text=head)
        if head in params and head not in (self.ton_param, self.surf_param):
            if len(parts) > 1:
                return f"'{head}' is a parameter and has no fields"
            return Var("param", head, text=head)
        if head in CONTEXT_VALUES and head not in (self.ton_param, self.surf_param):
            kinds, components = CONTEXT_VALUES[head]
            if self.kind not in kinds:
                return f"'{head}' is not available in {self.kind} rules"
            if not components:
                if len(parts) > 1:
                    return f"'{head}' is a number and has no fields"
                return Var("ctx", head, text=head)
            if len(parts) == 1:
                return Var("ctx", head, text=head)
            index = component_index(head, parts[1])
            if len(parts) != 2 or index is None:
                return (f"'{head}' is a vector; its components are {head}.x, {head}.y and "
                        f"{head}.z")
            return Var("ctx", head, component=index, text=".".join(parts))
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
                return Var("ton", attr, self.ton.carry[attr], writable=("=", "+=", "-=", "*="),
                           text=f"{head}.{attr}")
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
                return Var("surf", f"reflectance.{parts[2]}", MOTION_NAMES.index(parts[2]),
                           writable=ops, text=".".join(parts))
            if len(parts) == 2 and attr in self.surface.properties:
                ops = {"transport": ("+=", "-="), "update": ("=", "+=", "-=", "*=")}.get(self.kind, ())
                return Var("surf", attr, self.surface.properties[attr], writable=ops,
                           text=f"{head}.{attr}")
            if len(parts) == 2 and self.ton is not None and attr in self.ton.carry:
                return (f"surface {self.surface.name} has no property '{attr}'; '{attr}' is carried "
                        f"by ton {self.ton.name} (did you mean '{self.ton_param}.{attr}'?)")
            if len(parts) > 2:
                return f"'{head}.{attr}' has no fields"
            return (f"surface {self.surface.name} has no property '{attr}'"
                    f"{did_you_mean(attr, self.surface.properties)}")
        names = [n for n in (self.ton_param, self.surf_param) if n] + list(CONTEXT_VALUES)
        return f"unknown name '{head}'{did_you_mean(head, names)}"


#: id(ast.Ref) -> its binding, for the refs of one expansion of one body.
Bindings = dict


def bind(scope: Scope, body: list, report: Report) -> Bindings:
    """Bind every name of ``body`` (one expansion); report what cannot be bound."""
    bindings: Bindings = {}
    _bind_body(scope, body, report, bindings, frozenset())
    return bindings


def bind_expression(scope: Scope, e: A.Expr, report: Report) -> Bindings:
    """Bind every name of one expression (a surface source's weight)."""
    bindings: Bindings = {}
    _bind_expr(scope, e, report, bindings, frozenset())
    return bindings


def _bind_body(scope: Scope, body: list, report: Report, bindings: Bindings, lets: frozenset) -> None:
    error = lambda pos, message: report.error(pos, message, scope.unit.file)
    for st in body:
        if isinstance(st, A.Let):
            _bind_expr(scope, st.value, report, bindings, lets)
            taken = (st.name in lets or st.name in (scope.ton_param, scope.surf_param)
                     or st.name in CONTEXT_VALUES or st.name in FUNCTIONS
                     or st.name in scope.unit.params
                     or (scope.kind == "appearance" and st.name in LOOK_OUTPUTS))
            if taken:
                error(st.pos, f"'{st.name}' is already a name here; choose another")
            lets = lets | {st.name}
        elif isinstance(st, A.If):
            _bind_expr(scope, st.cond, report, bindings, lets)
            _bind_body(scope, st.then, report, bindings, lets)
            _bind_body(scope, st.otherwise, report, bindings, lets)
        else:
            var = scope.resolve(st.target, lets)
            if isinstance(var, str):
                error(st.target.pos, var)
            else:
                bindings[id(st.target)] = var
                if var.space in ("let", "param"):
                    what = "a let value" if var.space == "let" else "a parameter"
                    error(st.target.pos, f"'{var.text}' is {what} and cannot be changed")
                elif st.op not in var.writable:
                    error(st.pos if var.writable else st.target.pos, _write_error(scope, var, st.op))
            _bind_expr(scope, st.value, report, bindings, lets)


def _write_error(scope: Scope, var: Var, op: str) -> str:
    if var.space == "ctx":
        return f"'{var.text}' is read-only"
    if not var.writable:
        where = "appearance blocks" if scope.kind == "appearance" else "transport rules"
        return f"'{var.text}' is read-only in {where}; change it in an update rule"
    if var.space == "surf":
        return (f"'{op}' on a surface property in a transport rule: surface writes during "
                f"tracing are additive, use += or -=")
    return f"'{op}' is not allowed on '{var.text}'"


def _bind_expr(scope: Scope, e: A.Expr, report: Report, bindings: Bindings, lets: frozenset) -> None:
    if isinstance(e, A.Ref):
        var = scope.resolve(e, lets)
        if isinstance(var, str):
            report.error(e.pos, var, scope.unit.file)
            return
        if var.space == "param":
            scope.unit.used.add(var.name)
        bindings[id(e)] = var
    elif isinstance(e, A.Unary):
        _bind_expr(scope, e.operand, report, bindings, lets)
    elif isinstance(e, (A.Binary, A.Compare)):
        _bind_expr(scope, e.left, report, bindings, lets)
        _bind_expr(scope, e.right, report, bindings, lets)
    elif isinstance(e, A.Logic):
        _bind_expr(scope, e.left, report, bindings, lets)
        if e.right is not None:
            _bind_expr(scope, e.right, report, bindings, lets)
    elif isinstance(e, A.Call):
        fn = FUNCTIONS.get(e.name)
        if e.name == "relative":
            return      # not a value in a rule: the checker says so, its arguments are not looked at
        if fn is None:
            report.error(e.pos, f"unknown function '{e.name}'{did_you_mean(e.name, FUNCTIONS)}",
                         scope.unit.file)
        elif not fn.accepts(len(e.args)) or fn.string_arg \
                or (fn.appearance_only and scope.kind != "appearance"):
            return      # a malformed call's arguments are not looked at (one error is enough)
        for a in e.args:
            _bind_expr(scope, a, report, bindings, lets)
    elif isinstance(e, A.Vector):
        for item in e.items:
            _bind_expr(scope, item, report, bindings, lets)
    elif isinstance(e, A.Field):
        _bind_expr(scope, e.operand, report, bindings, lets)
    # a string has no names to bind


def declared(report: Report, unit: Unit, p: A.Param, table: dict, other: dict, want: str,
             other_kind: str) -> list:
    """The declarations a rule parameter's type names ('*': all of them)."""
    if p.type_name == "*":
        return list(table.values())
    found = table.get(p.type_name)
    if found is None:
        if p.type_name in other:
            report.error(p.type_pos, f"'{p.type_name}' is a {other_kind}; expected a {want} here", unit.file)
        else:
            report.error(p.type_pos, f"unknown {want} '{p.type_name}'{did_you_mean(p.type_name, table)}",
                         unit.file)
        return []
    return [found]
