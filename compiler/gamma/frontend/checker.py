"""Checking and typing: from the AST to the effect's IR (``ir.effect``).

``check`` runs the front end's passes over a parsed file:

1. ``resolve.Program`` loads the imported files and evaluates parameters;
2. declarations: ton types, surfaces (their row layout), sources (their
   arguments against ``ir.builtins.SOURCE_PARAMS``), ``assign``;
3. per rule and per expansion of its wildcards: ``resolve.bind`` binds
   every name, then ``_Typer`` types the body against ``ir.builtins`` and
   builds its IR (constants folded, statements and ``random()`` sites
   numbered) into the kernel it belongs to;
4. warnings (rules that never fire, properties never changed, parameters
   never used).

Every diagnostic goes to one ``Report``; errors are raised together as
``GammaError`` at the end.  This module never looks a name up itself.
"""

from __future__ import annotations

import math
from pathlib import Path

from .. import abi
from ..ir import effect as ir
import dataclasses

from ..ir.builtins import (CONTEXT_VALUES, FUNCTIONS, MAX_OCTAVES, REQUIRED, SHAPED_KINDS, SOURCE_KINDS, SOURCE_PARAMS,
                           VECTOR_COMPONENTS, context_kind)
from ..ir.float32 import arith_f32, round_f32
from ..ir.effect import Effect, Input, Kernel, Length, Place, Source, Surface, TonType
from . import ast as A
from .diagnostics import Report, did_you_mean
from .resolve import (MOTION_NAMES, Program, Scope, Unit, UsageError, bind, bind_expression, constant, declared,
                      path_problem, shown_path, stdlib_dir)
from .filefacts import is_file, resolved

__all__ = ["check", "load", "Effect", "Kernel", "Length", "Place", "Source", "Surface", "TonType",
           "UsageError", "stdlib_dir", "EVENTS"]

EVENTS = tuple(abi.EVENTS)             # hit, reflect, bounce, flow, settle
RESERVED_PROPERTY_NAMES = {"x", "y", "z", "nx", "ny", "nz", "surface", "reflectance", "motion"}
MAX_COUNT = 1e12  # gamma-tons per source and iteration


def check(module: A.Module, overrides: dict[str, float] | None = None,
          missing_masks: list | None = None) -> Effect:
    """Check a parsed file and everything it imports; ``overrides`` replaces the
    values of the file's own parameters (``gammac run --param``).  With
    ``missing_masks`` (a list), a mask() image that is not there is not an
    error: its path is added to the list (``gammac watch`` makes it)."""
    from .parser import too_deep

    try:
        return _Checker(module, overrides or {}, missing_masks).run()
    except RecursionError:
        raise too_deep(module.path, module.source) from None


def load(path: str, overrides: dict[str, float] | None = None) -> Effect:
    """Read, parse and check a file (OSError for an unreadable file)."""
    from .parser import parse

    with open(path, encoding="utf-8") as f:
        source = f.read()
    return check(parse(source, path), overrides)


_f32 = round_f32
_fold = arith_f32          # one float32 operation on constants, rounded as the machine would


# ---- declarations ------------------------------------------------------------------------

