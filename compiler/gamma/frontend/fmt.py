"""The canonical layout of a .gamma file (``gammac fmt``).

``format_source(text)`` parses the file (a syntax error raises the parser's
``GammaError``) and prints it again in one fixed layout:

* 4-space indentation, one item or statement per line, no ``;``;
* exactly one blank line between top-level declarations; inside a block at
  most one blank line, where the author had one or more;
* expressions with single spaces around binary operators and ``=``, ``, ``
  after commas and the fewest parentheses that keep the tree;
* numbers exactly as written (the formatter never changes a value);
* empty blocks as ``{ }``;
* comments kept: a comment on a line of its own stays before the item (or
  the closing ``}``) that follows it, at that item's indentation; a comment
  after code on the same line stays at the end of the output line holding
  that code, two spaces after it.

The layout is printed from lark's parse tree rather than from the AST: the
tree keeps the order of the items of a ``ton``/``surface`` block, the exact
text of every number, and the source span of every item, which is what the
comments are placed by.  Formatting is idempotent and parsing its output
gives the same AST as the input, modulo positions.
"""

from __future__ import annotations

import bisect
import threading
from dataclasses import dataclass, field
from functools import lru_cache

import lark
from lark import Token, Tree

from . import parser as _gamma_parser

INDENT = "    "

_lock = threading.Lock()
_sink: list[Token] = []


@lru_cache(maxsize=1)
def _tree_parser() -> lark.Lark:
    """A second parser from the same grammar that also hands us the comments."""
    return _gamma_parser.parser_from_grammar(
        lexer_callbacks={"COMMENT": _sink.append, "BLOCK_COMMENT": _sink.append})


# ---- expressions --------------------------------------------------------------

# Binding strength of each expression form; atoms bind tightest.
_ATOM = 8
_PREC = {"or_": 1, "and_": 2, "not_": 3, "compare": 4, "add": 5, "sub": 5,
         "mul": 6, "div": 6, "neg": 7}
_BINARY = {"or_": "or", "and_": "and", "add": "+", "sub": "-", "mul": "*", "div": "/"}


def _expr(node, need: int = 0) -> str:
    """``node`` printed, parenthesised when it binds less tightly than ``need``."""
    text, prec = _expr_prec(node)
    return f"({text})" if prec < need else text


def _args(children) -> list:
    return [c for c in children if c is not None]


def _expr_prec(node) -> tuple[str, int]:
    kind = node.data
    c = node.children
    if kind in ("number", "string"):
        return str(c[0]), _ATOM
    if kind == "ref":
        return ".".join(str(t) for t in c), _ATOM
    if kind == "call":
        return f"{c[0]}({', '.join(_expr(a) for a in _args(c[1:]))})", _ATOM
    if kind == "vector":
        return f"({', '.join(_expr(a) for a in c)})", _ATOM
    if kind == "field":   # a name or a number keeps its parentheses: (v).x, not v.x
        operand = _expr(c[0], _ATOM)
        if c[0].data in ("ref", "number"):
            operand = f"({operand})"
        return f"{operand}.{c[1]}", _ATOM
    if kind == "unary":  # unary plus: means nothing, the parser drops it too
        return _expr_prec(c[0])
    prec = _PREC[kind]
    if kind == "neg":
        operand = _expr(c[0], prec)
        return ("- " if operand.startswith("-") else "-") + operand, prec
    if kind == "not_":
        return f"not {_expr(c[0], prec)}", prec
    if kind == "compare":
        # both sides are sums: a comparison inside a comparison needs parentheses
        return f"{_expr(c[0], prec + 1)} {c[1]} {_expr(c[2], prec + 1)}", prec
    # left-associative binary operators: the right operand binds one level tighter
    return f"{_expr(c[0], prec)} {_BINARY[kind]} {_expr(c[1], prec + 1)}", prec


def _init(node) -> str:
    return f"{node.children[0]} = {_expr(node.children[1])}"


def _inits(nodes) -> str:
    return ", ".join(_init(n) for n in nodes)


def _param(node) -> str:
    return f"{node.children[0]}: {node.children[1]}"


# ---- layout: a list of output lines, each knowing the source span it prints ----

@dataclass
class _Comment:
    text: str
    blank: bool          # a blank line before it in the source


@dataclass
class _Line:
    indent: int
    text: str
    start: int           # source span [start, end) of the code this line prints
    end: int
    opens: bool = False  # ends with '{'
    closes: bool = False  # starts with '}'
    top: bool = False    # first line of a top-level declaration
    blank: bool = False  # a blank line before it in the source
    leading: list[_Comment] = field(default_factory=list)
    trailing: list[str] = field(default_factory=list)


