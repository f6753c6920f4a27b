"""Parse .gamma source text into the AST (``ast.py``).

The grammar is ``language/gamma.lark`` (installed next to this module as
``gamma.lark``).  lark's LALR parser stops at the first syntax error; to report
every syntax error of a file we blank out the declaration that failed (keeping
line breaks so positions stay true) and parse again.
"""

from __future__ import annotations

import os
import re
from functools import lru_cache
from pathlib import Path

import lark
from lark import Token, Transformer, v_args

from . import ast as A
from . import lalr_tables
from .diagnostics import Diagnostic, GammaError, Report

_DECL_START = re.compile(r"^[ \t]*(ton|surface|source|on|update|param|import|assign|appearance)\b", re.MULTILINE)


def grammar_path() -> Path:
    package = Path(__file__).resolve().parent.parent   # installed: gamma/gamma.lark
    for candidate in (package / "gamma.lark", package.parent.parent / "language" / "gamma.lark"):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError("gamma.lark not found next to the compiler or in language/")


@lru_cache(maxsize=1)
def _parser() -> lark.Lark:
    return parser_from_grammar()


def parser_from_grammar(**extra) -> lark.Lark:
    """gammac's LALR parser: from the tables built with the package when they
    match the grammar (``lalr_tables``), else by analysing the grammar, with
    lark's own cache of the analysis unless GAMMA_CACHE_DIR=off."""
    grammar = grammar_path()
    text = grammar.read_text(encoding="utf-8")
    prebuilt = lalr_tables.load(grammar.with_name(lalr_tables.TABLES_NAME), text, **extra)
    if prebuilt is not None:
        return prebuilt
    return lalr_tables.build(text, cache=os.environ.get("GAMMA_CACHE_DIR") != "off", **extra)


def _pos(tok) -> A.Pos:
    return A.Pos(tok.line, tok.column, max(1, len(str(tok))))


def _meta_pos(meta) -> A.Pos:
    width = meta.end_column - meta.column if meta.end_line == meta.line else 1
    return A.Pos(meta.line, meta.column, max(1, width))


