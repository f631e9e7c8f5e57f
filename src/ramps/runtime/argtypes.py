"""Program arguments checked against the types the program annotates.

How this works: ``check(fn, kwargs)`` binds ``kwargs`` to ``fn``'s signature
(names: a missing, unexpected or positional-only argument is a TypeError),
then converts each value to its parameter's annotation with msgspec
(``msgspec.convert``, strict): a value that does not fit raises TypeError
naming the argument, the type it expects and what is wrong, for example

    argument 'seed' must be int: Expected `int`, got `str`
    argument 'goals' must be list[tuple[float, float]]: Expected `float`, got `str` - at `goals[1][0]`

Rules, as msgspec decodes: an int is fine where a float is wanted (not a
float for an int, nor a bool for an int); a list is fine for a tuple or a
set, a dict for a Struct, dataclass or TypedDict (arguments travel as
msgpack, which has no tuples or classes, so that is what a node decodes);
``Annotated[int, Meta(ge=0)]`` constraints hold. Anything goes for a
parameter without an annotation, annotated ``Any`` or ``object``, or with a
type msgspec cannot check (a class of its own, a callable, a name that does
not resolve); the program itself is then the judge. A ``**kwargs``
parameter's annotation applies to each extra argument.

The same check runs in a client that has the program's module (the Team
API, before anything is sent: ``registry.encode_args``) and in the origin's
node on every submission (``node_clients``), for clients that cannot
(the ROS face, another language, a client without the module). What a
signature allows is worked out once per function.
"""

from __future__ import annotations

import inspect
import typing
import weakref
from typing import Any, Callable

import msgspec
import msgspec.inspect as mi

_CACHE: "weakref.WeakKeyDictionary[Any, ArgTypes]" = weakref.WeakKeyDictionary()


def check(fn: Callable[..., Any], kwargs: dict[str, Any]) -> None:
    """Raise TypeError unless ``kwargs`` fit ``fn``'s signature and types."""
    prepare(fn).check(kwargs)


def prepare(fn: Callable[..., Any]) -> "ArgTypes":
    """What ``fn``'s signature allows, worked out now if not yet (about 0.3 ms)."""
    types = _CACHE.get(fn) if _weakrefable(fn) else None
    if types is None:
        types = ArgTypes(fn)
        if _weakrefable(fn):
            _CACHE[fn] = types
    return types


def _weakrefable(fn: Any) -> bool:
    try:
        weakref.ref(fn)
        return True
    except TypeError:
        return False


class ArgTypes:
    """What one function's signature allows (see the module's docstring)."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.signature = inspect.signature(fn)
        namespace = getattr(inspect.unwrap(fn), "__globals__", None) or {}
        self.types: dict[str, Any] = {}
        self.extra: Any = None  # the **kwargs parameter's type, if it has one msgspec can check
        named: set[str] = set()
        required: set[str] = set()
        #: positional-only parameters: ``Signature.bind`` judges every call
        self._positional = False
        for p in self.signature.parameters.values():
            tp = _checkable(p.annotation, namespace)
            if p.kind is inspect.Parameter.VAR_KEYWORD:
                self.extra = tp
            elif p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY):
                named.add(p.name)
                if p.default is inspect.Parameter.empty:
                    required.add(p.name)
                if tp is not None:
                    self.types[p.name] = (tp, p.default)
            elif p.kind is inspect.Parameter.POSITIONAL_ONLY:
                self._positional = True
        has_kwargs = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in self.signature.parameters.values())
        #: the names a call may pass (None: any, there is a **kwargs), and those it must
        self._named: frozenset[str] | None = None if has_kwargs else frozenset(named)
        self._required = frozenset(required)

    def check(self, kwargs: dict[str, Any]) -> None:
        # what ``Signature.bind(**kwargs)`` accepts, told from the names alone where it can be (a call
        # of a program without arguments costs a microsecond, not ten); it raises the words otherwise
        if self._positional or not self._required <= kwargs.keys() or (
                self._named is not None and not self._named >= kwargs.keys()):
            self.signature.bind(**kwargs)
        if not kwargs:
            return
        for name, value in kwargs.items():
            entry = self.types.get(name)
            if entry is not None:
                tp, default = entry
                if value is None and default is None:  # ``x: int = None``: its default, passed on
                    continue
            elif self.extra is not None and name not in self.signature.parameters:
                tp = self.extra
            else:
                continue
            try:
                msgspec.convert(value, tp)
            except msgspec.ValidationError as exc:
                detail = str(exc).replace("`$", f"`{name}")
                raise TypeError(f"argument {name!r} must be {type_name(tp)}: {detail}") from None
            except TypeError:  # msgspec cannot check this type after all: the program judges
                continue


def _checkable(annotation: Any, namespace: dict[str, Any]) -> Any:
    """The type to check a parameter against, or None (anything goes)."""
    if annotation is inspect.Parameter.empty:
        return None
    if isinstance(annotation, str):  # ``from __future__ import annotations``
        try:
            annotation = eval(annotation, dict(namespace), {})  # noqa: S307 - the program's own annotation
        except Exception:
            return None
    if annotation is typing.Any or annotation is object:
        return None
    try:
        info = mi.type_info(annotation)
    except Exception:  # a type msgspec does not know at all
        return None
    return None if _custom(info, set()) else annotation


def _custom(t: Any, seen: set[int]) -> bool:
    """Whether a msgspec type holds a class msgspec cannot check (anywhere in it)."""
    if isinstance(t, mi.CustomType):
        return True
    if isinstance(t, mi.Metadata):
        return _custom(t.type, seen)
    fields = getattr(t, "fields", None)
    if fields is not None:  # Struct, dataclass, TypedDict, NamedTuple, attrs: once each (they may recurse)
        if id(t.cls) in seen:
            return False
        seen.add(id(t.cls))
        return any(_custom(f.type, seen) for f in fields)
    for attr in ("item_type", "key_type", "value_type"):
        if hasattr(t, attr) and _custom(getattr(t, attr), seen):
            return True
    return any(_custom(x, seen) for x in getattr(t, "item_types", ()) or getattr(t, "types", ()))


def type_name(tp: Any) -> str:
    """A type as a program's signature would write it: ``int``,
    ``list[tuple[float, float]]`` (``Annotated[int, Meta(ge=0)]`` as ``int``:
    msgspec's words name the constraint)."""
    if typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    return inspect.formatannotation(tp).replace("typing.", "")
