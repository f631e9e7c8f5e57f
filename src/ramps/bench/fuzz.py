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

Every input counts once; exceptions are counted and the first few kept with
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
from ramps.core.events import (
    Cancel,
    Deliver,
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

ME = "n"
#: robot names a hostile peer may use: teammates, this robot itself, long ones
PEERS = ["p", "q", "r1", ME, "x" * m.MAX_NAME, "o/app-1", "robot.é"]
PROGRAM_IDS = ["a", "b", "c", "n#1", "p" * m.MAX_NAME]
PROGRAMS = ["route_plan", "noop", "x"]
REASONS = ["busy", "unknown_program", "bad_request", "closing", ""]
#: msgpack type bytes that change how what follows is read
INTERESTING = [0x00, 0x7f, 0x80, 0x8f, 0x90, 0x9f, 0xa0, 0xbf, 0xc0, 0xc1, 0xc2, 0xc3, 0xc4, 0xc5, 0xc6, 0xc7,
               0xc8, 0xc9, 0xca, 0xcb, 0xcc, 0xcf, 0xd0, 0xd3, 0xd4, 0xd8, 0xd9, 0xda, 0xdb, 0xdc, 0xdd, 0xde,
               0xdf, 0xe0, 0xff]
_FLOATS = [0.0, -0.0, 1.0, 0.5, 1e-300, 5e-324, 1e300, sys.float_info.max, float("nan"), float("inf"),
           float("-inf"), -1.0, m.MIN_SPEED, m.MAX_SPEED, m.MAX_LOAD]
_INTS = [0, 1, -1, 2, 2**31, 2**32, 2**63 - 1, -(2**63), 2**64 - 1, m.MAX_CORES, m.MAX_CORES + 1]
_enc = msgspec.msgpack.Encoder()


# ====================================================================== valid messages
def _count(rng: random.Random) -> int:
    return rng.choice([0, 1, 2, 3, 5, 10, 2**31, 2**63 - 1]) if rng.random() < 0.3 else rng.randint(0, 6)


def _amount(rng: random.Random, hi: float = 20.0) -> float:
    return rng.choice([0.0, 1e-300, 1e300, m.MAX_LOAD]) if rng.random() < 0.1 else rng.uniform(0.0, hi)


def random_report(rng: random.Random, robot: str | None = None) -> m.LoadReport:
    """A load report within the schema's bounds, extremes included."""
    extreme = rng.random() < 0.15
    return m.LoadReport(
        robot=robot or rng.choice(PEERS), incarnation=rng.randint(0, 2), seq=_count(rng),
        cores=rng.choice([1, m.MAX_CORES]) if extreme else rng.randint(1, 8),
        speed=rng.choice([m.MIN_SPEED, m.MAX_SPEED]) if extreme else rng.uniform(0.1, 4.0),
        cpu_busy=_amount(rng, 8.0), runnable=rng.choice([0.0, m.MAX_LOAD]) if extreme else _amount(rng),
        ramps_running=_count(rng), ramps_avg=_amount(rng, 5.0), accepted_total=_count(rng),
        finished_total=_count(rng), window=_amount(rng, 2.0), mem_free=_count(rng),
        cpu_per_core=[rng.random() for _ in range(rng.randint(0, 4))], load_avg=_amount(rng),
        blacklisted=rng.sample(PEERS, rng.randint(0, 2)), bad_messages=_count(rng),
        sees=rng.choice([None, _count(rng)]),
        running=[m.RunningProgram(rng.choice(PROGRAMS), rng.choice(PEERS), rng.choice([None, 0.0, rng.random(), 1.0]))
                 for _ in range(rng.choice([0, 0, 1, 3]))],
        remaining=sorted(_amount(rng, 120.0) for _ in range(rng.choice([0, 1, 4, m.MAX_LISTED if extreme else 2]))),
        links=[m.LinkSeen(rng.choice(PEERS), rng.choice([None, _amount(rng, 0.5)]), rng.choice([None, _amount(rng, 1e7)]),
                          rng.choice([None, _amount(rng, 2.0)]))
               for _ in range(rng.choice([0, 1, 3, m.MAX_LISTED if extreme else 2]))],
        learned=[m.LearnedWork(rng.choice(PROGRAMS), _amount(rng, 100.0)) for _ in range(rng.choice([0, 1, 2]))],
    )


def random_message(rng: random.Random, *, pid: str | None = None, attempt: int | None = None,
                   host: str | None = None) -> m.Message:
    """One valid message of any type, with random fields in the schema."""
    pid = pid or rng.choice(PROGRAM_IDS)
    attempt = rng.randint(0, 4) if attempt is None else attempt
    host = host or rng.choice(PEERS)
    kind = rng.randrange(16)
    if kind == 0:
        return random_report(rng)
    if kind == 1:
        return m.OffloadRequest(program_id=pid, attempt=attempt, origin=rng.choice(PEERS), host=host,
                                program=rng.choice(PROGRAMS), args=rng.randbytes(rng.randint(0, 16)),
                                payload_size=_count(rng), work=_amount(rng, 60.0),
                                expected_runnable=None if rng.random() < 0.5 else _amount(rng),
                                time_budget=None if rng.random() < 0.5 else _amount(rng, 120.0),
                                force=rng.random() < 0.3,
                                resume=rng.choice([None, b"", rng.randbytes(8), b"\0" * m.MAX_CHECKPOINT_BYTES]),
                                resume_fraction=rng.choice([0.0, 1.0, rng.random()]))
    if kind == 2:
        return m.OffloadAccepted(program_id=pid, attempt=attempt, host=host, accept_seq=_count(rng))
    if kind == 3:
        return m.OffloadRejected(program_id=pid, attempt=attempt, host=host, reason=rng.choice(REASONS),
                                 permanent=rng.random() < 0.4, detail=rng.choice(["", "why", "d" * m.MAX_TEXT]),
                                 report=random_report(rng, host) if rng.random() < 0.5 else None)
    if kind == 4:
        refs = [m.ProgramRef(rng.choice(PROGRAM_IDS), rng.randint(0, 4)) for _ in range(rng.randint(0, 4))]
        if rng.random() < 0.5:
            refs.append(m.ProgramRef(pid, attempt))
        return m.Heartbeat(host=host, incarnation=_count(rng), programs=refs)
    if kind == 5:
        ok = rng.random() < 0.6
        return m.ProgramResult(program_id=pid, attempt=attempt, host=host, ok=ok,
                               value=_enc.encode(rng.randint(0, 9)) if ok else b"",
                               error="" if ok else "boom", retryable=not ok and rng.random() < 0.5,
                               finish_seq=_count(rng), result_size=_count(rng),
                               work_done=rng.choice([None, 0.0, _amount(rng, 100.0), 1e300]) if ok else None)
    if kind == 6:
        return m.ResultAck(program_id=pid, attempt=attempt, origin=rng.choice(PEERS))
    if kind == 7:
        return m.CancelProgram(program_id=pid, attempt=attempt, origin=rng.choice(PEERS))
    if kind == 8:
        return m.SubmitProgram(client=rng.choice(PEERS), request_id=_count(rng), program=rng.choice(PROGRAMS),
                               args=_enc.encode({"seed": rng.randint(0, 9)}), work=_amount(rng),
                               result_size=_count(rng), local_only=rng.random() < 0.3,
                               policy=rng.choice(["", "ramps", "nope"]))
    if kind == 9:
        return m.CancelSubmitted(client=rng.choice(PEERS), request_id=_count(rng))
    if kind == 11:
        return m.ProgramProgress(program_id=pid, attempt=attempt, host=host,
                                 fraction=rng.choice([0.0, 1.0, rng.random()]),
                                 detail=rng.choice(["", "step 3", "d" * m.MAX_PROGRESS_TEXT]))
    if kind == 15:
        return m.ProgramCheckpoint(program_id=pid, attempt=attempt, host=host,
                                   state=rng.choice([b"", rng.randbytes(16), b"\0" * m.MAX_CHECKPOINT_BYTES]),
                                   fraction=rng.choice([None, 0.0, 1.0, rng.random()]))
    if kind == 13:
        return m.LinkProbe(sent_at=_amount(rng, 1e6), padding=b"\0" * rng.choice([0, 16, m.MAX_PROBE_BYTES]))
    if kind == 14:
        return m.LinkProbeReply(sent_at=_amount(rng, 1e6), size=rng.choice([0, 16384, m.MAX_PROBE_BYTES]))
    if kind == 12:
        return m.ProgramUpdate(request_id=_count(rng), state=rng.choice(["placed", "running", "replaced", ""]),
                               host=rng.choice(["", *PEERS]), attempt=_count(rng),
                               fraction=rng.choice([None, 0.0, 1.0, rng.random()]), detail=rng.choice(["", "x"]))
    return m.ProgramOutcome(request_id=_count(rng), ok=rng.random() < 0.5, value=b"\x01", error="e",
                            error_kind=rng.choice(["", "program", "refused"]), host=rng.choice(["", *PEERS]),
                            attempts=_count(rng), moves=_count(rng),
                            resumed_from=rng.choice([None, 0.0, rng.random()]))


# ====================================================================== garbage and mutations
def random_object(rng: random.Random, depth: int = 0) -> Any:
    """Any msgpack-encodable value (the wrong shape, nearly always)."""
    k = rng.randrange(10 if depth < 4 else 7)
    if k == 0:
        return None
    if k == 1:
        return rng.random() < 0.5
    if k == 2:
        return rng.choice(_INTS) if rng.random() < 0.5 else rng.randint(-1000, 1000)
    if k == 3:
        return rng.choice(_FLOATS)
    if k == 4:
        return rng.choice(["", "v", "type", "msg", "sender", "load", "offload", "ack", "é", "*", "x" * 200])
    if k == 5:
        return rng.randbytes(rng.randint(0, 8))
    if k == 6:
        return m.PROTOCOL_VERSION + rng.choice((-1, 0, 1))
    if k == 7:
        return [random_object(rng, depth + 1) for _ in range(rng.randint(0, 4))]
    keys = ["v", "sender", "msg", "type", "robot", "program_id", "attempt", "host", "args", "programs", "cores"]
    return {rng.choice(keys): random_object(rng, depth + 1) for _ in range(rng.randint(0, 4))}


def _valid_bytes(rng: random.Random) -> bytes:
    return m.encode(rng.choice(PEERS), random_message(rng))


def _as_dict(rng: random.Random) -> dict:
    return msgspec.to_builtins(m.Envelope(v=m.PROTOCOL_VERSION, sender=rng.choice(PEERS), msg=random_message(rng)),
                               builtin_types=(bytes,))


def _truncated(rng):
    data = _valid_bytes(rng)
    return data[:rng.randrange(len(data))]


def _bit_flips(rng):
    data = bytearray(_valid_bytes(rng))
    for _ in range(rng.randint(1, 8)):
        i = rng.randrange(len(data))
        data[i] ^= 1 << rng.randrange(8)
    return bytes(data)


def _byte_edits(rng):
    data = bytearray(_valid_bytes(rng))
    for _ in range(rng.randint(1, 4)):
        i = rng.randrange(len(data) + 1)
        op = rng.randrange(3)
        if op == 0 and i < len(data):
            data[i] = rng.choice(INTERESTING)
        elif op == 1:
            data[i:i] = bytes([rng.choice(INTERESTING)]) + rng.randbytes(rng.randint(0, 4))
        elif data:
            del data[i:i + rng.randint(1, 8)]
    return bytes(data)


def _spliced(rng):
    a, b = _valid_bytes(rng), _valid_bytes(rng)
    return a[:rng.randrange(len(a) + 1)] + b[rng.randrange(len(b) + 1):]


def _wrong_version(rng):
    d = _as_dict(rng)
    d["v"] = rng.choice([0, 2, -1, 2**63 - 1, -(2**63), 2**64 - 1, m.PROTOCOL_VERSION + rng.randint(1, 1000)])
    if rng.random() < 0.3:
        d["msg"] = random_object(rng)  # a future version may have any body
    return _enc.encode(d)


def _wrong_shape(rng):
    return _enc.encode(random_object(rng))


def _bad_fields(rng):
    """A right envelope whose message has a field of the wrong type or out of
    its limits, an extra field, or a missing one."""
    d = _as_dict(rng)
    body = d["msg"]
    field = rng.choice([k for k in body if k != "type"] or ["type"])
    op = rng.randrange(4)
    if op == 0:
        body[field] = random_object(rng)
    elif op == 1:
        body[field] = rng.choice([-1, float("nan"), float("inf"), 2**64 - 1, "x" * (m.MAX_NAME + 1),
                                  "a*", "a\n", "$*", "", "y" * (m.MAX_TEXT + 1)])
    elif op == 2:
        body["extra"] = random_object(rng)
    else:
        body.pop(field, None)
    if rng.random() < 0.2:
        d["sender"] = rng.choice(["", "*", "**", "a/**", "s" * (m.MAX_NAME + 1), 7, None])
    return _enc.encode(d)


def _oversized(rng):
    """Over the total limit (checked before parsing) or near it."""
    n = m.MAX_MESSAGE_BYTES + rng.choice([1, 2, 1000, 1 << 20])
    if rng.random() < 0.5:
        return b"\x00" * n
    # a real message whose arguments take it over the limit
    return m.encode("p", m.OffloadRequest(program_id="a", attempt=1, origin="p", host=ME, program="x",
                                          args=b"\x00" * n))


def _big_fields(rng):
    """Under the total limit, over a field's limit (a list, a name, a text)."""
    k = rng.randrange(4)
    if k == 0:
        msg: m.Message = m.Heartbeat(host="p", incarnation=0,
                                     programs=[m.ProgramRef("a", 1)] * (m.MAX_REFS + rng.choice([0, 1])))
    elif k == 1:
        msg = random_report(rng, "p")
        msg = msgspec.structs.replace(msg, cpu_per_core=[0.5] * (m.MAX_CORES + rng.choice([0, 1])))
    elif k == 2:
        msg = m.OffloadRejected(program_id="a", attempt=1, host="p", reason="busy", permanent=False,
                                detail="d" * (m.MAX_TEXT + rng.choice([0, 1, 10_000])))
    else:
        msg = m.ProgramResult(program_id="a", attempt=1, host="p", ok=True,
                              value=b"\x01" * rng.choice([1 << 20, m.MAX_MESSAGE_BYTES - 1024]))
    return m.encode("p", msg)


def _deep(rng):
    depth = rng.choice([100, 1000, 10_000, 100_000, 1_000_000])
    nest = (b"\x91" if rng.random() < 0.5 else b"\x81\xa1k") * depth + b"\xc0"
    where = rng.randrange(3)
    if where == 0:
        return nest
    prefix = b"\x82\xa1v\x01\xa4junk" if where == 1 else (
        b"\x83\xa1v\x01\xa6sender\xa1p\xa3msg\x82\xa4type\xa4load\xa4junk")
    return prefix + nest


def _huge_lengths(rng):
    """Headers that declare gigabytes of string, bytes, array or map."""
    head = bytes([rng.choice([0xdb, 0xc6, 0xdd, 0xdf])]) + b"\xff\xff\xff" + bytes([rng.randrange(256)])
    prefix = rng.choice([b"", b"\x82\xa1v\x01\xa6sender", b"\x83\xa1v\x01\xa6sender\xa1p\xa3msg"])
    return prefix + head + rng.randbytes(rng.randint(0, 16))


def _ext(rng):
    """msgpack extension types (timestamps, unknown codes) where values go."""
    ext = rng.choice([b"\xd6\xff\x00\x00\x00\x01", b"\xd7\xff" + b"\xff" * 8, b"\xd4\x05\x00",
                      b"\xc7\x03\x07abc", b"\xd6\xff\xff\xff\xff\xff", b"\xc7\x0c\xff" + b"\xff" * 12])
    return rng.choice([ext, b"\x82\xa1v" + ext + b"\xa1x\x01", b"\x82\xa1v\x01\xa6sender" + ext])


_PICKLES: list[bytes] = []


def _pickled(rng):
    """Pickles of messages (made once, with the standard pickler; nobody
    here or in a node ever unpickles anything)."""
    if not _PICKLES:
        import pickle

        for proto in (0, 2, pickle.HIGHEST_PROTOCOL):
            _PICKLES.append(pickle.dumps({"type": "submit", "program": "noop", "args": b""}, protocol=proto))
            _PICKLES.append(pickle.dumps(_as_dict(random.Random(proto)), protocol=proto))
    return rng.choice(_PICKLES)


def _json(rng):
    return msgspec.json.encode(_as_dict(rng))


def _random_bytes(rng):
    return rng.randbytes(rng.choice([0, 1, 2, 3, 8, 64, 512, 4096]))


def _valid(rng):
    return _valid_bytes(rng)


#: (name, weight, maker) of every kind of wire input
WIRE_KINDS: list[tuple[str, int, Callable[[random.Random], bytes]]] = [
    ("random_bytes", 10, _random_bytes),
    ("valid", 6, _valid),
    ("truncated", 12, _truncated),
    ("bit_flips", 14, _bit_flips),
    ("byte_edits", 12, _byte_edits),
    ("spliced", 6, _spliced),
    ("wrong_version", 6, _wrong_version),
    ("wrong_shape", 8, _wrong_shape),
    ("bad_fields", 14, _bad_fields),
    ("huge_lengths", 3, _huge_lengths),
    ("ext_types", 2, _ext),
    ("deep_nesting", 1, _deep),
    ("pickle", 1, _pickled),
    ("json", 1, _json),
]
#: rare and costly (megabytes each): drawn once per this many wire inputs
OVERSIZED_EVERY = 500
BIG_FIELDS_EVERY = 1000


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
    return env


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

    data = bytearray(good) if rng.random() < 0.6 else bytearray(_enc.encode(random_object(rng)))
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
    if rng.random() < 0.5:
        data = _enc.encode(random_object(rng))
    else:
        data = bytearray(_enc.encode({"seed": rng.randint(0, 9), "grid": [[0, 1], [1, 0]], "name": "r1"}))
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] = rng.choice(INTERESTING)
        data = bytes(data[:rng.randint(0, len(data))]) if rng.random() < 0.3 else bytes(data)
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
            lo = rng.random() < 0.3
            sub = Submit(program_id=pid, program=rng.choice(PROGRAMS), work=rng.choice([0.0, 1e-9, 1.0, 50.0, 1e12]),
                         local_only=lo, payload_size=_count(rng), result_size=_count(rng),
                         policy=rng.choice(["", "", "paper", "round_robin"]))
            self.submitted.add(pid)
            if lo:
                self.local_only.add(pid)
            self._apply(node.handle(sub, self.now))
        elif k < 72 and node.executor.running:
            pid, attempt = rng.choice(sorted(node.executor.running))
            ok = rng.random() < 0.8
            self._apply(node.handle(ProgramFinished(program_id=pid, attempt=attempt, ok=ok,
                                                    value=b"\x01" if ok else b"", error="" if ok else "boom",
                                                    retryable=not ok and rng.random() < 0.5), self.now))
        elif k < 74 and node.executor.running:  # a running program reports progress, any value
            pid, attempt = rng.choice(sorted(node.executor.running))
            self._apply(node.handle(ProgressReported(program_id=pid, attempt=attempt,
                                                     fraction=rng.choice(_FLOATS + [0.3]),
                                                     detail=rng.choice(["", "x" * 1000])), self.now))
        elif k < 75 and node.origin.programs:  # (cancelling what it never had is local misuse)
            pid = rng.choice(sorted(node.origin.programs))
            self._apply(node.handle(Cancel(program_id=pid), self.now))
        elif k < 80:
            robot = rng.choice(PEERS)
            self._apply(node.handle(PeerLost(robot=robot) if rng.random() < 0.5 else PeerAlive(robot=robot),
                                    self.now))
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

    # ------------------------------------------------------------ helpers
    def _aimed(self) -> m.Message:
        """A message about one of this node's programs, with its real (or a
        neighbouring) attempt and host, so input reaches deep states."""
        rng = self.rng
        programs = self.node.origin.programs
        if not programs or rng.random() < 0.2:
            if self.node.executor.running and rng.random() < 0.5:
                pid, attempt = rng.choice(sorted(self.node.executor.running))
                return rng.choice([m.ResultAck, m.CancelProgram])(
                    program_id=pid, attempt=attempt, origin=rng.choice([ME, *PEERS]))
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
            if not isinstance(a, (Send, StartProgram, StopProgram, Deliver, Progress, PublishReport, Note)):
                raise AssertionError(f"not an action: {a!r}")
            if isinstance(a, Send):
                if a.to == ME:
                    raise AssertionError(f"a message to itself escaped the loopback: {a!r}")
                if isinstance(a.msg, m.OffloadRequest) and a.msg.program_id in self.local_only:
                    raise AssertionError(f"local_only program {a.msg.program_id} offered to {a.to}")
                self.sent.append((a.to, a.msg))
            elif isinstance(a, Deliver):
                if a.program_id not in self.submitted:
                    raise AssertionError(f"delivered a program never submitted: {a!r}")
                self.delivered[a.program_id] += 1
                if self.delivered[a.program_id] > 1:
                    raise AssertionError(f"program {a.program_id!r} delivered twice")