@v_args(meta=True)
class _ToAst(Transformer):
    # expressions
    def number(self, meta, c):
        return A.Number(float(c[0]), _pos(c[0]))

    def ref(self, meta, c):
        return A.Ref([str(t) for t in c], _meta_pos(meta), [_pos(t) for t in c])

    def call(self, meta, c):
        args = [a for a in c[1:] if a is not None]
        return A.Call(str(c[0]), args, _pos(c[0]))

    def _bin(op):
        def build(self, meta, c):
            return A.Binary(op, c[0], c[1], _meta_pos(meta))
        return build

    add, sub, mul, div = _bin("+"), _bin("-"), _bin("*"), _bin("/")

    def vector(self, meta, c):
        return A.Vector(list(c), _meta_pos(meta))

    def field(self, meta, c):
        return A.Field(c[0], str(c[1]), _meta_pos(meta), _pos(c[1]))

    def compare(self, meta, c):
        return A.Compare(str(c[1]), c[0], c[2], _meta_pos(meta))

    def and_(self, meta, c):
        return A.Logic("and", c[0], c[1], _meta_pos(meta))

    def or_(self, meta, c):
        return A.Logic("or", c[0], c[1], _meta_pos(meta))

    def not_(self, meta, c):
        return A.Logic("not", c[0], None, _meta_pos(meta))

    def let_stmt(self, meta, c):
        return A.Let(str(c[0]), c[1], _pos(c[0]))

    def if_stmt(self, meta, c):
        cond, then = c[0], c[1]
        other = c[2] if len(c) > 2 and c[2] is not None else []
        if isinstance(other, A.If):
            other = [other]
        return A.If(cond, then, other, _meta_pos(meta))

    if_chain = if_stmt

    def neg(self, meta, c):
        return A.Unary("-", c[0], _meta_pos(meta))

    def unary(self, meta, c):  # unary plus
        return c[0]

    # statements
    def target(self, meta, c):
        return A.Ref([str(t) for t in c], _meta_pos(meta), [_pos(t) for t in c])

    def stmt(self, meta, c):
        return A.Assign(c[0], str(c[1]), c[2], _pos(c[1]))

    def block(self, meta, c):
        return list(c)

    def param(self, meta, c):
        return A.Param(str(c[0]), str(c[1]), _pos(c[0]), _pos(c[1]))

    # declarations
    def init(self, meta, c):
        return A.Init(str(c[0]), c[1], _pos(c[0]))

    def init_list(self, meta, c):
        return list(c)

    def motion(self, meta, c):
        return ("motion", c[0])

    def carry(self, meta, c):
        return ("carry", c[0])

    def bounce(self, meta, c):
        return ("bounce", c[0])

    def step(self, meta, c):
        return ("step", c[0])

    def drip(self, meta, c):
        return ("drip", c[0])

    def reflectance(self, meta, c):
        return ("reflectance", c[0])

    def property(self, meta, c):
        return ("properties", c[0])

    def shape(self, meta, c):
        return ("shape", c[0])

    def param_decl(self, meta, c):
        return A.ParamDecl(str(c[0]), c[1], _pos(c[0]))

    def import_decl(self, meta, c):
        path = c[0]
        args = [a for a in c[1:] if a is not None]
        return A.ImportDecl(str(path)[1:-1], _pos(path), args)

    def assign_decl(self, meta, c):
        return A.AssignDecl(str(c[0])[1:-1], str(c[1]), _pos(c[0]), _pos(c[1]))

    def ton_decl(self, meta, c):
        decl = A.TonDecl(str(c[0]), _pos(c[0]))
        for key, value in c[1:]:
            if key in ("motion", "carry"):
                getattr(decl, key).extend(value)
            elif getattr(decl, key) is None:
                setattr(decl, key, value)
            else:
                decl.repeated.append((key, value))
        return decl

    def surface_decl(self, meta, c):
        decl = A.SurfaceDecl(str(c[0]), _pos(c[0]))
        for key, value in c[1:]:
            getattr(decl, key).extend(value)
        return decl

    def source_arg(self, meta, c):
        return A.SourceArg(None, c[0], c[0].pos)

    def named_arg(self, meta, c):
        return A.SourceArg(str(c[0]), c[1], _pos(c[0]))

    def window_from(self, meta, c):
        return ("first", c[0])

    def window_until(self, meta, c):
        return ("last", c[0])

    def window_strength(self, meta, c):
        return ("strength", c[0])

    def source_decl(self, meta, c):
        name, kind = c[0], c[1]
        rest = list(c[2:])
        windows = []
        while rest and isinstance(rest[-1], tuple):
            windows.insert(0, rest.pop())
        ton, count = rest[-2], rest[-1]
        args = [a for a in rest[:-2] if a is not None]
        decl = A.SourceDecl(str(name), _pos(name), str(kind), _pos(kind), args,
                            str(ton), _pos(ton), count)
        for key, expr in windows:
            if getattr(decl, key) is None:
                setattr(decl, key, expr)
            elif key == "strength":
                decl.repeated_strength.append(expr)
            else:
                decl.repeated_window.append(expr)
        return decl

    def rule_decl(self, meta, c):
        event, ton, surf, body = c
        return A.RuleDecl(str(event), _pos(event), ton, surf, body, _meta_pos(meta))

    def appearance_decl(self, meta, c):
        surf, body = c
        return A.AppearanceDecl(surf, body, _meta_pos(meta))

    def string(self, meta, c):
        return A.String(str(c[0])[1:-1], _pos(c[0]))

    def update_decl(self, meta, c):
        surf, body = c
        return A.UpdateDecl(surf, body, _meta_pos(meta))

    def start(self, meta, c):
        return list(c)


#: How deep the syntax tree of a declaration may be.  Every later phase
#: (checker, code generator, interpreter, formatter) walks the tree
#: recursively; this bound keeps them far from Python's recursion limit.  It
#: allows about 75 nested `if` blocks or 150 operators in one expression
#: (parentheses cost nothing), far beyond any hand-written effect (SPEC §1).
MAX_TREE_DEPTH = 160


