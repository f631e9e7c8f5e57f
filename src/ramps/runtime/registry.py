"""Programs: plain Python functions registered by name on every robot.

How this works: weak mobility means code never travels; every robot has the
same programs installed and only arguments and results cross the network. A
program is registered with the ``@ramps.program`` decorator, by a
``module:function`` path (``ramps node --program mypkg.plans:replan``), or by
an entry point in the ``ramps.programs`` group. Each has an optional cost
profile: expected work (work units, about CPU-seconds on a reference core),
payload and result sizes, and ``local_only`` for programs that must never
leave their robot (they touch its hardware).

An executable can be a program too (``ramps node --command NAME=PATH``, or a
``[commands.NAME]`` table in the config file): its target is
``exec:{...}`` and ``ramps.runtime.command`` runs it, arguments as JSON on
stdin, result as JSON on stdout.

Arguments are keyword arguments encoded with msgpack (msgspec); results are
any msgpack-encodable value. Arguments are checked against the function's
signature and the types it annotates (``ramps.runtime.argtypes``) before
anything is sent, so a bad call fails at the caller.
"""

from __future__ import annotations

import bisect
import importlib
import inspect
import math
import traceback
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from collections.abc import Iterable, Mapping
from typing import Any, Callable, Protocol

import msgspec

from ramps.core.accelerators import Accelerator
from ramps.core.messages import MAX_MESSAGE_BYTES
from ramps.runtime import argtypes
from ramps.errors import BadArguments, ConfigError, ProgramNotFound

#: largest encoded arguments a client will send, bytes: they must fit in one
#: wire message (ramps.core.messages.MAX_MESSAGE_BYTES, 8 MiB) with room for
#: the offer around them. A node may accept less (``max_args_bytes``).
MAX_ARGS_BYTES = MAX_MESSAGE_BYTES - 64 * 1024

_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder()


@dataclass
class ProgramSpec:
    name: str
    target: str  # "module:function"
    #: declared work units of one call, or a function of the call's keyword
    #: arguments that returns them (a cost that depends on the arguments)
    work: float | Callable[..., float] = 1.0
    payload: int = 0
    result: int = 0
    local_only: bool = False
    #: bytes of memory one run needs; robots reporting less free memory are skipped
    memory: int = 0
    #: modules the program imports only when it runs (to keep its own module
    #: cheap for callers, which import it to check arguments): the executor's
    #: fork server imports them with the program's module, before it forks a
    #: worker, so no run pays the import
    preload: tuple[str, ...] = ()
    #: the kind of accelerator it can use ("" = none), its work there (work
    #: units at slot speed 1, or a function of the call's arguments; 0 = the
    #: same as ``work``), and whether it may run on a CPU (``ramps.core.accelerators``)
    accelerator: str = ""
    accelerator_work: float | Callable[..., float] = 0.0
    cpu_fallback: bool = True
    _fn: Callable[..., Any] | None = field(default=None, repr=False)

    def declared_work(self, kwargs: dict[str, Any]) -> float:
        """The work one call with these arguments declares: ``work``, or what
        it returns for them when it is a function. BadArguments if that
        function fails on them or returns no finite number >= 0."""
        return self._declared(self.work, "work", kwargs)

    def declared_accelerator_work(self, kwargs: dict[str, Any]) -> float:
        """``declared_work`` of the program's work on its accelerator."""
        return self._declared(self.accelerator_work, "accelerator_work", kwargs)

    def _declared(self, work: float | Callable[..., float], what: str, kwargs: dict[str, Any]) -> float:
        if not callable(work):
            return float(work)
        try:
            value = work(**self._with_defaults(kwargs))
            amount = float(value)
        except Exception as exc:
            raise BadArguments(f"the {what} function of program {self.name!r} failed on these arguments: "
                               f"{type(exc).__name__}: {exc}") from None
        if not (math.isfinite(amount) and amount >= 0.0):
            raise BadArguments(f"the {what} function of program {self.name!r} returned {value!r} for these "
                               "arguments; it must return work units, a finite number >= 0")
        return amount

    def _with_defaults(self, kwargs: dict[str, Any]) -> dict[str, Any]:
        """``kwargs`` and the defaults of the parameters the call left out (a
        work function sees what the program will run with)."""
        try:
            bound = inspect.signature(self.function()).bind_partial(**kwargs)
        except (TypeError, ValueError):  # an executable, or arguments check_args refuses
            return kwargs
        bound.apply_defaults()
        return dict(bound.arguments)

    def function(self) -> Callable[..., Any]:
        if self._fn is None:
            self._fn = resolve(self.target)
        return self._fn

    def check_args(self, kwargs: dict[str, Any]) -> None:
        """Raise TypeError unless ``kwargs`` fit the program: its Python
        signature and annotated types (``ramps.runtime.argtypes``), or JSON
        for an executable."""
        fn = self.function()
        check = getattr(fn, "check_args", None)
        if check is not None:
            check(kwargs)
        else:
            argtypes.check(fn, kwargs)


