"""Sizes: no module over 500 lines, no function over 80 without its reason.

How this works: every module under ``src/ramps`` is read with ``ast``
(nothing is imported). A module may have at most ``MODULE_LINES`` lines; a
function (or method) at most ``FUNCTION_LINES``, from its ``def`` to its
last line, unless the first lines of its docstring say why it is long:
they contain "Long because" (docs/architecture.md, "Development"). The
modules and functions still over the limits are listed below with their
size today as a ceiling, so they can only shrink, and a reason each.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "ramps"
MODULE_LINES = 500
FUNCTION_LINES = 80
#: where a long function gives its reason: in the first lines of its docstring
REASON = "Long because"
REASON_WITHIN = 3  # lines of the docstring

#: modules over the limit: path under src/ramps -> (ceiling, why)
KNOWN_MODULES: dict[str, tuple[int, str]] = {}

#: functions over the limit without a reason yet: "path:qualified name" -> (ceiling, why)
KNOWN_FUNCTIONS: dict[str, tuple[int, str]] = {}


def modules() -> list[Path]:
    return sorted(p for p in SRC.rglob("*.py") if "interfaces" not in p.parts)


def functions(tree: ast.AST, prefix: str = "") -> list[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    """(qualified name, node) of every function in ``tree``, methods and nested ones too."""
    out: list[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]] = []
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            out.append((prefix + node.name, node))
            out += functions(node, f"{prefix}{node.name}.")
        elif isinstance(node, ast.ClassDef):
            out += functions(node, f"{prefix}{node.name}.")
        else:
            out += functions(node, prefix)
    return out


def gives_reason(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    doc = ast.get_docstring(fn) or ""
    return REASON in " ".join(doc.splitlines()[:REASON_WITHIN])


def test_no_module_over_the_limit_unless_known_and_no_longer_than_its_ceiling():
    too_long = []
    for path in modules():
        name = path.relative_to(SRC).as_posix()
        lines = len(path.read_text().splitlines())
        ceiling = KNOWN_MODULES.get(name, (MODULE_LINES, ""))[0]
        if lines > max(MODULE_LINES, ceiling) or (name in KNOWN_MODULES and lines > ceiling):
            too_long.append(f"{name}: {lines} lines (at most {max(MODULE_LINES, ceiling)})")
    assert not too_long, "split these modules by concept:\n" + "\n".join(too_long)


def test_no_function_over_the_limit_without_its_reason():
    too_long = []
    for path in modules():
        name = path.relative_to(SRC).as_posix()
        for qual, fn in functions(ast.parse(path.read_text())):
            assert fn.end_lineno is not None
            lines = fn.end_lineno - fn.lineno + 1
            ceiling = KNOWN_FUNCTIONS.get(f"{name}:{qual}", (FUNCTION_LINES, ""))[0]
            if lines > max(FUNCTION_LINES, ceiling) and not gives_reason(fn):
                too_long.append(f"{name}:{fn.lineno} {qual}: {lines} lines")
    assert not too_long, (f"split these into named steps, or say why at the top of the docstring "
                          f"(\"{REASON} ...\"):\n" + "\n".join(too_long))


def test_the_checker_sees_a_long_function_and_its_reason():
    body = "\n".join(f"    x{i} = {i}" for i in range(FUNCTION_LINES))
    bare = ast.parse(f"def f():\n{body}\n")
    told = ast.parse(f'def f():\n    """{REASON} it is a table."""\n{body}\n')
    (_, f_bare), = functions(bare)
    (_, f_told), = functions(told)
    assert f_bare.end_lineno - f_bare.lineno + 1 > FUNCTION_LINES and not gives_reason(f_bare)
    assert gives_reason(f_told)
    nested = ast.parse("class C:\n    def m(self):\n        def inner():\n            pass\n")
    assert [q for q, _ in functions(nested)] == ["C.m", "C.m.inner"]