# ====================================================================== the run
def run_fuzz(*, inputs: int = 100_000, seed: int = 0, core_share: float = 0.35, args_share: float = 0.1,
             fresh_node_every: int = 2000, progress: Callable[[int], None] | None = None,
             revocation_share: float = 0.02) -> dict:
    """Feed ``inputs`` generated inputs to the decoders and the core; return the figures."""
    rng = random.Random(seed)
    kinds, weights = [k[0] for k in WIRE_KINDS], [k[1] for k in WIRE_KINDS]
    makers = {k[0]: k[2] for k in WIRE_KINDS}
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
                try:
                    harness.shutdown()
                except Exception as exc:
                    tally.failed("core", "shutdown", exc)
                counts["core_delivered"] += sum(harness.delivered.values())
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
            n_wire = counts["decode_inputs"]
            if n_wire % OVERSIZED_EVERY == OVERSIZED_EVERY - 1:
                kind, data = "oversized", _oversized(rng)
            elif n_wire % BIG_FIELDS_EVERY == BIG_FIELDS_EVERY // 2:
                kind, data = "big_fields", _big_fields(rng)
            else:
                kind = rng.choices(kinds, weights)[0]
                data = makers[kind](rng)
            by_kind[kind] += 1
            counts["decode_inputs"] += 1
            env = fuzz_decode(rng, data, kind, tally, counts)
            if env is not None and not isinstance(env.msg, (m.SubmitProgram, m.CancelSubmitted, m.ProgramOutcome,
                                                             m.ProgramUpdate)):
                # what survived the decoder goes on to the core, as in a node
                try:
                    harness.step(env)
                except Exception as exc:
                    tally.failed("core", f"decoded:{kind}", exc)
                counts["core_from_decoder"] += 1
        counts[target] += 1
        if progress is not None and (i + 1) % 10_000 == 0:
            progress(i + 1)
    try:
        harness.shutdown()
    except Exception as exc:
        tally.failed("core", "shutdown", exc)
    counts["core_delivered"] += sum(harness.delivered.values())
    seconds = time.perf_counter() - started
    from ramps.experiments.bench import machine

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
        "exceptions": tally.exceptions, "exception_samples": tally.samples,
    }


__all__ = ["WIRE_KINDS", "CoreHarness", "random_message", "random_object", "random_report", "run_fuzz"]