def resolve(target: str) -> Callable[..., Any]:
    """Import ``module:function`` (or make the runner of an ``exec:``
    target); raise ConfigError saying what is wrong."""
    from ramps.runtime.command import TARGET_PREFIX, parse_target

    if target.startswith(TARGET_PREFIX):
        try:
            return parse_target(target)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    module, sep, attr = target.partition(":")
    if not sep or not module or not attr:
        raise ConfigError(f"program target {target!r} must look like 'package.module:function'")
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:
        raise ConfigError(f"cannot import {module!r} for program {target!r}: {exc}") from exc
    except (Exception, SystemExit) as exc:  # the module itself failed: what and where, in one line
        what = (f"called sys.exit({exc.code!r})" if isinstance(exc, SystemExit)
                else f"raised {type(exc).__name__}: {exc}")
        raise ConfigError(f"cannot import {module!r} for program {target!r}: it {what}{_where(exc)}") from exc
    fn: Any = mod
    for part in attr.split("."):
        fn = getattr(fn, part, None)
        if fn is None:
            raise ConfigError(f"{module!r} has no {attr!r} (program {target!r})")
    if not callable(fn):
        raise ConfigError(f"program {target!r} is not callable")
    return fn


def _where(exc: BaseException) -> str:
    """`` (at path/mod.py:12)``: the innermost frame of the exception's
    traceback outside the import machinery (a SyntaxError's own line)."""
    if isinstance(exc, SyntaxError):
        return ""  # its message names the file and line already
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if "importlib" not in f.filename]
    return f" (at {frames[-1].filename}:{frames[-1].lineno})" if frames else ""


#: route_plan's work by picks, in work units, on the default 20x12 grid with a tote of 4: the
#: median over seeds 0-4, 6 to 14 picks measured on this project's 2-core VM (2026-11-27, 0.57
#: units a CPU second), 16 and 18 scaled from ramps.programs.route's table. NP-hard: one seed may
#: take 10x another of the same size
ROUTE_WORK = ((6, 0.012), (8, 0.024), (10, 0.04), (12, 0.15), (14, 0.8), (16, 10.0), (18, 50.0))
_ROUTE_SIZES = [p for p, _ in ROUTE_WORK]


def route_plan_work(picks: int = 8, time_limit: float = 60.0, workers: int = 1, **_: Any) -> float:
    """The work a route_plan call declares: ``ROUTE_WORK`` interpolated on a
    log scale between the sizes measured (3x a pick beyond them), at most
    what its ``time_limit`` lets its workers compute (at 0.5 units a CPU second)."""
    picks = max(1, int(picks))
    i = min(max(1, bisect.bisect_left(_ROUTE_SIZES, picks)), len(ROUTE_WORK) - 1)  # the segment it is in, or the last
    (p0, w0), (p1, w1) = ROUTE_WORK[i - 1], ROUTE_WORK[i]
    slope = math.log(w1 / w0) / (p1 - p0) if picks <= p1 else math.log(3.0)
    work = w1 * math.exp(slope * (picks - p1))
    return min(work, max(0.001, 0.5 * float(time_limit) * max(1, int(workers))))


BUILTINS = {
    "route_plan": ProgramSpec("route_plan", "ramps.programs.route:plan_route", work=route_plan_work, payload=200,
                              result=2000, preload=("ortools.sat.python.cp_model",)),
    "burn": ProgramSpec("burn", "ramps.programs.burn:burn", work=1.0, payload=50, result=100),
    "burn_accel": ProgramSpec("burn_accel", "ramps.programs.burn:burn_accel", payload=60, result=100,
                              work=lambda units=1.0, **_: units, accelerator="cuda",
                              accelerator_work=lambda accel_units=0.05, **_: accel_units),
    "noop": ProgramSpec("noop", "ramps.programs.burn:noop", work=0.001),
    "echo": ProgramSpec("echo", "ramps.programs.burn:echo", work=0.001),
}


