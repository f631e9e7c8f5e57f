"""The layers of ``ramps``: no import runs back up, and no import circle.

How this works: every module under ``src/ramps`` is parsed with ``ast``
(nothing is imported or run) and each import of a ramps module becomes an
arrow from the importer to the module it names: ``from ramps.runtime import
worker`` is an arrow to ``ramps.runtime.worker``, ``from ramps import
__version__`` one to the package ``ramps``. Imports at module level, inside
functions and under ``TYPE_CHECKING`` all count, and so does a literal
``__import__("ramps.x")`` or ``importlib.import_module("ramps.x")``; the
parent packages Python imports on the way are not arrows, nor are the
``"module:function"`` targets of the registry (data, resolved when a program
runs). ``LAYERS`` is the order, ground first, drawn the same in
docs/architecture.md ("Layers"). A module may import modules of its own
package and of lower layers; packages that share a layer do not import each
other. Two checks on that graph:

- no circle: no module reaches itself through its imports (each strongly
  connected component of the graph is one module);
- no arrow back up: none from a lower layer to a higher one, nor between
  packages of one layer.

No import is exempt. The checker itself is tested on small synthetic graphs,
so a broken checker cannot pass silently.
"""

from __future__ import annotations

import ast
import gc
import re
from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
#: files in the package that are no modules of it: the ROS action type's
#: sources (``ramps ros --build-interfaces``) and a ROS launch file
SKIP = ("ramps.ros.interfaces", "ramps.ros.launch")

#: the layers, ground first: a module imports only its own package and lower
#: layers (docs/architecture.md draws the same, top first)
LAYERS: tuple[tuple[str, ...], ...] = (
    ("ramps.errors", "ramps.version"),
    ("ramps.core", "ramps.extras"),
    ("ramps.sim", "ramps.runtime"),
    ("ramps",),
    ("ramps.programs", "ramps.testing", "ramps.ros"),
    ("ramps.experiments",),
    ("ramps.observe",),
    ("ramps.bench", "ramps.testbed"),
    ("ramps.lab",),
    ("ramps.cli",),
)

Graph = dict[str, dict[str, int]]  # module -> {imported module: line of the first such import}


# ------------------------------------------------------------------ the graph
def module_name(path: Path, src: Path = SRC) -> str:
    parts = list(path.relative_to(src).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def statements(body: list) -> Iterator[ast.AST]:
    """Every statement of ``body`` and of the blocks inside it (functions,
    classes, ``if``, ``try``, ``with``, loops, ``match``): where imports are.
    Faster than ``ast.walk``, which visits every expression too."""
    for node in body:
        yield node
        for block in ("body", "orelse", "finalbody", "handlers", "cases"):
            inner = getattr(node, block, None)
            if inner:
                yield from statements(inner)


def imported_names(text: str, module: str, is_package: bool) -> list[tuple[str, int]]:
    """(dotted name, line) of every import in the source ``text``: each name a
    ``from`` import takes is given as ``package.name`` (a module, or not: see
    ``owner``)."""
    tree = ast.parse(text)
    package = module if is_package else module.rpartition(".")[0]
    found: list[tuple[str, int]] = []
    for node in statements(tree.body):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([base] if base else []))
            found += [(f"{base}.{alias.name}", node.lineno) for alias in node.names]
    if "__import__" in text or "import_module" in text:  # an expression: only here the whole tree
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                    and isinstance(node.args[0].value, str):
                fn = node.func
                name = fn.id if isinstance(fn, ast.Name) else fn.attr if isinstance(fn, ast.Attribute) else ""
                if name in ("__import__", "import_module"):
                    found.append((node.args[0].value, node.lineno))
    return found


