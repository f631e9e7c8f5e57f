"""``ramps bench fuzz``: garbage, mutated and hostile input at every decoder and at the core.

How this works: one seeded ``random.Random`` makes every input, so a seed
replays a run exactly (the hypothesis tests in tests/test_fuzz.py cover the
same ground with shrinking; this is the long run, with no test dependency).
Four targets, in shares of the input count:

* the wire decoder ``ramps.core.messages.decode``: random bytes, valid
  encodings of every message type truncated, bit-flipped, edited and spliced,
  other protocol versions, valid msgpack of the wrong shape, messages over the
  size limit or over a field's limit, deep nesting, huge declared lengths,
  pickles and JSON. Anything but ``WireError`` escaping is a failure, and so
  is a version error that does not name both versions;
* the program-argument decoder ``ramps.runtime.registry.decode_args``, which
  a node runs on a client's bytes: it may raise ``BadArguments`` or msgspec's
  decode errors (the node turns either into a ``bad_arguments`` outcome);
* the revocation-list decoder ``ramps.runtime.revocation.decode``, which a
  secured node runs on whatever arrives on ``ramps/<team>/revoked``: a list
  signed by a throwaway team CA, mutated and truncated, or random msgpack; it
  may only return the list or raise ``CredentialsError``;
* the core: a ``Node`` fed valid but hostile messages from any sender (itself
  included), messages that came out of the decoder, replays of what it sent
  and what it heard, reordered batches, its own programs ending, peers lost
  and found, and time moving on to its timers. The core must never raise, must
  deliver each program once, and must never offer a ``local_only`` program
  to another robot. A fresh node (another policy) is started now and then.
  Submissions carry deadlines and ``on_miss`` (``random_deadline``): the core
  must refuse one that is not a finite number, or an unknown ``on_miss``,
  with ``ValueError`` and nothing changed; a delivery is a miss exactly when
  an ok result comes after its deadline, or (``on_miss`` "fail", ``error_kind``
  "deadline") it was refused as unmeetable; and everything it sends decodes
  (no NaN, infinite or negative ``deadline_in`` or ``time_budget``). What the
  wire decoder accepts keeps every deadline field within its limits.

The inputs come from ``ramps.testing.hostile`` (the generators, shipped for
your own tests); this module is the runner. Every input counts once; exceptions are counted and the first few kept with
their tracebacks. Nothing here asserts: the CLI prints the figures and
exits 1 if any exception was counted.
"""

from __future__ import annotations

import functools
import math
import random
import sys
import time
import traceback
from collections import Counter, deque
from typing import Any, Callable

import msgspec

from ramps.core import messages as m
from ramps.core.battery import BatteryMeasured
from ramps.core.deadlines import ON_MISS
from ramps.core.events import (
    ApplicationHere,
    Cancel,
    Deliver,
    NameTaken,
    Note,
    PeerAlive,
    PeerLost,
    ProgramFinished,
    Progress,
    ProgressReported,
    Received,
    Send,
    StartProgram,
    StopProgram,
    PublishReport,
    Submit,
)
from ramps.core.node import Node
from ramps.core.policy import POLICIES
from ramps.errors import BadArguments
from ramps.runtime.registry import decode_args
from ramps.testing.hostile import (
    BIG_FIELDS_EVERY,
    ENCODER,
    FLOATS,
    INTERESTING,
    ME,
    OVERSIZED_EVERY,
    PEERS,
    PROGRAM_IDS,
    PROGRAMS,
    WIRE_KINDS,
    big_fields,
    oversized,
    random_count,
    random_deadline,
    random_message,
    random_object,
)

#: the wire input's kinds, their weights and their makers, from ``WIRE_KINDS``
_WIRE_NAMES = [k[0] for k in WIRE_KINDS]
_WIRE_WEIGHTS = [k[1] for k in WIRE_KINDS]
_WIRE_MAKERS = {k[0]: k[2] for k in WIRE_KINDS}

# ====================================================================== the decoders
class _Tally:
    def __init__(self, keep: int = 10) -> None:
        self.exceptions = 0
        self.samples: list[dict] = []
        self.keep = keep

    def failed(self, target: str, kind: str, exc: BaseException, data: bytes | None = None) -> None:
        self.exceptions += 1
        if len(self.samples) < self.keep:
            self.samples.append({"target": target, "kind": kind, "error": f"{type(exc).__name__}: {exc}"[:500],
                                 "input": (data[:64].hex() if data is not None else None),
                                 "traceback": "".join(traceback.format_exception(exc))[-2000:]})


