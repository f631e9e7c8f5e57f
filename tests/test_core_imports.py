"""``ramps.core`` does no I/O: a static check of every core module's imports.

How this works: each module under ``src/ramps/core`` is parsed with ``ast``
(nothing is imported or run) and every ``import``/``from ... import`` is
checked against a list of modules that would let the core touch the world:
event loops, threads, sockets, processes, the OS, the wall clock, Zenoh.
The ``random`` module may be imported only for ``random.Random``, the type of
the injected, seeded generator: any other use of the module (``random.random()``,
``random.choice``, ``random.seed``, ``from random import uniform``) reads the
hidden global generator and breaks "same seed, same trace". Dynamic imports
(``__import__``, ``importlib.import_module``) are refused too, so the list
cannot be dodged.

Rules (docs/architecture.md: the core is sans-I/O): a failure names the file
and line of each offence. The checker is itself tested on synthetic sources,
so a broken checker cannot pass silently.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[1] / "src" / "ramps" / "core"

FORBIDDEN = frozenset({
    "asyncio", "threading", "socket", "selectors", "time", "zenoh",
    "subprocess", "multiprocessing", "os",
})
#: the only name of the ``random`` module the core may use
RANDOM_ALLOWED = frozenset({"Random"})
DYNAMIC_IMPORTS = frozenset({"__import__", "import_module"})


def _top(module: str) -> str:
    return module.split(".", 1)[0]


def violations(source: str, filename: str = "<string>") -> list[str]:
    """Every forbidden import or use in ``source``, as 'file:line: why'."""
    tree = ast.parse(source, filename=filename)
    found: list[tuple[int, str]] = []
    random_aliases: set[str] = set()

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                top = _top(alias.name)
                if top in FORBIDDEN:
                    found.append((node.lineno, f"imports forbidden module {alias.name!r}"))
                elif alias.name == "random":
                    random_aliases.add(alias.asname or "random")
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import inside the package
                continue
            top = _top(node.module or "")
            if top in FORBIDDEN:
                found.append((node.lineno, f"imports from forbidden module {node.module!r}"))
            elif node.module == "random":
                for alias in node.names:
                    if alias.name not in RANDOM_ALLOWED:
                        found.append((node.lineno, f"imports random.{alias.name} (module-level "
                                                   "randomness; inject a random.Random instead)"))
        elif isinstance(node, ast.Call):
            fn = node.func
            name = fn.id if isinstance(fn, ast.Name) else fn.attr if isinstance(fn, ast.Attribute) else None
            if name in DYNAMIC_IMPORTS:
                found.append((node.lineno, f"dynamic import via {name}()"))

    if random_aliases:
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in random_aliases and node.attr not in RANDOM_ALLOWED):
                found.append((node.lineno, f"uses module-level {node.value.id}.{node.attr} "
                                           "(inject a seeded random.Random instead)"))
    return [f"{filename}:{line}: {why}" for line, why in sorted(found)]


def core_modules() -> list[Path]:
    return sorted(CORE.rglob("*.py"))


# ------------------------------------------------------------------ the core itself
def test_core_directory_is_found() -> None:
    names = {p.name for p in core_modules()}
    # so a wrong path cannot make every check below pass vacuously
    assert {"node.py", "origin.py", "executor.py", "program.py", "loadview.py"} <= names, names


@pytest.mark.parametrize("path", core_modules(), ids=lambda p: p.name)
def test_core_module_has_no_forbidden_imports(path: Path) -> None:
    bad = violations(path.read_text(encoding="utf-8"), filename=str(path.relative_to(CORE.parents[2])))
    assert not bad, "ramps.core must do no I/O and use no global randomness:\n" + "\n".join(bad)


# ------------------------------------------------------------------ the checker catches offences
@pytest.mark.parametrize("source, needle", [
    ("import time\n", "'time'"),
    ("import os.path\n", "'os.path'"),
    ("from os import path\n", "'os'"),
    ("import asyncio as aio\n", "'asyncio'"),
    ("from threading import Thread\n", "'threading'"),
    ("import socket, json\n", "'socket'"),
    ("import selectors\n", "'selectors'"),
    ("import zenoh\n", "'zenoh'"),
    ("import subprocess\n", "'subprocess'"),
    ("from multiprocessing.pool import Pool\n", "'multiprocessing.pool'"),
    ("import random\nx = random.random()\n", "random.random"),
    ("import random\nx = random.choice([1, 2])\n", "random.choice"),
    ("import random\nx = random.uniform(0, 1)\n", "random.uniform"),
    ("import random\nrandom.seed(3)\n", "random.seed"),
    ("import random as r\nx = r.randint(1, 6)\n", "r.randint"),
    ("import random\npick = random.choice\n", "random.choice"),
    ("from random import uniform\n", "random.uniform"),
    ("def f():\n    import time\n    return time.monotonic()\n", "'time'"),
    ("m = __import__('socket')\n", "__import__"),
    ("import importlib\nm = importlib.import_module('os')\n", "import_module"),
])
def test_checker_catches(source: str, needle: str) -> None:
    bad = violations(source, filename="synthetic.py")
    assert bad, f"checker missed a forbidden use in:\n{source}"
    assert any(needle in b for b in bad), bad
    assert all(b.startswith("synthetic.py:") for b in bad)


def test_checker_names_the_line() -> None:
    source = "from __future__ import annotations\n\nimport json\nimport time\n"
    assert violations(source, "m.py") == ["m.py:4: imports forbidden module 'time'"]


@pytest.mark.parametrize("source", [
    "import random\n\ndef f(rng: random.Random) -> float:\n    return rng.random()\n",
    "import random\nrng = random.Random(7)\nx = rng.choice([1, 2])\n",
    "from random import Random\nrng = Random(0)\n",
    "import heapq, math\nfrom collections import deque\nimport msgspec\n",
    "from .events import Note\n",
    # modules are matched by their whole top-level name, not by prefix
    "import timezones_table\nimport osmosis\n",
])
def test_checker_allows(source: str) -> None:
    assert violations(source) == []
