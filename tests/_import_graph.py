"""The import graph of the hilbench package, built from its source, and the layer table it is
checked against (docs/architecture.md, "Layers").

Every `import` and `from ... import` in a module counts, wherever it is: at the top, inside a
function (a lazy import) or under `if TYPE_CHECKING:`. ``from hilbench.a import b`` is an edge to
the module ``hilbench.a.b`` when there is one, else to ``hilbench.a``. The implicit import of a
parent package's ``__init__`` is not an edge (every module would then import the API).
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Layer:
    name: str
    paths: tuple[str, ...]  # repository paths: a module file or a package folder ("hilbench/bench/")
    may_import: frozenset[str]


def module_sources(root: Path = ROOT) -> dict[str, str]:
    """{module name: source text} of every module of the hilbench package."""
    out = {}
    for path in sorted((root / "hilbench").rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path.read_text(encoding="utf-8")
    return out


def is_package(name: str, root: Path = ROOT) -> bool:
    return (root / Path(*name.split(".")) / "__init__.py").exists()


def package_of(name: str, root: Path = ROOT) -> str:
    """The package a module belongs to (a package's __init__ belongs to itself)."""
    return name if is_package(name, root) else name.rpartition(".")[0]


def imports_of(name: str, source: str, modules: set[str], root: Path = ROOT) -> set[str]:
    """The hilbench modules ``name`` imports, anywhere in its source."""
    here = package_of(name, root).split(".")
    out = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names if alias.name.split(".")[0] == "hilbench")
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(here[:len(here) - node.level + 1] + ([base] if base else []))
            if base.split(".")[0] != "hilbench":
                continue
            for alias in node.names:
                target = f"{base}.{alias.name}"
                out.add(target if target in modules else base)
    out.discard(name)
    return {m for m in out if m in modules}


def import_graph(sources: dict[str, str], root: Path = ROOT) -> dict[str, set[str]]:
    modules = set(sources)
    return {name: imports_of(name, text, modules, root) for name, text in sources.items()}


def layer_table(doc: Path = ROOT / "docs" / "architecture.md") -> list[Layer]:
    """The rows of the "Layers" table: a layer, its paths (the `hilbench/...` cells) and what it
    may import ("every layer above": all rows before it; "—": none)."""
    text = doc.read_text(encoding="utf-8")
    section = text[text.index("## Layers"):]
    rows = [line for line in section.splitlines() if line.startswith("|")][2:]
    layers: list[Layer] = []
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        name, where, may = cells[0], cells[1], cells[2]
        paths = tuple(p for p in re.findall(r"`([^`]+)`", where) if p.startswith("hilbench"))
        if may.startswith("every layer above"):
            allowed = frozenset(layer.name for layer in layers)
        else:
            allowed = frozenset(x.strip() for x in may.split(",") if x.strip() not in ("", "—"))
        unknown = allowed - {layer.name for layer in layers}
        assert not unknown, f"layer {name!r} may import {sorted(unknown)}: not a layer above it"
        layers.append(Layer(name, paths, allowed))
    return layers


def layer_of(module: str, layers: list[Layer], root: Path = ROOT) -> str | None:
    """The layer whose path holds the module (the longest matching path)."""
    parts = module.split(".")
    file = "/".join(parts) + ("/__init__.py" if is_package(module, root) else ".py")
    best: tuple[int, str] | None = None
    for layer in layers:
        for path in layer.paths:
            if file == path or (path.endswith("/") and file.startswith(path)):
                if best is None or len(path) > best[0]:
                    best = (len(path), layer.name)
    return best[1] if best else None


def upward_imports(graph: dict[str, set[str]], layers: list[Layer], root: Path = ROOT) -> list[str]:
    """Every import from a module to one of a layer it may not import, as 'a (layer) -> b (layer)'."""
    allowed = {layer.name: layer.may_import | {layer.name} for layer in layers}
    out = []
    for module in sorted(graph):
        mine = layer_of(module, layers, root)
        for target in sorted(graph[module]):
            theirs = layer_of(target, layers, root)
            if mine is None or theirs is None:
                out.append(f"{module} ({mine}) -> {target} ({theirs}): a module in no layer of the table")
            elif theirs not in allowed[mine]:
                out.append(f"{module} ({mine}) -> {target} ({theirs})")
    return out


def cross_package_cycles(graph: dict[str, set[str]], root: Path = ROOT) -> list[list[str]]:
    """The strongly connected components that hold modules of more than one package."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:  # Tarjan, recursive (the graph is a few hundred modules deep at most)
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
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
            if len({package_of(m, root) for m in component}) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found