class Registry:
    def __init__(self, specs: dict[str, ProgramSpec] | None = None) -> None:
        self._specs: dict[str, ProgramSpec] = dict(specs or {})

    def add(self, spec: ProgramSpec) -> ProgramSpec:
        self._specs[spec.name] = spec
        return spec

    def add_target(self, target: str, name: str | None = None, **profile: Any) -> ProgramSpec:
        """Register ``module:function`` (checked now, so a typo fails at start)."""
        fn = resolve(target)
        spec = getattr(fn, "__ramps_program__", None)
        if spec is not None and name is None:
            return self.add(spec)
        return self.add(ProgramSpec(name or target.rsplit(":", 1)[-1].rsplit(".", 1)[-1], target, _fn=fn, **profile))

    def add_command(self, name: str, path: str, *, timeout: float | None = None, args: list[str] | None = None,
                    work: float = 1.0, local_only: bool = False) -> ProgramSpec:
        """Register the executable at ``path`` as program ``name`` (checked
        now: it must exist and be executable here)."""
        from ramps.runtime.command import DEFAULT_TIMEOUT, CommandProgram, command_target

        if not name or not name.replace("_", "a").replace("-", "a").replace(".", "a").isalnum():
            raise ConfigError(f"command name {name!r}: use letters, digits, '_', '-' and '.'")
        try:
            target = command_target(path, timeout=timeout or DEFAULT_TIMEOUT, args=args, name=name)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        fn = resolve(target)
        assert isinstance(fn, CommandProgram)
        return self.add(ProgramSpec(name, target, work=work, local_only=local_only, _fn=fn))

    def load_entry_points(self) -> None:
        for ep in entry_points(group="ramps.programs"):
            self.add(ProgramSpec(ep.name, ep.value))

    def get(self, name: str) -> ProgramSpec:
        try:
            return self._specs[name]
        except KeyError:
            known = ", ".join(sorted(self._specs)) or "none"
            raise ProgramNotFound(f"no program {name!r} is registered (known: {known})") from None

    def names(self) -> frozenset[str]:
        return frozenset(self._specs)

    def targets(self) -> dict[str, str]:
        return {name: spec.target for name, spec in self._specs.items()}

    def specs(self) -> list[ProgramSpec]:
        return list(self._specs.values())

    def __contains__(self, name: str) -> bool:
        return name in self._specs


#: programs registered in this process with @program, plus the built-ins
default_registry = Registry(BUILTINS)


