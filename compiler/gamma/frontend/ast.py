"""AST of a .gamma file: plain dataclasses, every node with its source position.

The parser (``parser.py``) builds these; name resolution (``resolve.py``) and
the checker (``checker.py``) read them and produce the IR (``gamma.ir``).
Nothing after the front end reads the AST (``gammac emit --ast`` prints it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..records import Record, record


@dataclass(frozen=True)
class Pos:
    """A source span on one line: 1-based line and column, and its width."""

    line: int
    col: int
    width: int = 1


# ---- expressions ------------------------------------------------------------

@record
class Number(Record):
    value: float
    pos: Pos


@record
class Ref(Record):
    """A dotted name: ``iteration``, ``t.patina``, ``s.reflectance.straight``."""

    parts: list[str]
    pos: Pos
    part_pos: list[Pos] = field(default_factory=list)


@record
class Unary(Record):
    op: str  # '-'
    operand: "Expr"
    pos: Pos


@record
class Binary(Record):
    op: str  # '+', '-', '*', '/'
    left: "Expr"
    right: "Expr"
    pos: Pos


@record
class Call(Record):
    name: str
    args: list["Expr"]
    pos: Pos


@record
class Vector(Record):
    """``(a, b, c)``: a point or direction of a source, or a vector value in a rule."""

    items: list["Expr"]
    pos: Pos


@record
class Field(Record):
    """``EXPR.x``: a component of a vector that is not a name (``cross(a, b).x``, ``(a + b).y``);
    ``position.x`` and ``v.x`` are ``Ref``."""

    operand: "Expr"
    name: str
    pos: Pos
    name_pos: Pos


@record
class String(Record):
    """A string literal: only the argument of ``texture("file.png")``."""

    value: str
    pos: Pos


@record
class Compare(Record):
    op: str  # '<', '<=', '>', '>=', '==', '!='
    left: "Expr"
    right: "Expr"
    pos: Pos


@record
class Logic(Record):
    op: str  # 'and', 'or', 'not' (right is None for 'not')
    left: "Expr"
    right: "Expr | None"
    pos: Pos


Expr = Number | Ref | Unary | Binary | Call | Vector | Field | Compare | Logic | String


# ---- statements and declarations -------------------------------------------

@record
class Assign(Record):
    target: Ref
    op: str  # '=', '+=', '-=', '*='
    value: Expr
    pos: Pos  # of the operator


@record
class Let(Record):
    """``let name = value``: an immutable local, visible to the end of its block."""

    name: str
    value: Expr
    pos: Pos


@record
class If(Record):
    cond: Expr
    then: list["Stmt"]
    otherwise: list["Stmt"]
    pos: Pos


Stmt = Assign | Let | If


@record
class Init(Record):
    name: str
    value: Expr
    pos: Pos


@record
class TonDecl(Record):
    name: str
    pos: Pos
    motion: list[Init] = field(default_factory=list)
    carry: list[Init] = field(default_factory=list)
    bounce: Expr | None = None
    step: Expr | None = None
    drip: Expr | None = None        # drip angle, degrees
    repeated: list[tuple[str, Expr]] = field(default_factory=list)  # 2nd 'bounce'/'step'/'drip'


@record
class SurfaceDecl(Record):
    name: str
    pos: Pos
    reflectance: list[Init] = field(default_factory=list)
    properties: list[Init] = field(default_factory=list)
    shape: list[Init] = field(default_factory=list)   # property = metres per unit (SPEC §19)


@record
class SourceArg(Record):
    name: str | None      # None for a positional argument
    value: Expr
    pos: Pos


@record
class SourceDecl(Record):
    name: str
    pos: Pos
    kind: str
    kind_pos: Pos
    args: list[SourceArg]
    ton: str
    ton_pos: Pos
    count: Expr
    first: Expr | None = None   # `from N`
    last: Expr | None = None    # `until N`
    repeated_window: list[Expr] = field(default_factory=list)
    strength: Expr | None = None  # `strength S`
    repeated_strength: list[Expr] = field(default_factory=list)


@record
class Param(Record):
    name: str
    type_name: str        # a declared name, or '*' (every ton type / every surface)
    pos: Pos
    type_pos: Pos


@record
class RuleDecl(Record):
    """``on EVENT(t: Ton, s: Surface) { ... }``"""

    event: str
    event_pos: Pos
    ton: Param
    surface: Param
    body: list[Stmt]
    pos: Pos


@record
class UpdateDecl(Record):
    """``update(s: Surface) { ... }``"""

    surface: Param
    body: list[Stmt]
    pos: Pos


@record
class AppearanceDecl(Record):
    """``appearance(s: Surface) { color = ... }``: how a surface looks."""

    surface: Param
    body: list[Stmt]
    pos: Pos


@record
class ParamDecl(Record):
    """``param rate = 0.015``: a constant an importer or the command line may override."""

    name: str
    value: Expr
    pos: Pos


@record
class ImportDecl(Record):
    """``import "rust.gamma" (rate = 0.03)``"""

    path: str
    pos: Pos
    args: list[Init]


@record
class AssignDecl(Record):
    """``assign "chain*" = Iron``: scene parts matching the pattern are Iron."""

    pattern: str
    surface: str
    pos: Pos
    surface_pos: Pos


Decl = (TonDecl | SurfaceDecl | SourceDecl | RuleDecl | UpdateDecl | ParamDecl | ImportDecl
        | AssignDecl | AppearanceDecl)


@record
class Module(Record):
    path: str
    source: str
    decls: list[Decl]


def dump(node, indent: int = 0) -> str:
    """A readable tree of the AST (``gammac emit --ast``), positions as line:col."""
    import dataclasses

    pad = "  " * indent
    if isinstance(node, list):
        if not node:
            return "[]"
        return "\n".join(f"{pad}- {dump(item, indent + 1).lstrip()}" for item in node)
    if not dataclasses.is_dataclass(node) or isinstance(node, Pos):
        return repr(node)
    pos = getattr(node, "pos", None)
    head = type(node).__name__ + (f" @{pos.line}:{pos.col}" if isinstance(pos, Pos) else "")
    lines = [pad + head]
    for f in dataclasses.fields(node):
        if f.name in ("pos", "source") or f.name.endswith("_pos"):
            continue
        value = getattr(node, f.name)
        if isinstance(value, list) and value and dataclasses.is_dataclass(value[0]):
            lines.append(f"{pad}  {f.name}:")
            lines.append(dump(value, indent + 2))
        elif dataclasses.is_dataclass(value):
            lines.append(f"{pad}  {f.name}:")
            lines.append(dump(value, indent + 2))
        else:
            lines.append(f"{pad}  {f.name}: {value!r}")
    return "\n".join(lines)