def fuzz_decode(rng: random.Random, data: bytes, kind: str, tally: _Tally, out: Counter) -> m.Envelope | None:
    """One input at the wire decoder; returns the envelope if it decoded."""
    try:
        env = m.decode(data)
    except m.WireError as exc:
        out["wire_error"] += 1
        if kind == "wrong_version" and "version" in str(exc):
            v = str(m.PROTOCOL_VERSION)
            if f"this node speaks version {v}" not in str(exc) or "message is version" not in str(exc):
                tally.failed("decode", kind, AssertionError(f"version error does not name both versions: {exc}"),
                             data)
        return None
    except Exception as exc:  # the one thing decode must never do
        tally.failed("decode", kind, exc, data)
        return None
    out["decoded"] += 1
    broken = _out_of_limits(env.msg)
    if broken:
        tally.failed("decode", kind, AssertionError(f"decoded a deadline field out of its limits: {broken}"), data)
    return env


def _out_of_limits(msg: m.Message) -> str:
    """What in ``msg`` breaks a deadline field's limits (a finite number >= 0, a short word, a bool), or ""."""
    for name in ("deadline_in", "deadline", "time_budget"):
        x = getattr(msg, name, None)
        if x is not None and not (type(x) is float and 0.0 <= x <= sys.float_info.max):
            return f"{type(msg).__name__}.{name} = {x!r}"
    on_miss = getattr(msg, "on_miss", "")
    if type(on_miss) is not str or len(on_miss) > m.MAX_NAME:
        return f"on_miss = {on_miss!r}"[:200]
    if type(getattr(msg, "missed_deadline", False)) is not bool:
        return f"missed_deadline = {msg.missed_deadline!r}"  # type: ignore[union-attr]
    return ""


@functools.lru_cache(maxsize=1)
def _signed_list() -> tuple[bytes, Any]:
    """A revocation list signed by a throwaway team CA, and that CA's
    certificate: made once per process, since an ECDSA signature (and the
    CA's key) differ every time, and the same seed must give the same run."""
    import tempfile

    from ramps.runtime import revocation, security

    with tempfile.TemporaryDirectory() as d:
        security.create_ca(d, "fuzz")
        rl, _ = revocation.revoke(d, ["r3", "r7"])
        ca_cert, _, _ = security.load_ca(d)
    return revocation.encode(rl), ca_cert


def fuzz_revocations(rng: random.Random, good: bytes, ca_cert, tally: _Tally, out: Counter) -> None:
    """One input at the revocation-list decoder a secured node runs on ``ramps/<team>/revoked``."""
    from ramps.errors import CredentialsError
    from ramps.runtime import revocation

    data = bytearray(good) if rng.random() < 0.6 else bytearray(ENCODER.encode(random_object(rng)))
    for _ in range(rng.randint(0, 4)):
        if data:
            data[rng.randrange(len(data))] = rng.choice(INTERESTING)
    if rng.random() < 0.2:
        data = data[:rng.randint(0, len(data))]
    try:
        revocation.decode(bytes(data), ca_cert, "fuzz")
        out["revocations_ok"] += 1
    except CredentialsError:  # the node counts it as a bad message and keeps its list
        out["revocations_refused"] += 1
    except Exception as exc:
        tally.failed("revocation", "list", exc, bytes(data))


def fuzz_args(rng: random.Random, tally: _Tally, out: Counter) -> None:
    """One input at the program-argument decoder a node runs on a client's bytes."""
    data: bytes
    if rng.random() < 0.5:
        data = ENCODER.encode(random_object(rng))
    else:
        mangled = bytearray(ENCODER.encode({"seed": rng.randint(0, 9), "grid": [[0, 1], [1, 0]], "name": "r1"}))
        for _ in range(rng.randint(1, 4)):
            mangled[rng.randrange(len(mangled))] = rng.choice(INTERESTING)
        data = bytes(mangled[:rng.randint(0, len(mangled))]) if rng.random() < 0.3 else bytes(mangled)
    try:
        decode_args(data)
        out["args_ok"] += 1
    except (BadArguments, msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError, RecursionError):
        # the node turns any of these into a bad_arguments outcome for the client
        out["args_refused"] += 1
    except Exception as exc:
        tally.failed("decode_args", "args", exc, data)


