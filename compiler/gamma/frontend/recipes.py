"""The standard library's recipes as ``gammac recipes`` lists them.

A recipe is a ``.gamma`` file in ``stdlib/``.  Its leading ``//`` comment is
its documentation (the first sentence is the summary); its ``param``
declarations, with the ``//`` comment at the end of their line, are its
parameters.  Both are read from the file itself, so the listing cannot drift
from what an import gets.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from . import ast as A

_PARAM_LINE = re.compile(r"^\s*param\s+(\w+)\s*=\s*([^/]*?)\s*(?://\s*(.*))?$")


@dataclass
class RecipeParam:
    name: str
    default: str          # as written in the recipe
    doc: str


@dataclass
class Recipe:
    name: str             # the file name, as imported: "rust.gamma"
    path: Path
    summary: str          # first sentence of the leading comment
    doc: str              # the whole leading comment, without the slashes
    params: list[RecipeParam] = field(default_factory=list)
    tons: list[str] = field(default_factory=list)
    surfaces: list[str] = field(default_factory=list)
    sources: list[str] = field(default_factory=list)


def _leading_comment(text: str) -> str:
    lines = []
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped.startswith("//"):
            break
        lines.append(stripped[2:].removeprefix(" "))
    return "\n".join(lines).strip()


def _summary(doc: str) -> str:
    first_paragraph = " ".join(doc.split("\n\n")[0].split())
    match = re.match(r"(.+?[.!?])(\s+[A-Z(]|$)", first_paragraph)
    return match.group(1) if match else first_paragraph


def read_recipe(path: Path) -> Recipe:
    from .parser import parse

    text = path.read_text(encoding="utf-8")
    doc = _leading_comment(text)
    recipe = Recipe(name=path.name, path=path, summary=_summary(doc), doc=doc)
    for line in text.splitlines():
        match = _PARAM_LINE.match(line)
        if match:
            recipe.params.append(RecipeParam(match.group(1), match.group(2), (match.group(3) or "").strip()))
    for decl in parse(text, str(path)).decls:
        if isinstance(decl, A.TonDecl):
            recipe.tons.append(decl.name)
        elif isinstance(decl, A.SurfaceDecl):
            recipe.surfaces.append(decl.name)
        elif isinstance(decl, A.SourceDecl):
            recipe.sources.append(decl.name)
    return recipe


def stdlib_recipes(folder: Path | None = None) -> list[Recipe]:
    from .checker import stdlib_dir

    folder = folder or stdlib_dir()
    return [read_recipe(p) for p in sorted(folder.glob("*.gamma"))]


def as_json(recipes: list[Recipe]) -> str:
    """The listing for tools (the Blender add-on): every field of every
    recipe, the path absolute, parameters' defaults as written."""
    import json

    return json.dumps([{
        "name": r.name, "path": str(r.path.resolve()), "summary": r.summary, "doc": r.doc,
        "params": [{"name": p.name, "default": p.default, "doc": p.doc} for p in r.params],
        "tons": r.tons, "surfaces": r.surfaces, "sources": r.sources,
    } for r in recipes], indent=1, ensure_ascii=False) + "\n"


def describe(recipes: list[Recipe], verbose: bool = False) -> str:
    """The listing: one paragraph per recipe (name, summary, what it
    declares, parameters with defaults); ``verbose`` adds the whole comment."""
    out = []
    for r in recipes:
        out.append(f"{r.name}  {r.summary}")
        declares = []
        if r.tons:
            declares.append("ton " + ", ".join(r.tons))
        if r.surfaces:
            declares.append("surface " + ", ".join(r.surfaces))
        if r.sources:
            declares.append("source " + ", ".join(r.sources))
        out.append("    declares: " + "; ".join(declares))
        width = max((len(f"{p.name} = {p.default}") for p in r.params), default=0)
        for p in r.params:
            left = f"{p.name} = {p.default}"
            out.append(f"    param {left:<{width}}  {p.doc}".rstrip())
        if verbose and r.doc:
            out.append("")
            out.extend("    " + line if line else "" for line in r.doc.splitlines())
        out.append("")
    out.append(f'{len(recipes)} recipes; use one with: import "NAME.gamma" (PARAM = VALUE, ...)')
    return "\n".join(out) + "\n"