class _Checker:
    def __init__(self, module: A.Module, overrides: dict[str, float], missing_masks: list | None = None):
        self.module = module
        self.overrides = overrides
        self.missing_masks = missing_masks
        self.report = Report()
        self.unit: Unit | None = None
        self.textures: dict[tuple, int] = {}    # (kind, resolved path) -> index; kind "color" or "mask"
        self.base_color_calls: list = []        # base_color(): Call.texture set to len(textures) at the end
        self.inputs: dict[str, Input] = {}      # what surfels read at setup (mask(), attribute()), by name
        self.inputs_base = abi.ROW_HEADER       # their first row slot: after every surface's properties
        self.mask_uses: list = []               # every mask() call: (pos, file, surface, path)

    def error(self, pos: A.Pos, message: str) -> None:
        self.report.error(pos, message, self.unit.file)

    def constant(self, expr: A.Expr, what: str) -> float | None:
        return constant(self.report, self.unit, expr, what)

    def run(self) -> Effect:
        program = Program(self.report, self.module, self.overrides)
        units, main = program.units, program.main
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
        self.inputs_base = abi.ROW_HEADER + max((len(s.properties) for s in surfaces.values()), default=0)
        self.surfaces = surfaces
        self.weight_kernels: list[Kernel] = []   # surface sources' weights, slot fixed at the end
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
            elif isinstance(d, (A.UpdateDecl, A.AppearanceDecl)):
                self.surface_rule(d, surfaces, tons, kernels)
        self.unit = main
        if program.unknown_overrides:
            raise UsageError(program.unknown_overrides[0])
        width = self.inputs_base + len(self.inputs)
        for kernel in self.weight_kernels:      # the weight goes in the slot after the row
            for body in kernel.bodies:
                body[:] = [dataclasses.replace(st, target=dataclasses.replace(st.target, slot=width))
                           for st in body]
            kernels[("weight", kernel.source)] = kernel
        self.report.raise_errors(self.module.path, self.module.source)
        effect = Effect(self.module.path, self.module.source, tons, surfaces, sources,
                        list(kernels.values()), width)
        self.collect_warnings(effect, units)
        effect.warnings = self.report.warnings
        effect.params = dict(main.params)
        effect.assign = assign
        effect.textures = [path for _, path in self.textures]
        effect.texture_kinds = [kind for kind, _ in self.textures]
        effect.inputs = list(self.inputs.values())
        effect.mask_uses = list(self.mask_uses)
        for call in self.base_color_calls:
            call.texture = len(effect.textures)
        for kernel in effect.kernels:
            kernel.base_slot = len(effect.textures)
            kernel.inputs = [item.name for item in effect.inputs]
            kernel.inputs_base = self.inputs_base
        effect.files = [u.path for u in program.units]
        effect.overrides = dict(self.overrides)
        return effect

    def collect_warnings(self, effect: Effect, units: list[Unit]) -> None:
        by_decl = {id(d): u for u in units for d in u.module.decls}
        warn = lambda unit, pos, message: self.report.warn(pos, message, unit.file)
        emitted = {s.ton for s in effect.sources}
        for kernel in effect.transport_kernels():
            if kernel.ton.index not in emitted:
                for rule in kernel.rules:
                    warn(by_decl[id(rule)], rule.event_pos,
                         f"this rule never fires for ton {kernel.ton.name}: no source emits it")
        written = {(k.surface.index, st.target.slot) for k in effect.kernels for st in k.statements()
                   if st.target.space == "surf"}
        for surface in effect.surfaces.values():
            unit = by_decl[id(surface.decl)]
            for init in surface.decl.properties:
                slot = surface.properties.get(init.name)
                if slot is not None and (surface.index, slot) not in written:
                    warn(unit, init.pos, f"property '{init.name}' of {surface.name} is never "
                         "changed by any rule")
        for unit in units:
            for name, pos in unit.param_pos.items():
                if name not in unit.used:
                    warn(unit, pos, f"parameter '{name}' is never used")

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
        drip = None
        if d.drip is not None:
            drip = self.constant(d.drip, "the drip angle")
            if drip is not None and not (0.0 <= drip <= 90.0):
                self.error(d.drip.pos, f"the drip angle must be between 0 and 90 degrees, not {drip:g}")
                drip = None
        return TonType(d.name, index, values, {n: i for i, n in enumerate(carry)},
                       [v for v, _ in carry.values()], bounce, step, drip, d)

    def surface(self, d: A.SurfaceDecl, index: int) -> Surface:
        refl = self.inits(d.reflectance, "reflectance", MOTION_NAMES, unit=True)
        props = self.inits(d.properties, "property")
        for name, (_, init) in props.items():
            if name in RESERVED_PROPERTY_NAMES or name.startswith("reflectance_"):
                self.error(init.pos, f"property name '{name}' is reserved "
                           "(it names a column of the output maps or a built-in field)")
        row = [refl.get(n, (0.0, None))[0] for n in MOTION_NAMES] + [v for v, _ in props.values()]
        slots = {n: abi.ROW_HEADER + i for i, n in enumerate(props)}
        shape = {}
        for name, (rate, init) in self.inits(d.shape, "shape rate").items():
            if name not in slots:
                self.error(init.pos, f"shape follows '{name}', which is not a property of {d.name}"
                           f"{did_you_mean(name, slots)}")
            elif not math.isfinite(rate):
                self.error(init.value.pos, f"shape rate of '{name}' must be finite")
            else:
                shape[name] = (slots[name], rate, f"{self.module.path}:{init.pos.line}:{init.pos.col}")
        return Surface(d.name, index, slots, row, d, shape)

    # -- scene values (source arguments, bounce distance, flow step) --

    def relative_args(self, e: A.Expr, n: int, what: str) -> tuple | None:
        """The constants of ``relative(...)`` with n arguments, else None."""
        if len(e.args) != n:
            self.error(e.pos, f"relative() takes {n} argument{'s' if n > 1 else ''} for {what}")
            return None
        values = [self.constant(a, "an argument of relative()") for a in e.args]
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
        if kind_of_value == "surface":
            name = e.parts[0] if isinstance(e, A.Ref) and len(e.parts) == 1 else None
            if name in self.surfaces:
                return name
            self.error(e.pos, f"{what} must be a surface of the effect"
                       + (did_you_mean(name, self.surfaces) if name else ""))
            return None
        if kind_of_value == "axis":
            if isinstance(e, A.Ref) and e.parts == ["normal"]:
                return "normal"
            return self.direction(e, what + " (normal, down, up or (x, y, z))")
        if kind_of_value == "weight":
            return e                    # an expression of the surfel, typed by surface_source_weight
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
        for extra in d.repeated_strength:
            self.error(extra.pos, "'strength' is given twice")
        strength = None
        if d.strength is not None:
            strength = self.constant(d.strength, "the strength of a source")
            if strength is not None and not (math.isfinite(strength) and strength > 0):
                self.error(d.strength.pos, f"the strength of a source must be a positive number, not {strength:g}")
                ok = False
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
        kind = params.get("shape", d.kind) if d.kind in SHAPED_KINDS else d.kind
        if kind == "surface":
            weight = params["weight"]
            params["weight"] = None if weight is None else self.surface_source_weight(d, params["surface"], weight)
            if weight is not None and params["weight"] is None:
                return None
        return Source(d.name, kind, ton.index, int(count), params, first or 1, last, d, strength)

    def surface_source_weight(self, d: A.SourceDecl, surface: str, e: A.Expr) -> Kernel | None:
        """The kernel of a surface source's ``weight``: an update-shaped kernel
        over the surfel's row (``s.NAME``) that stores the weight after it."""
        for ref in _refs(e):
            head = ref.parts[0]
            if head != "s" and len(ref.parts) > 1 and head not in CONTEXT_VALUES:
                self.error(ref.pos, f"the weight of a surface source is worked out for each surfel before "
                           f"any γ-ton leaves, so it cannot read '{'.'.join(ref.parts)}'; "
                           "it reads the surfel as s.NAME")
                return None
        surf = self.surfaces[surface]
        scope = Scope("update", None, None, "s", surf, self.unit)
        kernel = Kernel("weight", None, surf, source=d.name)
        before = len(self.report.errors)
        typer = _Typer(self, scope, bind_expression(scope, e, self.report), kernel)
        value = typer.want(e, {}, "float")
        if value is None or len(self.report.errors) > before:
            return None
        target = ir.Var("surf", "weight", 0, text=f"weight of {d.name}")
        kernel.bodies.append([ir.Store(target, "=", value, 1, e.pos, self.unit.path)])
        kernel.random_sites = typer.sites
        self.weight_kernels.append(kernel)
        return kernel


    # -- rules --

    def rule(self, d: A.RuleDecl, tons, surfaces, kernels) -> None:
        if d.event not in EVENTS:
            self.error(d.event_pos, f"unknown event '{d.event}'; expected one of "
                       f"{', '.join(EVENTS)}{did_you_mean(d.event, EVENTS)}")
        ton_types = declared(self.report, self.unit, d.ton, tons, surfaces, "ton type", "surface")
        surfs = declared(self.report, self.unit, d.surface, surfaces, tons, "surface", "ton type")
        if d.ton.name == d.surface.name:
            self.error(d.surface.pos, f"both parameters are named '{d.ton.name}'")
            return
        for ton in ton_types:
            for surf in surfs:
                scope = Scope("transport", d.ton.name, ton, d.surface.name, surf, self.unit)
                kernel = kernels.setdefault((d.event, ton.index, surf.index), Kernel(d.event, ton, surf))
                self.body(scope, d, kernel)

    def surface_rule(self, d: A.UpdateDecl | A.AppearanceDecl, surfaces, tons, kernels) -> None:
        """``update(s: S) {...}`` or ``appearance(s: S) {...}``."""
        event = "update" if isinstance(d, A.UpdateDecl) else "appearance"
        for surf in declared(self.report, self.unit, d.surface, surfaces, tons, "surface", "ton type"):
            scope = Scope(event, None, None, d.surface.name, surf, self.unit)
            kernel = kernels.setdefault((event, surf.index), Kernel(event, None, surf))
            self.body(scope, d, kernel)

    def body(self, scope: Scope, d, kernel: Kernel) -> None:
        """Bind, type and lower one expansion of a rule body into ``kernel``."""
        bindings = bind(scope, d.body, self.report)
        typer = _Typer(self, scope, bindings, kernel)
        kernel.bodies.append(typer.statements(d.body, {}))
        kernel.rules.append(d)
        kernel.random_sites = typer.sites

    def image(self, call: A.Call, kind: str = "color") -> str | None:
        """The resolved path of ``texture("file")``'s or ``mask("file")``'s image."""
        what = "texture" if kind == "color" else "mask"
        arg = call.args[0] if call.args else None
        if not isinstance(arg, A.String):
            example = "rust.png" if kind == "color" else "moss-mask.png"
            self.error(call.pos, f'{call.name}() takes a file name in quotes: {call.name}("{example}")')
            return None
        problem = path_problem(arg.value)
        if problem:
            self.error(arg.pos, f"cannot read {what} '{shown_path(arg.value)}': {problem}")
            return None
        path = resolved(resolved(Path(self.unit.path)).parent / arg.value)
        if not is_file(path):
            if kind == "mask" and self.missing_masks is not None and not path.exists():
                if str(path) not in self.missing_masks:
                    self.missing_masks.append(str(path))
                return str(path)
            self.error(arg.pos, f"cannot find {what} '{arg.value}' next to {Path(self.unit.path).name}")
            return None
        return str(path)

    def texture(self, call: A.Call, kind: str = "color") -> int | None:
        """The index in Effect.textures of ``texture("file")``'s (or an
        appearance block's ``mask("file")``'s) image."""
        path = self.image(call, kind)
        return None if path is None else self.textures.setdefault((kind, path), len(self.textures))

    def input(self, kind: str, key: str, pos: A.Pos, surface: str, text: str) -> Input:
        """The row column of ``mask(key)`` or ``attribute(key)`` (made on first use)."""
        name = f"{kind}:{key}"
        item = self.inputs.get(name)
        if item is None:
            item = self.inputs[name] = Input(kind, key, self.inputs_base + len(self.inputs))
        item.uses.append((pos, self.unit.file, surface, text))
        return item