# ====================================================================== the core
class CoreHarness:
    """One ``Node`` under hostile input, checking its promises as it goes."""

    def __init__(self, rng: random.Random, policy: str) -> None:
        self.rng = rng
        self.node = Node(ME, cores=2, speed=1.0, policy=policy, rng=random.Random(rng.random()),
                         registry=frozenset({"route_plan", "noop"}) if rng.random() < 0.5 else None)
        self.now = 0.0
        self.submitted: set[str] = set()
        self.local_only: set[str] = set()
        self.delivered: Counter[str] = Counter()
        #: each submitted program's deadline and on_miss
        self.deadlines: dict[str, tuple[float | None, str]] = {}
        #: submissions the core refused (a deadline not a finite number, an unknown on_miss)
        self.refused = 0
        self.sent: deque[tuple[str, m.Message]] = deque(maxlen=64)
        self.heard: deque[tuple[str, m.Message]] = deque(maxlen=64)
        self._ids = 0

    def step(self, decoded: m.Envelope | None = None) -> None:
        """One input; raises only if the core broke a promise or raised."""
        rng = self.rng
        if decoded is not None:
            return self._receive(decoded.sender, decoded.msg)
        k = rng.randrange(100)
        node = self.node
        if k < 30:
            self._receive(rng.choice(PEERS), self._aimed() if rng.random() < 0.6 else random_message(rng))
        elif k < 40 and self.sent:  # a replay of something this node sent, back at it
            to, msg = rng.choice(self.sent)
            self._receive(rng.choice([to, ME, rng.choice(PEERS)]), msg)
        elif k < 48 and self.heard:  # a replay of something it heard
            self._receive(*rng.choice(self.heard))
        elif k < 52 and len(self.heard) > 1:  # a reordered batch
            batch = rng.sample(list(self.heard), min(len(self.heard), rng.randint(2, 6)))
            for sender, msg in batch:
                self._apply(node.handle(Received(sender=sender, msg=msg), self.now))
        elif k < 62:
            self._ids += 1
            pid = f"n#{self._ids}" if rng.random() < 0.8 else rng.choice(PROGRAM_IDS)
            if pid in self.submitted:
                pid = f"n#{self._ids}-again"
            deadline, on_miss = random_deadline(rng, self.now)
            self.submit(Submit(program_id=pid, program=rng.choice(PROGRAMS), work=rng.choice([0.0, 1e-9, 1.0, 50.0,
                                                                                             1e12]),
                               local_only=rng.random() < 0.3, payload_size=random_count(rng),
                               result_size=random_count(rng), policy=rng.choice(["", "", "paper", "round_robin"]),
                               deadline=deadline, on_miss=on_miss))
        elif k < 72 and node.executor.running:
            pid, attempt = rng.choice(sorted(node.executor.running))
            ok = rng.random() < 0.8
            self._apply(node.handle(ProgramFinished(program_id=pid, attempt=attempt, ok=ok,
                                                    value=b"\x01" if ok else b"", error="" if ok else "boom",
                                                    retryable=not ok and rng.random() < 0.5), self.now))
        elif k < 74 and node.executor.running:  # a running program reports progress, any value
            pid, attempt = rng.choice(sorted(node.executor.running))
            self._apply(node.handle(ProgressReported(program_id=pid, attempt=attempt,
                                                     fraction=rng.choice(FLOATS + [0.3]),
                                                     detail=rng.choice(["", "x" * 1000])), self.now))
        elif k < 75 and node.origin.programs:  # (cancelling what it never had is local misuse)
            pid = rng.choice(sorted(node.origin.programs))
            self._apply(node.handle(Cancel(program_id=pid), self.now))
        elif k < 79:
            robot, r = rng.choice(PEERS), rng.random()  # teammates come and go; an application connects
            self._apply(node.handle(PeerLost(robot=robot) if r < 0.45 else PeerAlive(robot=robot) if r < 0.9
                                    else ApplicationHere(), self.now))
        elif k < 80:  # this robot's battery, any reading (ramps.core.battery)
            self._apply(node.handle(BatteryMeasured(charge=rng.choice([None, 0.05, 0.22, 0.9, *FLOATS]),
                                                    power=rng.choice([None, 6.0, *FLOATS])), self.now))
        elif k < 90:
            self.now += rng.choice([0.0, 0.01, 0.3, 1.0, 2.5, 11.0])
            self._apply(node.tick(self.now))
        else:
            d = node.next_deadline()
            if d is not None:
                if not math.isfinite(d):
                    raise AssertionError(f"next_deadline() is {d!r}")
                self.now = max(self.now, d)
                self._apply(node.tick(self.now))

    def shutdown(self) -> None:
        """What the runtime does on SIGTERM: hand back, cancel the rest."""
        node = self.node
        out: list = []
        node.executor.hand_back(self.now, out)
        for pid, ap in list(node.origin.programs.items()):
            if ap.state not in ("done", "failed"):
                out.extend(node.handle(Cancel(program_id=pid), self.now))
        self._apply(node._loopback(out, self.now))
        left = node.origin.active()
        if left:
            raise AssertionError(f"{left} program(s) still active after shutdown")

    def submit(self, sub: Submit) -> None:
        """What the runtime does with a submission: one whose deadline is not a
        finite number, or whose ``on_miss`` is unknown, must be refused with
        ``ValueError`` and leave no trace; any other must be taken."""
        d = sub.deadline
        bad = (d is not None and not (type(d) in (int, float) and abs(d) <= sys.float_info.max)
               or sub.on_miss not in ON_MISS)
        try:
            actions = self.node.handle(sub, self.now)
        except ValueError:
            if not bad:
                raise
            if sub.program_id in self.node.origin.programs:
                raise AssertionError(f"refused {sub.program_id!r} but kept it") from None
            self.refused += 1
            return
        if bad:
            raise AssertionError(f"took a deadline of {d!r}, on_miss {sub.on_miss!r}")
        self.submitted.add(sub.program_id)
        self.deadlines[sub.program_id] = (d, sub.on_miss)
        if sub.local_only:
            self.local_only.add(sub.program_id)
        self._apply(actions)

    # ------------------------------------------------------------ helpers
    def _aimed(self) -> m.Message:
        """A message about one of this node's programs, with its real (or a
        neighbouring) attempt and host, so input reaches deep states."""
        rng = self.rng
        programs = self.node.origin.programs
        if not programs or rng.random() < 0.2:
            if self.node.executor.running and rng.random() < 0.5:
                pid, attempt = rng.choice(sorted(self.node.executor.running))
                kinds: list[type[m.ResultAck] | type[m.CancelProgram]] = [m.ResultAck, m.CancelProgram]
                kind = rng.choice(kinds)
                return kind(program_id=pid, attempt=attempt, origin=rng.choice([ME, *PEERS]))
            return random_message(rng)
        ap = programs[rng.choice(sorted(programs))]
        attempt = rng.choice(sorted({ap.attempt, max(0, ap.attempt - 1), ap.attempt + 1, *ap.live}))
        host = rng.choice(sorted({ap.host or "p", *ap.live.values(), "p", ME}))
        return random_message(rng, pid=ap.program_id, attempt=attempt, host=host)

    def _receive(self, sender: str, msg: m.Message) -> None:
        self.heard.append((sender, msg))
        self._apply(self.node.handle(Received(sender=sender, msg=msg), self.now))

    def _apply(self, actions: list) -> None:
        for a in actions:
            if not isinstance(a, (Send, StartProgram, StopProgram, Deliver, Progress, PublishReport, Note, NameTaken)):
                raise AssertionError(f"not an action: {a!r}")
            if isinstance(a, Send):
                if a.to == ME:
                    raise AssertionError(f"a message to itself escaped the loopback: {a!r}")
                if isinstance(a.msg, m.OffloadRequest) and a.msg.program_id in self.local_only:
                    raise AssertionError(f"local_only program {a.msg.program_id} offered to {a.to}")
                try:
                    m.decode(m.encode(ME, a.msg))
                except m.WireError as exc:
                    raise AssertionError(f"sent what the wire refuses ({exc}): {a.msg!r}"[:500]) from None
                self.sent.append((a.to, a.msg))
            elif isinstance(a, Deliver):
                if a.program_id not in self.submitted:
                    raise AssertionError(f"delivered a program never submitted: {a!r}")
                self.delivered[a.program_id] += 1
                if self.delivered[a.program_id] > 1:
                    raise AssertionError(f"program {a.program_id!r} delivered twice")
                self._check_miss(a)

    def _check_miss(self, a: Deliver) -> None:
        """A delivery is a miss exactly when an ok result comes after its
        deadline, or it was refused as unmeetable (on_miss "fail")."""
        due, on_miss = self.deadlines.get(a.program_id, (None, "run"))
        if a.error_kind == "deadline":
            if due is None or on_miss != "fail" or not a.missed_deadline or a.ok:
                raise AssertionError(f"refused as unmeetable: {a!r}, deadline {due!r}, on_miss {on_miss!r}")
        elif a.missed_deadline != (a.ok and due is not None and self.now > due):
            raise AssertionError(f"missed_deadline {a.missed_deadline} at {self.now}, deadline {due!r}: {a!r}")