class _Layout:
    def __init__(self, text: str):
        self.text = text
        self.code = text      # the source with comments blanked, set by format_source
        self.lines: list[_Line] = []

    def line(self, indent, text, start, end, *, opens=False, closes=False, top=False):
        self.lines.append(_Line(indent, text, start, end, opens, closes, top))

    def brace_after(self, offset: int) -> int:
        """Offset of the first '{' at or after ``offset`` (comments skipped)."""
        return self.code.index("{", offset)

    # declarations
    def decl(self, node):
        kind, c, m = node.data, node.children, node.meta
        start, end = m.start_pos, m.end_pos
        if kind == "param_decl":
            self.line(0, f"param {c[0]} = {_expr(c[1])}", start, end, top=True)
        elif kind == "import_decl":
            args = _args(c[1:])
            tail = f" ({_inits(args)})" if args else ""
            self.line(0, f"import {c[0]}{tail}", start, end, top=True)
        elif kind == "assign_decl":
            self.line(0, f"assign {c[0]} = {c[1]}", start, end, top=True)
        elif kind == "source_decl":
            self.line(0, self.source(c), start, end, top=True)
        elif kind in ("ton_decl", "surface_decl"):
            word = "ton" if kind == "ton_decl" else "surface"
            brace = self.brace_after(c[0].end_pos)
            self.line(0, f"{word} {c[0]} {{", start, brace + 1, opens=True, top=True)
            for item in c[1:]:
                self.item(item, 1)
            self.line(0, "}", end - 1, end, closes=True)
        elif kind == "rule_decl":
            event, ton, surface, block = c
            self.line(0, f"on {event}({_param(ton)}, {_param(surface)}) {{",
                      start, block.meta.start_pos + 1, opens=True, top=True)
            self.block_rest(block, 0)
        elif kind in ("update_decl", "appearance_decl"):
            surface, block = c
            word = "update" if kind == "update_decl" else "appearance"
            self.line(0, f"{word}({_param(surface)}) {{", start, block.meta.start_pos + 1,
                      opens=True, top=True)
            self.block_rest(block, 0)
        else:  # pragma: no cover - the grammar has no other declaration
            raise AssertionError(f"unknown declaration {kind}")

    def source(self, c) -> str:
        name, kind = c[0], c[1]
        rest = list(c[2:])
        args = []
        while rest and (rest[0] is None or isinstance(rest[0], Tree)):
            args.append(rest.pop(0))
        ton, count, windows = rest[0], rest[1], rest[2:]
        shown = []
        for a in _args(args):
            if a.data == "named_arg":
                shown.append(f"{a.children[0]} = {_expr(a.children[1])}")
            else:
                shown.append(_expr(a.children[0]))
        text = f"source {name} = {kind}({', '.join(shown)}) emits {ton} count {_expr(count)}"
        for w in windows:
            word = {"window_from": "from", "window_until": "until", "window_strength": "strength"}[w.data]
            text += f" {word} {_expr(w.children[0])}"
        return text

    def item(self, node, indent):
        """One item of a ton or surface block."""
        word = node.data  # motion, carry, bounce, step, drip, reflectance, property
        value = node.children[0]
        shown = _inits(value.children) if isinstance(value, Tree) and value.data == "init_list" \
            else _expr(value)
        self.line(indent, f"{word} {shown}", node.meta.start_pos, node.meta.end_pos)

    # statements
    def block_rest(self, block, indent):
        """The statements of ``block`` and its closing '}' (the '{' is already printed)."""
        for stmt in block.children:
            self.stmt(stmt, indent + 1)
        self.line(indent, "}", block.meta.end_pos - 1, block.meta.end_pos, closes=True)

    def stmt(self, node, indent):
        kind, c, m = node.data, node.children, node.meta
        if kind == "stmt":
            target = ".".join(str(t) for t in c[0].children)
            self.line(indent, f"{target} {c[1]} {_expr(c[2])}", m.start_pos, m.end_pos)
        elif kind == "let_stmt":
            self.line(indent, f"let {c[0]} = {_expr(c[1])}", m.start_pos, m.end_pos)
        elif kind == "if_stmt":
            cond, block, rest = _if_parts(node)
            self.line(indent, f"if {_expr(cond)} {{", m.start_pos, block.meta.start_pos + 1,
                      opens=True)
            while True:
                for stmt in block.children:
                    self.stmt(stmt, indent + 1)
                close = block.meta.end_pos - 1
                if rest is None:
                    self.line(indent, "}", close, close + 1, closes=True)
                    return
                if rest.data == "block":
                    self.line(indent, "} else {", close, rest.meta.start_pos + 1,
                              opens=True, closes=True)
                    block, rest = rest, None
                else:  # if_chain
                    cond, nblock, nrest = _if_parts(rest)
                    self.line(indent, f"}} else if {_expr(cond)} {{", close,
                              nblock.meta.start_pos + 1, opens=True, closes=True)
                    block, rest = nblock, nrest
        else:  # pragma: no cover
            raise AssertionError(f"unknown statement {kind}")