def program(name: str | None = None, *, work: float | Callable[..., float] = 1.0, payload: int = 0, result: int = 0,
            local_only: bool = False, memory: int = 0,
            preload: tuple[str, ...] | list[str] = (), accelerator: str = "",
            accelerator_work: float | Callable[..., float] = 0.0,
            cpu_fallback: bool = True) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Register a function as a ramps program (in an installed module).

    ``work`` is its declared cost in work units, about CPU seconds on a
    reference core (origins learn the real one from completed runs of at
    least 0.1 units), or a function of a call's keyword arguments that
    returns it, for a cost that depends on them:
    ``@ramps.program(work=lambda picks, **_: 0.2 * picks)``; ``memory`` the bytes one run needs: a robot that
    reports less free memory is not offered it. ``preload`` names modules
    the function imports only inside its body (say ``("torch",)``, so that
    callers, which import the program's module to check arguments, do not
    pay for them): every robot's executor imports them once, with the
    program's module, before it starts a worker, so no run pays the import.
    Modules imported at the top of the program's module need no mention.
    ``accelerator`` names a kind of accelerator the program can use
    (``"cuda"``): robots that offer one run it there, with
    ``ramps.accelerator()`` saying which device, and ``accelerator_work`` is
    its work there (a number or a function of the arguments, like ``work``);
    ``cpu_fallback=False`` keeps it off robots without one
    (docs/accelerators.md)."""
    if memory < 0:
        raise ConfigError(f"program {name or '?'}: memory must be >= 0 bytes, got {memory}")
    if not callable(work) and not (isinstance(work, (int, float)) and math.isfinite(work) and work >= 0):
        raise ConfigError(f"program {name or '?'}: work is work units (a finite number >= 0) or a function "
                          f"of the call's arguments that returns them, got {work!r}")
    if isinstance(preload, str) or not all(isinstance(m, str) and m for m in preload):
        raise ConfigError(f"program {name or '?'}: preload is a list of module names, got {preload!r}")
    _check_accelerator(name or "?", accelerator, accelerator_work, cpu_fallback)

    def deco(fn: Callable[..., Any]) -> Callable[..., Any]:
        if fn.__module__ == "__main__":
            raise ConfigError(
                f"program {fn.__name__!r} is defined in __main__: put it in an importable module installed "
                "on every robot (code never travels, only arguments do)"
            )
        spec = ProgramSpec(name or fn.__name__, f"{fn.__module__}:{fn.__qualname__}", work=work,
                           payload=payload, result=result, local_only=local_only, memory=memory,
                           preload=tuple(preload), accelerator=accelerator, accelerator_work=accelerator_work,
                           cpu_fallback=cpu_fallback, _fn=fn)
        fn.__ramps_program__ = spec  # type: ignore[attr-defined]
        default_registry.add(spec)
        return fn

    return deco


def _check_accelerator(name: str, accelerator: str, work: Any, cpu_fallback: bool) -> None:
    """ConfigError for a program's accelerator declaration that cannot be right."""
    if accelerator:
        try:
            Accelerator(kind=accelerator)
        except ValueError as exc:
            raise ConfigError(f"program {name}: {exc}") from None
    elif not cpu_fallback:
        raise ConfigError(f"program {name}: cpu_fallback=False needs an accelerator kind, e.g. accelerator='cuda'")
    if not callable(work) and not (isinstance(work, (int, float)) and math.isfinite(work) and work >= 0):
        raise ConfigError(f"program {name}: accelerator_work is work units (a finite number >= 0) or a function "
                          f"of the call's arguments that returns them, got {work!r}")


def encode_args(spec: ProgramSpec, kwargs: dict[str, Any], *, max_bytes: int = MAX_ARGS_BYTES) -> bytes:
    """Encode ``kwargs`` and check them against the program's signature and
    types: BadArguments for what cannot be sent (not msgpack, over
    ``max_bytes``), then for what does not fit the program."""
    try:
        data = _encoder.encode(kwargs)
    except (TypeError, msgspec.EncodeError) as exc:
        raise BadArguments(f"arguments of {spec.name!r} cannot be sent (msgpack only, never pickle): {exc}") from None
    if len(data) > max_bytes:
        raise BadArguments(f"arguments of {spec.name!r} are {len(data)} bytes; the limit is {max_bytes}")
    try:
        spec.check_args(kwargs)
    except TypeError as exc:
        raise BadArguments(f"bad arguments for program {spec.name!r}: {exc}") from None
    return data


def decode_value(data: bytes) -> Any:
    return _decoder.decode(data) if data else None


def encode_value(value: Any) -> bytes:
    return _encoder.encode(value)


def decode_args(data: bytes) -> dict[str, Any]:
    args = _decoder.decode(data) if data else {}
    if not isinstance(args, dict) or not all(isinstance(k, str) for k in args):
        raise BadArguments("program arguments must be a mapping of names to values")
    return args


class CommandSpec(Protocol):
    """An executable to register as a program (``ramps.runtime.settings.CommandEntry``)."""

    @property
    def path(self) -> str: ...
    @property
    def timeout(self) -> float: ...
    @property
    def args(self) -> list[str]: ...
    @property
    def work(self) -> float: ...
    @property
    def local_only(self) -> bool: ...


def node_registry(base: Registry, programs: Iterable[str], commands: Mapping[str, CommandSpec]) -> Registry:
    """The programs a node runs: ``base``'s, those of installed packages that declare
    ``ramps.programs``, its own ``programs`` (``package.module:function``) and its
    ``commands`` (executables, ``ramps.runtime.command``)."""
    registry = Registry(dict(base._specs))
    registry.load_entry_points()
    for target in programs:
        registry.add_target(target)
    for name, cmd in commands.items():
        registry.add_command(name, cmd.path, timeout=cmd.timeout, args=cmd.args, work=cmd.work,
                             local_only=cmd.local_only)
    return registry