def owner(name: str, modules: set[str]) -> str | None:
    """The module that ``name`` is, or that defines it (its longest prefix that is a module)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def build_graph(sources: dict[str, tuple[str, bool]]) -> Graph:
    """``sources``: module -> (its source, whether it is a package's ``__init__``)."""
    modules = set(sources)
    graph: Graph = {}
    for module, (text, is_package) in sources.items():
        arrows = graph.setdefault(module, {})
        for name, line in imported_names(text, module, is_package):
            target = owner(name, modules)
            if target is not None and target != module:
                arrows[target] = min(line, arrows.get(target, line))
    return graph


@lru_cache(maxsize=1)
def ramps_graph() -> Graph:
    sources = {}
    for path in sorted((SRC / "ramps").rglob("*.py")):
        name = module_name(path)
        if not name.startswith(SKIP):
            sources[name] = (path.read_text(encoding="utf-8"), path.name == "__init__.py")
    collecting = gc.isenabled()
    gc.disable()  # syntax trees hold no cycles: collecting among them would only cost time (a third)
    try:
        return build_graph(sources)
    finally:
        if collecting:
            gc.enable()


# ------------------------------------------------------------------ the checks
def layer_of(module: str, layers: tuple[tuple[str, ...], ...] = LAYERS) -> tuple[int, str] | None:
    """(layer, the package or module of ``LAYERS`` that holds ``module``); the
    root package's entry holds only the root package itself."""
    best: tuple[int, str] | None = None
    for i, layer in enumerate(layers):
        for entry in layer:
            if module == entry or ("." in entry and module.startswith(entry + ".")):
                if best is None or len(entry) > len(best[1]):
                    best = (i, entry)
    return best


def circles(graph: Graph) -> list[list[str]]:
    """Every set of modules that import each other in a loop (Tarjan's
    strongly connected components of more than one module), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
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
    return sorted(found)


def upward(graph: Graph, layers: tuple[tuple[str, ...], ...] = LAYERS) -> list[str]:
    """Every arrow from a lower layer to a higher one or across one layer, as
    'importer -> imported (line N): why'."""
    bad = []
    for module, arrows in sorted(graph.items()):
        here = layer_of(module, layers)
        for target, line in sorted(arrows.items()):
            there = layer_of(target, layers)
            if here is None or there is None or here[1] == there[1] or there[0] < here[0]:
                continue
            how = "stands above" if there[0] > here[0] else "shares a layer with"
            bad.append(f"{module} -> {target} (line {line}): {there[1]} {how} {here[1]}")
    return bad


def describe(graph: Graph, component: list[str]) -> str:
    inside = set(component)
    return "\n".join(f"  {m} -> {t} (line {line})" for m in component
                     for t, line in sorted(graph[m].items()) if t in inside)


# ------------------------------------------------------------------ ramps itself
def test_the_graph_is_read() -> None:
    graph = ramps_graph()
    # so a wrong path or a broken reader cannot make the checks pass vacuously
    assert len(graph) > 100
    assert "ramps.core.origin" in graph["ramps.core.node"]  # at module level
    assert "ramps.runtime.running" in graph["ramps"]  # in a function (ramps.progress)
    assert "ramps.runtime.settings" in graph["ramps.runtime.transport"]  # under TYPE_CHECKING


def test_every_module_has_a_layer_and_every_entry_a_module() -> None:
    graph = ramps_graph()
    homeless = [m for m in sorted(graph) if layer_of(m) is None]
    assert not homeless, f"modules outside every layer (add their package to LAYERS): {homeless}"
    entries = [entry for layer in LAYERS for entry in layer]
    stale = [e for e in entries if e not in graph]
    assert not stale, f"LAYERS names what is no module or package of ramps: {stale}"
    assert len(entries) == len(set(entries))


def test_no_import_circle() -> None:
    graph = ramps_graph()
    found = circles(graph)
    assert not found, "modules that import each other in a loop:\n" + "\n\n".join(
        describe(graph, c) for c in found)


def test_no_import_runs_back_up() -> None:
    bad = upward(ramps_graph())
    assert not bad, "imports against the layers (docs/architecture.md, Layers):\n" + "\n".join(bad)


def test_the_architecture_page_draws_the_same_layers() -> None:
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = re.search(r"^## Layers\n.*?^```text\n(.*?)^```", text, re.S | re.M)
    assert block, "docs/architecture.md has no Layers section with a text block"
    drawn = []
    for row in block.group(1).splitlines():
        names = re.split(r"\s{2,}", row.strip())[0]
        drawn.append(tuple("ramps" if n == "ramps" else f"ramps.{n}" for n in re.split(r"\s*·\s*", names)))
    assert tuple(reversed(drawn)) == LAYERS


# ------------------------------------------------------------------ the checker itself
def test_a_circle_through_a_function_level_import_is_found() -> None:
    graph = build_graph({
        "p": ("", True),
        "p.a": ("from p.b import x\n", False),
        "p.b": ("def f():\n    from p import c\n", False),
        "p.c": ("import p.a\n", False),
        "p.d": ("from p.a import y\n", False),
    })
    assert circles(graph) == [["p.a", "p.b", "p.c"]]


def test_type_checking_relative_nested_and_literal_dynamic_imports_are_arrows() -> None:
    graph = build_graph({
        "p": ("", True),
        "p.a": ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from p.b import B\n", False),
        "p.b": ("from .a import A\nfrom . import c\n", False),
        "p.c": ("m = __import__('p.a')\n", False),
        "p.d": ("class K:\n    def f(self):\n        try:\n            pass\n        except ImportError:\n"
                "            import p.a as a\n", False),
    })
    assert graph["p.a"] == {"p.b": 3}
    assert graph["p.b"] == {"p.a": 1, "p.c": 2}
    assert graph["p.c"] == {"p.a": 1}
    assert graph["p.d"] == {"p.a": 6}


def test_an_arrow_up_and_one_across_a_layer_are_found() -> None:
    layers = (("p.low",), ("p.mid", "p.side"), ("p.top",))
    graph = build_graph({
        "p": ("", True),
        "p.low": ("import p.top\n", False),
        "p.mid": ("from p.low import x\nfrom p import side\n", False),
        "p.side": ("", False),
        "p.top": ("import p.mid, p.low\n", False),
    })
    bad = upward(graph, layers)
    assert bad == ["p.low -> p.top (line 1): p.top stands above p.low",
                   "p.mid -> p.side (line 2): p.side shares a layer with p.mid"]
    assert layer_of("p", layers) is None and layer_of("p.mid.x", layers) == (1, "p.mid")
