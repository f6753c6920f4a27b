"""AST of a .gamma file: plain dataclasses, every node with its source position.

The parser (``parser.py``) builds these; name resolution (``resolve.py``) and
the checker (``checker.py``) read them and produce the IR (``gamma.ir``).
Nothing after the front end reads the AST (``gammac emit --ast`` prints it).
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Pos:
    """A source span on one line: 1-based line and column, and its width."""

    line: int
    col: int
    width: int = 1


# ---- expressions ------------------------------------------------------------

@dataclass
class Number:
    value: float
    pos: Pos


@dataclass
class Ref:
    """A dotted name: ``iteration``, ``t.patina``, ``s.reflectance.straight``."""

    parts: list[str]
    pos: Pos
    part_pos: list[Pos] = field(default_factory=list)


@dataclass
class Unary:
    op: str  # '-'
    operand: "Expr"
    pos: Pos


@dataclass
class Binary:
    op: str  # '+', '-', '*', '/'
    left: "Expr"
    right: "Expr"
    pos: Pos


@dataclass
class Call:
    name: str
    args: list["Expr"]
    pos: Pos


@dataclass
class Vector:
    """``(a, b, c)``: a point or direction of a source, or a vector value in a rule."""

    items: list["Expr"]
    pos: Pos


@dataclass
class Field:
    """``EXPR.x``: a component of a vector that is not a name (``cross(a, b).x``, ``(a + b).y``);
    ``position.x`` and ``v.x`` are ``Ref``."""

    operand: "Expr"
    name: str
    pos: Pos
    name_pos: Pos


@dataclass
class String:
    """A string literal: only the argument of ``texture("file.png")``."""

    value: str
    pos: Pos


@dataclass
class Compare:
    op: str  # '<', '<=', '>', '>=', '==', '!='
    left: "Expr"
    right: "Expr"
    pos: Pos


@dataclass
class Logic:
    op: str  # 'and', 'or', 'not' (right is None for 'not')
    left: "Expr"
    right: "Expr | None"
    pos: Pos


Expr = Number | Ref | Unary | Binary | Call | Vector | Field | Compare | Logic | String


# ---- statements and declarations -------------------------------------------

@dataclass
class Assign:
    target: Ref
    op: str  # '=', '+=', '-=', '*='
    value: Expr
    pos: Pos  # of the operator


@dataclass
class Let:
    """``let name = value``: an immutable local, visible to the end of its block."""

    name: str
    value: Expr
    pos: Pos


@dataclass
class If:
    cond: Expr
    then: list["Stmt"]
    otherwise: list["Stmt"]
    pos: Pos


Stmt = Assign | Let | If


@dataclass
class Init:
    name: str
    value: Expr
    pos: Pos


@dataclass
class TonDecl:
    name: str
    pos: Pos
    motion: list[Init] = field(default_factory=list)
    carry: list[Init] = field(default_factory=list)
    bounce: Expr | None = None
    step: Expr | None = None
    drip: Expr | None = None        # drip angle, degrees
    repeated: list[tuple[str, Expr]] = field(default_factory=list)  # 2nd 'bounce'/'step'/'drip'


@dataclass
class SurfaceDecl:
    name: str
    pos: Pos
    reflectance: list[Init] = field(default_factory=list)
    properties: list[Init] = field(default_factory=list)
    shape: list[Init] = field(default_factory=list)   # property = metres per unit (SPEC §19)


@dataclass
class SourceArg:
    name: str | None      # None for a positional argument
    value: Expr
    pos: Pos


@dataclass
class SourceDecl:
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


@dataclass
class Param:
    name: str
    type_name: str        # a declared name, or '*' (every ton type / every surface)
    pos: Pos
    type_pos: Pos


@dataclass
class RuleDecl:
    """``on EVENT(t: Ton, s: Surface) { ... }``"""

    event: str
    event_pos: Pos
    ton: Param
    surface: Param
    body: list[Stmt]
    pos: Pos


@dataclass
class UpdateDecl:
    """``update(s: Surface) { ... }``"""

    surface: Param
    body: list[Stmt]
    pos: Pos


@dataclass
class AppearanceDecl:
    """``appearance(s: Surface) { color = ... }``: how a surface looks."""

    surface: Param
    body: list[Stmt]
    pos: Pos


@dataclass
class ParamDecl:
    """``param rate = 0.015``: a constant an importer or the command line may override."""

    name: str
    value: Expr
    pos: Pos


@dataclass
class ImportDecl:
    """``import "rust.gamma" (rate = 0.03)``"""

    path: str
    pos: Pos
    args: list[Init]


@dataclass
class AssignDecl:
    """``assign "chain*" = Iron``: scene parts matching the pattern are Iron."""

    pattern: str
    surface: str
    pos: Pos
    surface_pos: Pos


Decl = (TonDecl | SurfaceDecl | SourceDecl | RuleDecl | UpdateDecl | ParamDecl | ImportDecl
        | AssignDecl | AppearanceDecl)


@dataclass
class Module:
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