def _if_parts(node):
    c = node.children
    return c[0], c[1], (c[2] if len(c) > 2 else None)


# ---- comments -----------------------------------------------------------------

def _blank_before(text: str, offset: int) -> bool:
    """Whether a blank line separates ``offset`` from the code or comment before it."""
    i = offset
    newlines = 0
    while i > 0 and text[i - 1] in " \t\r\n\f\v":
        i -= 1
        if text[i] == "\n":
            newlines += 1
    return i > 0 and newlines >= 2


def _attach(layout: _Layout, comments: list[Token]) -> list[_Comment]:
    """Give each comment to a line (leading or trailing); return those after all code."""
    text, lines = layout.text, layout.lines
    starts = [ln.start for ln in lines]
    ends = [ln.end for ln in lines]
    # the source with comments blanked out entirely (newlines too): a line break
    # inside a block comment does not make the comment after it an own-line one
    flat = list(layout.code)
    for tok in comments:
        for i in range(tok.start_pos, tok.end_pos):
            flat[i] = " "
    flat = "".join(flat)
    after_all: list[_Comment] = []
    for tok in comments:
        body = str(tok).rstrip() if tok.type == "COMMENT" else str(tok)
        line_start = flat.rfind("\n", 0, tok.start_pos) + 1
        if flat[line_start:tok.start_pos].strip():
            # after code on its line: stays at the end of the line printing that code
            prev = len(flat[:tok.start_pos].rstrip()) - 1
            at = max(0, bisect.bisect_right(starts, prev) - 1)
            lines[at].trailing.append(body)
            continue
        comment = _Comment(body, _blank_before(text, tok.start_pos))
        rest = flat[tok.end_pos:]
        stripped = rest.lstrip()
        if not stripped or not lines:
            after_all.append(comment)
            continue
        nxt = tok.end_pos + len(rest) - len(stripped)
        at = min(bisect.bisect_right(ends, nxt), len(lines) - 1)
        lines[at].leading.append(comment)
    return after_all


def _merge_empty_blocks(lines: list[_Line]) -> list[_Line]:
    """``X {`` directly followed by ``}...`` (nothing between) becomes ``X { }...``."""
    out: list[_Line] = []
    for ln in lines:
        if out and out[-1].opens and ln.closes and not ln.leading:
            head = out[-1]
            head.text = f"{head.text} {ln.text}"
            head.end = ln.end
            head.opens = ln.opens
            head.trailing.extend(ln.trailing)
        else:
            out.append(ln)
    return out


def _render_comment(indent: int, text: str) -> str:
    # a block comment spanning lines: re-indent its first line only, keep the rest
    return INDENT * indent + text


def _render(lines: list[_Line], after_all: list[_Comment]) -> str:
    out: list[str] = []
    prev_opens = False

    def put(text: str, blank: bool):
        if out and blank and not prev_opens:
            out.append("")
        out.append(text)

    for ln in lines:
        comment_indent = ln.indent + 1 if ln.closes else ln.indent
        first = True
        for com in ln.leading:
            put(_render_comment(comment_indent, com.text), com.blank or (ln.top and first))
            prev_opens = False
            first = False
        code = INDENT * ln.indent + ln.text
        if ln.trailing:
            code += "  " + "  ".join(ln.trailing)
        blank = False if ln.closes else (ln.blank or (ln.top and first))
        put(code, blank)
        prev_opens = ln.opens
    for com in after_all:
        put(_render_comment(0, com.text), com.blank)
        prev_opens = False
    return "\n".join(out) + "\n" if out else ""


# ---- entry point --------------------------------------------------------------

def format_source(text: str, path: str = "<input>") -> str:
    """The canonical layout of a .gamma file; raises GammaError on a syntax error."""
    text = text.replace("\r\n", "\n").removeprefix("\ufeff")   # a byte-order mark is not kept
    _gamma_parser.parse(text, path)  # syntax errors, reported as the compiler reports them
    with _lock:
        _sink.clear()
        tree = _tree_parser().parse(text)
        comments = sorted(_sink, key=lambda t: t.start_pos)
        _sink.clear()
    layout = _Layout(text)
    code = list(text)
    for tok in comments:
        for i in range(tok.start_pos, tok.end_pos):
            if code[i] != "\n":
                code[i] = " "
    layout.code = "".join(code)
    try:
        for decl in tree.children:
            layout.decl(decl)
    except RecursionError:
        raise _gamma_parser.too_deep(path, text) from None
    for ln in layout.lines:
        ln.blank = _blank_before(text, ln.start)
    after_all = _attach(layout, comments)
    return _render(_merge_empty_blocks(layout.lines), after_all)