def _refs(e) -> list:
    """Every name (A.Ref) in an expression."""
    if isinstance(e, A.Ref):
        return [e]
    found = []
    for f in dataclasses.fields(e) if dataclasses.is_dataclass(e) else ():
        value = getattr(e, f.name)
        for item in value if isinstance(value, list) else [value]:
            if dataclasses.is_dataclass(item) and not isinstance(item, A.Pos):
                found += _refs(item)
    return found


KIND_NAMES = {"float": "a number", "bool": "a truth value (a comparison)", "color": "a colour",
              "vector": "a vector"}


_LOOK_KINDS = {name: kind for name, _, kind in abi.APPEARANCE_OUTPUTS}


def _var_kind(var) -> str:
    """The kind of a stored-to or loaded name: an appearance output's own
    (``color`` a colour, the others numbers), else a number."""
    return _LOOK_KINDS[var.name] if var.space == "look" else "float"


def _short(kind: str) -> str:
    return KIND_NAMES[kind].split(" (")[0]


class _Typer:
    """Types one expansion of a rule body with its bindings and builds its IR.
    An expression that is wrong gives None (after reporting why); a body with
    any error is never used, as ``check`` then raises."""

    def __init__(self, checker: _Checker, scope: Scope, bindings: dict, kernel: Kernel):
        self.checker, self.scope, self.bindings, self.kernel = checker, scope, bindings, kernel
        self.number = len(kernel.statements())   # statement numbers continue across bodies
        self.sites = kernel.random_sites         # and so do random() sites

    def error(self, pos: A.Pos, message: str) -> None:
        self.checker.error(pos, message)

    def statements(self, body: list, lets: dict) -> list:
        """IR of the statements; ``lets`` maps the let names in scope to their kinds."""
        lets = dict(lets)
        out = []
        for st in body:
            if isinstance(st, A.Let):
                value = self.expr(st.value, lets)
                lets[st.name] = value.kind if value is not None else None
                out.append(ir.Let(st.name, value, st.pos))
            elif isinstance(st, A.If):
                cond = self.want(st.cond, lets, "bool")
                then = self.statements(st.then, lets)
                otherwise = self.statements(st.otherwise, lets)
                out.append(ir.If(cond, then, otherwise, st.pos))
            else:
                target = self.bindings.get(id(st.target))
                kind = _var_kind(target) if target is not None else "float"
                value = self.want(st.value, lets, kind)
                self.number += 1
                if target is not None:
                    out.append(ir.Store(target, st.op, value, self.number, st.target.pos,
                                        self.scope.unit.path))
        return out

    def want(self, e: A.Expr, lets: dict, kind: str):
        got = self.expr(e, lets)
        if got is not None and got.kind != kind:
            self.error(e.pos, f"expected {KIND_NAMES[kind]} here, but this is {_short(got.kind)}")
        return got

    def expr(self, e: A.Expr, lets: dict):
        """The IR of ``e`` (its ``kind`` says float, bool or color), or None after an error."""
        if isinstance(e, A.Number):
            return ir.Const(_f32(e.value), e.pos)
        if isinstance(e, A.Ref):
            var = self.bindings.get(id(e))
            if var is None:
                return None            # resolve.bind reported it
            if var.space == "param":
                return ir.Const(_f32(self.scope.unit.params[var.name]), e.pos)
            if var.space == "let":
                kind = lets[var.name]
                if kind is None:
                    return None
                if var.component is None:
                    return ir.Load(var, kind, e.pos)
                whole = ir.Load(dataclasses.replace(var, component=None, text=var.name), kind, e.pos)
                return self.component(whole, e.parts[1], e.pos, e.part_pos[1] if e.part_pos else e.pos,
                                      var.name)
            if var.space == "ctx":
                whole = var.component is None and context_kind(var.name) == "vector"
                return ir.Load(var, "vector" if whole else "float", e.pos)
            return ir.Load(var, _var_kind(var), e.pos)
        if isinstance(e, A.String):
            self.error(e.pos, 'a string is only the argument of texture("..."), mask("...") or attribute("...")')
            return None
        if isinstance(e, A.Unary):
            operand = self.expr(e.operand, lets)
            if operand is None:
                return None
            if operand.kind == "bool":
                self.error(e.operand.pos, "expected a number here, but this is a truth value")
                return None
            if isinstance(operand, ir.Const):
                return ir.Const(-operand.value, e.pos)
            return ir.Neg(operand, operand.kind, e.pos)
        if isinstance(e, A.Binary):
            left, right = self.expr(e.left, lets), self.expr(e.right, lets)
            if left is None or right is None:
                return None
            kinds = (left.kind, right.kind)
            if kinds == ("float", "float"):
                if isinstance(left, ir.Const) and isinstance(right, ir.Const):
                    return ir.Const(_fold(e.op, left.value, right.value), e.pos)
                return ir.Arith(e.op, left, right, "float", e.pos)
            # colours and vectors: c +- c, c * number, number * c, c / number
            for kind in ("color", "vector"):
                if kinds == (kind, kind) and e.op in "+-" \
                        or kinds == (kind, "float") and e.op in "*/" \
                        or kinds == ("float", kind) and e.op == "*":
                    return ir.Arith(e.op, left, right, kind, e.pos)
            hint = "; use dot() or cross()" if kinds == ("vector", "vector") and e.op in "*/" else ""
            self.error(e.pos, f"'{e.op}' cannot combine {_short(left.kind)} and {_short(right.kind)}{hint}")
            return None
        if isinstance(e, A.Compare):
            left, right = self.want(e.left, lets, "float"), self.want(e.right, lets, "float")
            return ir.Compare(e.op, left, right, e.pos)
        if isinstance(e, A.Logic):
            left = self.want(e.left, lets, "bool")
            right = self.want(e.right, lets, "bool") if e.right is not None else None
            return ir.Logic(e.op, left, right, e.pos)
        if isinstance(e, A.Vector):
            if len(e.items) != 3:
                self.error(e.pos, f"a vector has 3 components (x, y, z), not {len(e.items)}")
                for item in e.items:
                    self.expr(item, lets)
                return None
            items = [self.want(item, lets, "float") for item in e.items]
            return ir.MakeVector(items, e.pos) if None not in items else None
        if isinstance(e, A.Field):
            operand = self.expr(e.operand, lets)
            return self.component(operand, e.name, e.pos, e.name_pos, None) if operand is not None else None
        if isinstance(e, A.Call):
            return self.call(e, lets)
        raise AssertionError(f"unknown expression {e!r}")

    def component(self, operand, field: str, pos: A.Pos, field_pos: A.Pos, name: str | None):
        """``operand.field``: a component of a vector (``name``: the let it is read from)."""
        what = f"'{name}'" if name else "this"
        if operand.kind != "vector":
            self.error(pos, f"{what} is {_short(operand.kind)} and has no fields; only a vector has "
                       "components (.x, .y, .z)")
            return None
        if field not in VECTOR_COMPONENTS:
            self.error(field_pos, f"a vector has the components x, y and z, not '{field}'")
            return None
        return ir.Component(operand, VECTOR_COMPONENTS.index(field), pos)

    def octaves(self, e: A.Expr, lets: dict, fn: str):
        """The constant whole number of octaves of fbm()."""
        value = self.expr(e, lets)
        if value is None:
            return None
        if not isinstance(value, ir.Const) or not (1 <= value.value <= MAX_OCTAVES) \
                or value.value != int(value.value):
            self.error(e.pos, f"the octaves of {fn}() must be a constant whole number from 1 to "
                       f"{MAX_OCTAVES}" + (f", not {value.value:g}" if isinstance(value, ir.Const) else ""))
            return None
        return value

    def scene_input(self, e: A.Call):
        """``mask("file")`` / ``attribute("NAME")``: the surfel's value, kept in
        its row from setup (a read-only Load); in an appearance block a mask is
        sampled at the point instead, like texture()."""
        surface = self.scope.surface.name
        if e.name == "mask":
            key = self.checker.image(e, "mask")
            if key is None:
                return ir.Const(0.0, e.pos)      # reported; the rest is still checked
            self.checker.mask_uses.append((e.pos, self.checker.unit.file, surface, key))
            if self.scope.kind == "appearance":
                textures = self.checker.textures
                index = textures.setdefault(("mask", key), len(textures))
                return ir.Call("mask", [], "float", e.pos, texture=index)
        else:
            arg = e.args[0] if e.args else None
            if not isinstance(arg, A.String) or not arg.value.strip():
                self.error(e.pos, 'attribute() takes a vertex attribute\'s name in quotes: attribute("wetness")')
                return ir.Const(0.0, e.pos)
            key = arg.value.strip()
        text = f'{e.name}("{e.args[0].value}")'
        item = self.checker.input(e.name, key, e.pos, surface, text)
        return ir.Load(ir.Var("surf", item.name, item.slot, text=text), "float", e.pos)

    def call(self, e: A.Call, lets: dict):
        if e.name == "relative":
            self.error(e.pos, "relative() describes a place or length in the scene; "
                       "it is not a value in a rule")
            return None
        fn = FUNCTIONS.get(e.name)
        if fn is None:                 # resolve.bind reported the name; check the arguments
            for a in e.args:
                self.expr(a, lets)
            return None
        n = len(e.args)
        if not fn.accepts(n):
            lo, hi = fn.min_args, fn.max_args
            want = f"{lo}" if lo == hi else f"at least {lo}"
            plural = "s" if (hi or lo) != 1 else ""
            self.error(e.pos, f"{e.name}() takes {want} argument{plural}, not {n}")
            return None
        if fn.appearance_only and self.scope.kind != "appearance":
            self.error(e.pos, f"{e.name}() gives a colour: it belongs in appearance blocks")
            return None
        if e.name == "texture":
            # a colour even when the file is missing, so the rest is still checked
            return ir.Call("texture", [], "color", e.pos, texture=self.checker.texture(e))
        if e.name in ("mask", "attribute"):
            return self.scene_input(e)
        if e.name == "base_color":
            # its slot follows the effect's textures, whose number is known at the end
            call = ir.Call("base_color", [], "color", e.pos)
            self.checker.base_color_calls.append(call)
            return call
        if fn.result == "like-first":  # mix(): of colours or vectors with a number, or of numbers
            first = self.expr(e.args[0], lets)
            if first is not None and first.kind in ("color", "vector"):
                kind = first.kind
                args = [first, self.want(e.args[1], lets, kind), self.want(e.args[2], lets, "float")]
            else:
                if first is not None and first.kind == "bool":
                    self.error(e.args[0].pos, "expected a number here, but this is a truth value")
                args = [first] + [self.want(a, lets, "float") for a in e.args[1:]]
                kind = "float"
        else:
            args = [self.octaves(a, lets, e.name) if fn.arg_kind(i) == "octaves"
                    else self.want(a, lets, fn.arg_kind(i)) for i, a in enumerate(e.args)]
            kind = fn.result
        site = None
        if e.name == "random":
            site, self.sites = self.sites, self.sites + 1
        # typed even when an argument is wrong (reported), so its parent is still checked
        return ir.Call(e.name, args, kind, e.pos, site=site)
