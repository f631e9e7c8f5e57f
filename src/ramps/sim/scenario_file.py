"""Load a ``Scenario`` from a YAML (or TOML) file, with errors that name a line.

How this works: the text is read as UTF-8 and composed by PyYAML's safe loader
into a node tree (which knows each node's line); the tree is checked for
duplicate keys and then constructed into plain dicts, lists and scalars.
``msgspec.convert`` turns that into a ``Scenario`` and ``Scenario.check()``
runs the semantic checks. Both report the field at fault as a path such as
``$.robots[2].cores``; the path is walked down the node tree as far as it
goes and the deepest node's line is reported.

Rules: safe loading only (no Python objects are ever constructed); every
failure is a ``ScenarioFileError`` whose ``str`` is a clickable one-liner
``FILE:LINE: FIELD: MESSAGE``; ``1e3`` is read as a float (YAML 1.2 style)
rather than PyYAML's string. TOML files (``.toml``) load through ``tomllib``
and carry no line numbers for field errors.
"""

from __future__ import annotations

import difflib
import os
import re
import tomllib
from typing import Any

import msgspec
import msgspec.inspect as mi
import yaml

from ramps.sim.scenario import Scenario, ScenarioError

__all__ = ["ScenarioFileError", "load_scenario", "scenario_from_dict"]

_STR_TAG = "tag:yaml.org,2002:str"
_AT = re.compile(r"^(.*?) - at `([^`]*)`(?: in `([^`]*)`)?$", re.S)
_STEP = re.compile(r"\.([A-Za-z_]\w*)|\[(\d+)\]")
#: names people reach for that difflib would not match to the right field
_ALIASES = {
    "cpus": "cores", "cpu": "cores", "ncores": "cores", "threads": "cores",
    "load": "background", "stress": "background", "n": "count", "number": "count",
    "time": "at", "start": "at", "interval": "spacing", "period": "spacing",
    "size": "payload", "params": "payload", "robot": "origin", "host": "origin",
    "fault": "kind", "type": "kind",
}


class ScenarioFileError(Exception):
    """A scenario file that cannot be loaded; ``str()`` is ``file:line: field: message``."""

    def __init__(self, file: str, message: str, *, line: int | None = None, field: str | None = None) -> None:
        self.file = file
        self.line = line
        self.field = field
        self.message = message
        super().__init__(str(self))

    def __str__(self) -> str:
        parts = [self.file] + ([str(self.line)] if self.line is not None else [])
        shown = (self.field or "").removeprefix("$").removeprefix(".")
        return ":".join(parts) + ": " + (f"{shown}: " if shown else "") + self.message


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e3`` / ``-2E-5`` as floats."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def load_scenario(path: str | os.PathLike[str]) -> Scenario:
    """Read, parse, convert and check the scenario in ``path`` (YAML or ``.toml``)."""
    file = os.fspath(path)
    text = _read(file)
    if file.lower().endswith(".toml"):
        return _from_toml(text, file)
    root = _compose(text, file)
    if root is None or (isinstance(root, yaml.ScalarNode) and root.tag == "tag:yaml.org,2002:null"):
        raise ScenarioFileError(file, "the file is empty (expected a mapping with `robots` and `programs`)")
    if not isinstance(root, yaml.MappingNode):
        kind = "a list" if isinstance(root, yaml.SequenceNode) else f"a single value ({root.value!r})"
        raise ScenarioFileError(
            file, f"the document must be a mapping with `robots` and `programs`, got {kind}", line=_line(root)
        )
    _check_duplicates(root, file, set())
    loader = _Loader("")
    try:
        data = loader.construct_document(root)
    except yaml.YAMLError as e:
        raise _yaml_error(e, file) from e
    finally:
        loader.dispose()
    return _convert(data, file, root)


def scenario_from_dict(data: dict[str, Any], source: str = "<dict>") -> Scenario:
    """Convert and check already-parsed data; errors name ``source`` and a field (no line)."""
    if not isinstance(data, dict):
        raise ScenarioFileError(source, f"the scenario must be a mapping, got {type(data).__name__}")
    return _convert(data, source, None)


# -- reading and parsing ------------------------------------------------------


def _read(file: str) -> str:
    try:
        with open(file, "rb") as fh:
            raw = fh.read()
    except FileNotFoundError:
        raise ScenarioFileError(file, "no such file") from None
    except IsADirectoryError:
        raise ScenarioFileError(file, "is a directory, not a scenario file") from None
    except OSError as e:
        raise ScenarioFileError(file, f"cannot read the file: {e.strerror or e}") from e
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ScenarioFileError(file, f"the file is not UTF-8 text (byte {raw[e.start]:#04x})", line=line) from None


def _compose(text: str, file: str) -> yaml.Node | None:
    try:
        return yaml.compose(text, Loader=_Loader)
    except yaml.YAMLError as e:
        raise _yaml_error(e, file) from e


def _yaml_error(e: yaml.YAMLError, file: str) -> ScenarioFileError:
    if isinstance(e, yaml.MarkedYAMLError):
        mark = e.problem_mark or e.context_mark
        what = "; ".join(s for s in (e.context, e.problem) if s) or "invalid YAML"
        return ScenarioFileError(file, f"YAML syntax error: {what}", line=mark.line + 1 if mark else None)
    return ScenarioFileError(file, f"YAML error: {e}")


def _from_toml(text: str, file: str) -> Scenario:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"\(at line (\d+), column \d+\)", str(e))
        msg = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(e))
        raise ScenarioFileError(file, f"TOML syntax error: {msg}", line=int(m.group(1)) if m else None) from e
    if not data:
        raise ScenarioFileError(file, "the file is empty (expected `robots` and `programs`)")
    return _convert(data, file, None)