# ====================================================================== the run
def run_fuzz(*, inputs: int = 100_000, seed: int = 0, core_share: float = 0.35, args_share: float = 0.1,
             fresh_node_every: int = 2000, progress: Callable[[int], None] | None = None,
             revocation_share: float = 0.02) -> dict:
    """Feed ``inputs`` generated inputs to the decoders and the core; return the figures."""
    rng = random.Random(seed)
    tally = _Tally()
    counts: Counter = Counter()
    by_kind: Counter = Counter()
    policies = sorted(POLICIES)
    harness = CoreHarness(rng, rng.choice(policies))
    nodes = 1
    core_steps = 0
    signed = None  # a signed revocation list and its CA, made on first use
    started = time.perf_counter()
    for i in range(inputs):
        r = rng.random()
        if r < core_share:
            target = "core"
            try:
                harness.step()
            except Exception as exc:
                tally.failed("core", "event", exc)
            core_steps += 1
            if core_steps % fresh_node_every == 0:
                _retire(harness, tally, counts)
                harness = CoreHarness(rng, rng.choice(policies))
                nodes += 1
        elif r < core_share + args_share:
            target = "args"
            fuzz_args(rng, tally, counts)
        elif r < core_share + args_share + revocation_share:
            target = "revocation"
            if signed is None:
                signed = _signed_list()
            fuzz_revocations(rng, signed[0], signed[1], tally, counts)
        else:
            target = "decode"
            _fuzz_wire(rng, harness, tally, counts, by_kind)
        counts[target] += 1
        if progress is not None and (i + 1) % 10_000 == 0:
            progress(i + 1)
    _retire(harness, tally, counts)
    seconds = time.perf_counter() - started
    from ramps.bench.simulator import machine

    return {
        "benchmark": "fuzz", "machine": machine(), "seed": seed, "inputs": inputs, "seconds": seconds,
        "inputs_per_s": inputs / seconds if seconds else 0.0,
        "decoder_inputs": counts["decode"], "args_inputs": counts["args"], "core_events": counts["core"],
        "core_from_decoder": counts["core_from_decoder"], "core_nodes": nodes,
        "decoded": counts["decoded"], "wire_errors": counts["wire_error"],
        "args_ok": counts["args_ok"], "args_refused": counts["args_refused"],
        "revocation_inputs": counts["revocation"], "revocations_ok": counts["revocations_ok"],
        "revocations_refused": counts["revocations_refused"],
        "programs_delivered": counts["core_delivered"], "wire_kinds": dict(sorted(by_kind.items())),
        "submits_refused": counts["core_refused"], "deadline_misses": counts["core_misses"],
        "exceptions": tally.exceptions, "exception_samples": tally.samples,
    }


