"""The package's import rules (issue 33, item 3), checked on its source with
``ast``: every import counts, also those inside functions (only ``if
TYPE_CHECKING:`` blocks, which never run, do not).

- no import cycle between gamma's modules;
- the compiler (``frontend``, ``ir``, ``backends``) imports nothing from the
  driver, the viewer, the command line or the API;
- no private name (``_name``) is taken from a module of another package;
- ``import gamma`` imports neither the driver nor the compiler.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SOURCE = Path(__file__).resolve().parent.parent / "compiler" / "gamma"
#: Modules that are not Python source (the C++ runtime).
EXTENSIONS = {"gamma._runtime"}
COMPILER = ("gamma.frontend", "gamma.ir", "gamma.backends")
ABOVE_THE_COMPILER = ("gamma.driver", "gamma.viewer", "gamma.cli", "gamma.api", "gamma.launch")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SOURCE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {module_name(p): p for p in sorted(SOURCE.rglob("*.py"))}


def package_of(name: str) -> str:
    """The package a module belongs to (a package's ``__init__`` to itself)."""
    return name if MODULES.get(name, Path()).name == "__init__.py" else name.rpartition(".")[0]


def _runs(tree: ast.AST):
    """Every node of ``tree`` outside ``if TYPE_CHECKING:`` blocks."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            yield from (n for child in node.orelse for n in [child, *_runs(child)])
            continue
        yield node
        yield from _runs(node)


def imports(name: str) -> list[tuple[str, str | None, int]]:
    """(module imported, name taken from it or None, line) of every gamma
    import in module ``name``."""
    tree = ast.parse(MODULES[name].read_text(encoding="utf-8"))
    package = package_of(name).split(".")
    found = []
    for node in _runs(tree):
        if isinstance(node, ast.Import):
            found += [(a.name, None, node.lineno) for a in node.names if a.name.split(".")[0] == "gamma"]
        elif isinstance(node, ast.ImportFrom):
            source = ".".join(package[:len(package) - node.level + 1] + [node.module or ""]).strip(".") \
                if node.level else node.module
            if source.split(".")[0] != "gamma":
                continue
            for alias in node.names:
                whole = f"{source}.{alias.name}"
                if whole in MODULES or whole in EXTENSIONS:
                    found.append((whole, None, node.lineno))      # a module of a package
                else:
                    found.append((source, alias.name, node.lineno))
    return found


GRAPH = {name: {m for m, _, _ in imports(name) if m in MODULES and m != name} for name in MODULES}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_source_is_found():
    assert {"gamma", "gamma.cli", "gamma.options", "gamma.driver.running.runner", "gamma.frontend.checker"} <= set(MODULES)
    assert "gamma.driver.running.common" in GRAPH["gamma.driver.running.runner"]     # a top-level import
    assert "gamma.driver.outputs.writers" in GRAPH["gamma.driver.running.runner"]    # one inside a function


def test_the_cycle_finder_finds_cycles():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    assert cycles(GRAPH) == []


@pytest.mark.parametrize("name", [n for n in MODULES if n.startswith(COMPILER)])
def test_the_compiler_imports_nothing_above_it(name):
    above = sorted(f"{m} (line {line})" for m, _, line in imports(name)
                   if m.startswith(ABOVE_THE_COMPILER) or m == "gamma")
    assert above == [], f"{name} imports {', '.join(above)}"


def test_no_private_name_is_taken_across_packages():
    taken = []
    for name in MODULES:
        for source, what, line in imports(name):
            if (what and what.startswith("_") and not what.startswith("__")
                    and package_of(source if source in MODULES else name) != package_of(name)):
                taken.append(f"{name}:{line} takes {source}.{what}")
    assert taken == []


def test_importing_gamma_imports_neither_driver_nor_compiler():
    probe = ("import sys, gamma; "
             "print(sorted(m for m in sys.modules if m.startswith(('gamma.driver', 'gamma.frontend', "
             "'gamma.backends', 'gamma.ir', 'gamma.api', 'gamma.cli'))))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