def _check_duplicates(node: yaml.Node, file: str, seen: set[int]) -> None:
    if id(node) in seen:  # aliases share nodes; recursive anchors would loop
        return
    seen.add(id(node))
    if isinstance(node, yaml.MappingNode):
        keys: dict[Any, int] = {}
        for k, v in node.value:
            if isinstance(k, yaml.ScalarNode) and k.tag != "tag:yaml.org,2002:merge":
                if (k.tag, k.value) in keys:
                    raise ScenarioFileError(
                        file,
                        f"duplicate key `{k.value}` (first given on line {keys[(k.tag, k.value)]})",
                        line=_line(k),
                    )
                keys[(k.tag, k.value)] = _line(k)
            _check_duplicates(v, file, seen)
    elif isinstance(node, yaml.SequenceNode):
        for item in node.value:
            _check_duplicates(item, file, seen)


# -- converting and locating errors --------------------------------------------


def _convert(data: Any, file: str, root: yaml.Node | None) -> Scenario:
    try:
        scenario = msgspec.convert(data, Scenario)
    except msgspec.ValidationError as e:
        raise _validation_error(str(e), file, root) from e
    try:
        return scenario.check()
    except ScenarioError as e:
        raise ScenarioFileError(file, e.message, line=_locate(root, e.path), field=e.path) from e


def _validation_error(text: str, file: str, root: yaml.Node | None) -> ScenarioFileError:
    m = _AT.match(text)
    message, path = (m.group(1), m.group(3) or m.group(2)) if m else (text, "$")
    struct = _struct_at(path)
    unknown = re.fullmatch(r"Object contains unknown field `([^`]*)`", message)
    if unknown:
        name = unknown.group(1)
        message = f"unknown field `{name}`"
        if struct is not None:
            valid = [f.encode_name for f in struct.fields]
            alias = _ALIASES.get(name.lower())
            close = [alias] if alias in valid else difflib.get_close_matches(name, valid, n=1, cutoff=0.6)
            message += f"; did you mean `{close[0]}`?" if close else ""
            message += f" (valid fields: {', '.join(valid)})"
        node = _walk(root, path)[0]
        hit = _lookup(node, name) if isinstance(node, yaml.MappingNode) else None
        line = _line(hit[0]) if hit else _locate(root, path)
        return ScenarioFileError(file, message, line=line, field=f"{path}.{name}")
    if m and m.group(3) and message == "Expected `str`":
        message = "keys must be strings"
        node = _walk(root, path)[0]
        if isinstance(node, yaml.MappingNode):
            bad = next((k for k, _ in node.value if k.tag != _STR_TAG), None)
            if bad is not None:
                got = f", got `{bad.value}`" if isinstance(bad, yaml.ScalarNode) else ""
                return ScenarioFileError(file, message + got, line=_line(bad), field=path)
    elif missing := re.fullmatch(r"Object missing required field `([^`]*)`", message):
        message = f"missing required field `{missing.group(1)}`"
    elif re.fullmatch(r"Expected `str`, got `(bool|int|float|null)`", message):
        message += " (put the value in quotes)"
    elif struct is not None and (word := re.match(r"\w+", message)):
        # errors from a struct's __post_init__ often start with the field name
        if word.group(0) in {f.encode_name for f in struct.fields}:
            path = f"{path}.{word.group(0)}"
    return ScenarioFileError(file, message, line=_locate(root, path), field=path)


def _struct_at(path: str) -> mi.StructType | None:
    """The struct type that the path names within ``Scenario``, if it is one."""
    t: Any = mi.type_info(Scenario)
    for name, index in _STEP.findall(path):
        if isinstance(t, mi.UnionType):
            t = next((u for u in t.types if isinstance(u, (mi.StructType, mi.ListType))), None)
        if index and isinstance(t, mi.ListType):
            t = t.item_type
        elif name and isinstance(t, mi.StructType):
            t = next((f.type for f in t.fields if f.encode_name == name), None)
        else:
            return None
    if isinstance(t, mi.UnionType):
        t = next((u for u in t.types if isinstance(u, mi.StructType)), None)
    return t if isinstance(t, mi.StructType) else None


def _walk(root: yaml.Node | None, path: str) -> tuple[yaml.Node | None, yaml.Node | None]:
    """The deepest node along ``path`` and the key node that led to it (if any)."""
    node, key = root, None
    for name, index in _STEP.findall(path) if root is not None else ():
        if index and isinstance(node, yaml.SequenceNode) and int(index) < len(node.value):
            node, key = node.value[int(index)], None
        elif name and isinstance(node, yaml.MappingNode) and (hit := _lookup(node, name)):
            key, node = hit
        else:
            break
    return node, key


def _lookup(node: yaml.MappingNode, name: str) -> tuple[yaml.Node, yaml.Node] | None:
    # constructing the data flattened `<<: *anchor` merges into this node,
    # merged entries first: the last entry of a name is the one that counts
    for k, v in reversed(node.value):
        if isinstance(k, yaml.ScalarNode) and k.tag == _STR_TAG and k.value == name:
            return k, v
    return None


def _locate(root: yaml.Node | None, path: str) -> int | None:
    """Line of the node at ``path``: the value itself if scalar, else the key naming it."""
    node, key = _walk(root, path)
    if node is None:
        return None
    return _line(key if key is not None and not isinstance(node, yaml.ScalarNode) else node)


def _line(node: yaml.Node) -> int:
    return node.start_mark.line + 1