def _fuzz_wire(rng: random.Random, harness: CoreHarness, tally: _Tally, counts: Counter, by_kind: Counter) -> None:
    """One input for the wire decoder (now and then an oversized one or one with big fields);
    what it decodes goes on to the core, as in a node."""
    n_wire = counts["decode_inputs"]
    if n_wire % OVERSIZED_EVERY == OVERSIZED_EVERY - 1:
        kind, data = "oversized", oversized(rng)
    elif n_wire % BIG_FIELDS_EVERY == BIG_FIELDS_EVERY // 2:
        kind, data = "big_fields", big_fields(rng)
    else:
        kind = rng.choices(_WIRE_NAMES, _WIRE_WEIGHTS)[0]
        data = _WIRE_MAKERS[kind](rng)
    by_kind[kind] += 1
    counts["decode_inputs"] += 1
    env = fuzz_decode(rng, data, kind, tally, counts)
    if env is not None and not isinstance(env.msg, (m.SubmitProgram, m.CancelSubmitted, m.ProgramOutcome,
                                                     m.ProgramUpdate)):
        try:
            harness.step(env)
        except Exception as exc:
            tally.failed("core", f"decoded:{kind}", exc)
        counts["core_from_decoder"] += 1


def _retire(harness: CoreHarness, tally: _Tally, counts: Counter) -> None:
    """Shut a fuzzed node's core down and count the programs it delivered."""
    try:
        harness.shutdown()
    except Exception as exc:
        tally.failed("core", "shutdown", exc)
    counts["core_delivered"] += sum(harness.delivered.values())
    counts["core_refused"] += harness.refused
    counts["core_misses"] += harness.node.origin.deadline_misses


__all__ = ["CoreHarness", "fuzz_args", "fuzz_decode", "fuzz_revocations", "run_fuzz"]