def _too_deep_at(tree) -> A.Pos | None:
    """Where the tree first exceeds MAX_TREE_DEPTH (found without recursion)."""
    stack = [(tree, 0)]
    while stack:
        node, depth = stack.pop()
        if depth > MAX_TREE_DEPTH:
            meta = node.meta
            return A.Pos(getattr(meta, "line", 1), getattr(meta, "column", 1))
        stack.extend((c, depth + 1) for c in node.children if isinstance(c, lark.Tree))
    return None


def _describe(token: Token) -> str:
    if token.type == "$END":
        return "end of file"
    return f"'{token}'"


def _syntax_diagnostic(err: lark.exceptions.LarkError) -> Diagnostic:
    if isinstance(err, lark.exceptions.UnexpectedToken):
        tok = err.token
        expected = sorted(err.accepts or err.expected)
        names = {"NAME": "a name", "NUMBER": "a number", "STRING": "a string", "ASSIGN_OP": "'=' or '+='",
                 "RBRACE": "'}'", "LBRACE": "'{'", "LPAR": "'('", "RPAR": "')'",
                 "COMMA": "','", "COLON": "':'", "EQUAL": "'='", "SEMICOLON": "';'",
                 "MINUS": "'-'", "PLUS": "'+'", "STAR": "'*'", "SLASH": "'/'", "DOT": "'.'",
                 "$END": "end of file"}
        shown = [names.get(e, f"'{e.lower()}'")
                 for e in expected if not e.startswith("__")]
        hint = f"; expected {', '.join(sorted(set(shown))[:8])}" if shown else ""
        if tok.type == "$END":
            return Diagnostic(A.Pos(err.line if err.line > 0 else 1, max(1, err.column)),
                              f"unexpected end of file{hint}")
        return Diagnostic(_pos(tok), f"syntax error: unexpected {_describe(tok)}{hint}")
    if isinstance(err, lark.exceptions.UnexpectedCharacters):
        return Diagnostic(A.Pos(err.line, err.column),
                          f"syntax error: unexpected character '{err.char}'")
    if isinstance(err, lark.exceptions.UnexpectedEOF):
        return Diagnostic(A.Pos(1, 1), "unexpected end of file")
    return Diagnostic(A.Pos(1, 1), f"syntax error: {err}")


def _offset(text: str, line: int, col: int) -> int:
    lines = text.split("\n")
    return sum(len(l) + 1 for l in lines[: line - 1]) + col - 1


def _blank(text: str, start: int, end: int) -> str:
    return text[:start] + re.sub(r"[^\n]", " ", text[start:end]) + text[end:]


def parse(source: str, path: str = "<input>") -> A.Module:
    """Parse a whole file; raise GammaError with every syntax error found."""
    report = Report()
    # A byte-order mark is not part of the text (editors on Windows write one).
    text = source = source.removeprefix("\ufeff")
    for _ in range(100):
        try:
            tree = _parser().parse(text)
            break
        except lark.exceptions.LarkError as err:
            diag = _syntax_diagnostic(err)
            report.extend([diag])    # kept as found, in order
            at = min(_offset(text, diag.pos.line, diag.pos.col), len(text))
            starts = [m.start(1) for m in _DECL_START.finditer(text)]
            if at in starts:
                # The unexpected token opens the next declaration (e.g. a missing
                # '}'): the broken declaration is the one before it.
                before = [s for s in starts if s < at]
                end = at
            else:
                before = [s for s in starts if s <= at]
                after = [s for s in starts if s > at]
                end = after[0] if after else len(text)
            start = before[-1] if before else 0
            if text[start:end].strip() == "":
                break
            text = _blank(text, start, end)
    else:
        tree = None
    report.raise_errors(path, source)
    deep = _too_deep_at(tree)
    if deep is not None:
        raise too_deep(path, source, deep)
    try:
        decls = _ToAst().transform(tree)
    except RecursionError:
        raise too_deep(path, source) from None
    return A.Module(path, source, decls)


def too_deep(path: str, source: str, pos: A.Pos = A.Pos(1, 1)) -> GammaError:
    return GammaError(path, source, [Diagnostic(pos, "nesting too deep: the compiler accepts "
                                                "about 75 nested blocks or 150 operators in one "
                                                "expression; split it with 'let'")])
