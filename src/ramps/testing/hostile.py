"""Hostile input for ramps: wire messages a misbehaving or broken peer may send.

How this works: every maker takes one seeded ``random.Random`` and returns
bytes (or a message), so a seed replays the same inputs. ``random_message``
and ``random_report`` build *valid* messages of every type, with values at
and beyond their limits (names of the longest length, zero, NaN, the
largest counts) and from any sender, the receiving robot ``ME`` included.
``WIRE_KINDS`` lists the makers of wire input, with weights: random bytes,
valid encodings truncated, bit-flipped, edited and spliced, other protocol
versions, valid msgpack of the wrong shape, fields out of their limits
(deadline fields among them: NaN, infinite, negative, of the wrong type),
huge declared lengths, msgpack extension types, deep nesting, pickles and
JSON; ``oversized`` and ``big_fields`` make messages of megabytes (rare and
costly: draw them once per ``OVERSIZED_EVERY``/``BIG_FIELDS_EVERY`` inputs).
``random_deadline`` draws a submission's deadline and ``on_miss``, valid or
one the core must refuse (``GOOD_DEADLINES``, ``BAD_DEADLINES``, ``BAD_ON_MISS``).

Use them to test your own code that handles ramps messages, as ramps does:
``ramps bench fuzz`` (``ramps.bench.fuzz``) runs them at the decoders and
the core, ``ramps bench flood`` floods a real node with them, and
tests/test_fuzz.py draws from them in hypothesis tests. Nothing here
decodes, asserts or does I/O.
"""

from __future__ import annotations

import random
import sys
from typing import Any, Callable

import msgspec

from ramps.core import messages as m

ME = "n"
#: robot names a hostile peer may use: teammates, this robot itself, long ones
PEERS = ["p", "q", "r1", ME, "x" * m.MAX_NAME, "o/app-1", "robot.é"]
PROGRAM_IDS = ["a", "b", "c", "n#1", "p" * m.MAX_NAME]
PROGRAMS = ["route_plan", "noop", "x"]
REASONS = ["busy", "late", "unknown_program", "bad_request", "closing", "battery", ""]
#: msgpack type bytes that change how what follows is read
INTERESTING = [0x00, 0x7f, 0x80, 0x8f, 0x90, 0x9f, 0xa0, 0xbf, 0xc0, 0xc1, 0xc2, 0xc3, 0xc4, 0xc5, 0xc6, 0xc7,
               0xc8, 0xc9, 0xca, 0xcb, 0xcc, 0xcf, 0xd0, 0xd3, 0xd4, 0xd8, 0xd9, 0xda, 0xdb, 0xdc, 0xdd, 0xde,
               0xdf, 0xe0, 0xff]
FLOATS = [0.0, -0.0, 1.0, 0.5, 1e-300, 5e-324, 1e300, sys.float_info.max, float("nan"), float("inf"),
           float("-inf"), -1.0, m.MIN_SPEED, m.MAX_SPEED, m.MAX_LOAD]
_INTS = [0, 1, -1, 2, 2**31, 2**32, 2**63 - 1, -(2**63), 2**64 - 1, m.MAX_CORES, m.MAX_CORES + 1]
ENCODER = msgspec.msgpack.Encoder()
#: ``Submit.deadline`` values the core must take (absolute times: past, now, soon, huge) and refuse
#: with ValueError (not a finite number); ``on_miss`` values it must refuse
GOOD_DEADLINES = [None, 0.0, -1.0, 1.0, 30.0, 1e300, -1e300, sys.float_info.max, -sys.float_info.max, 5, -(2**63)]
BAD_DEADLINES = [float("nan"), float("inf"), float("-inf"), "2", b"1", True, 10**400, [1.0]]
BAD_ON_MISS = ["nope", "", "RUN", None, 3]
#: deadline fields as a hostile peer may write them on the wire; only finite numbers >= 0 (and None) decode
WIRE_DEADLINES = [float("nan"), float("inf"), float("-inf"), -1.0, -1e-300, "2", True, [], {}, 2**64 - 1, 0.0,
                  sys.float_info.max, None]


def random_deadline(rng: random.Random, now: float) -> tuple[Any, Any]:
    """A ``Submit``'s deadline and ``on_miss``: mostly valid (none, or around ``now``), now and then
    a value the core must refuse."""
    k = rng.random()
    deadline: Any
    if k < 0.4:
        deadline = None
    elif k < 0.8:
        deadline = now + rng.choice([-5.0, 0.0, 0.5, 2.0, 10.0, 60.0, 1e6])
    else:
        deadline = rng.choice(GOOD_DEADLINES + BAD_DEADLINES)
    on_miss = rng.choice(["run", "run", "local", "fail"]) if rng.random() < 0.95 else rng.choice(BAD_ON_MISS)
    return deadline, on_miss


# ====================================================================== valid messages
def random_count(rng: random.Random) -> int:
    return rng.choice([0, 1, 2, 3, 5, 10, 2**31, 2**63 - 1]) if rng.random() < 0.3 else rng.randint(0, 6)


def _amount(rng: random.Random, hi: float = 20.0) -> float:
    return rng.choice([0.0, 1e-300, 1e300, m.MAX_LOAD]) if rng.random() < 0.1 else rng.uniform(0.0, hi)


def random_report(rng: random.Random, robot: str | None = None) -> m.LoadReport:
    """A load report within the schema's bounds, extremes included."""
    extreme = rng.random() < 0.15
    return m.LoadReport(
        robot=robot or rng.choice(PEERS), incarnation=rng.randint(0, 2), seq=random_count(rng),
        cores=rng.choice([1, m.MAX_CORES]) if extreme else rng.randint(1, 8),
        speed=rng.choice([m.MIN_SPEED, m.MAX_SPEED]) if extreme else rng.uniform(0.1, 4.0),
        cpu_busy=_amount(rng, 8.0), runnable=rng.choice([0.0, m.MAX_LOAD]) if extreme else _amount(rng),
        ramps_running=random_count(rng), ramps_avg=_amount(rng, 5.0), accepted_total=random_count(rng),
        finished_total=random_count(rng), window=_amount(rng, 2.0), mem_free=random_count(rng),
        cpu_per_core=[rng.random() for _ in range(rng.randint(0, 4))], load_avg=_amount(rng),
        blacklisted=rng.sample(PEERS, rng.randint(0, 2)), bad_messages=random_count(rng),
        sees=rng.choice([None, random_count(rng)]),
        running=[m.RunningProgram(rng.choice(PROGRAMS), rng.choice(PEERS), rng.choice([None, 0.0, rng.random(), 1.0]))
                 for _ in range(rng.choice([0, 0, 1, 3]))],
        remaining=sorted(_amount(rng, 120.0) for _ in range(rng.choice([0, 1, 4, m.MAX_LISTED if extreme else 2]))),
        links=[m.LinkSeen(rng.choice(PEERS), rng.choice([None, _amount(rng, 0.5)]), rng.choice([None, _amount(rng, 1e7)]),
                          rng.choice([None, _amount(rng, 2.0)]))
               for _ in range(rng.choice([0, 1, 3, m.MAX_LISTED if extreme else 2]))],
        learned=[m.LearnedWork(rng.choice(PROGRAMS), _amount(rng, 100.0)) for _ in range(rng.choice([0, 1, 2]))],
        accelerators=[m.AcceleratorSeen(rng.choice(["cuda", "npu"]), rng.choice([1, m.MAX_CORES]) if extreme else 1,
                                        rng.choice([m.MIN_SPEED, m.MAX_SPEED]) if extreme else rng.uniform(1.0, 40.0),
                                        random_count(rng), random_count(rng), random_count(rng),
                                        rng.choice([None, 0.0, rng.random()]),
                                        sorted(_amount(rng, 60.0) for _ in range(rng.choice([0, 1, 3]))))
                      for _ in range(rng.choice([0, 0, 1, 2]))],
        moves=random_count(rng), moves_aborted=random_count(rng), node_cpu=_amount(rng, 2.0),
        battery=rng.choice([None, None, 0.0, 1.0, rng.random()]), low_battery=rng.random() < 0.1,
        submits=rng.random() < 0.3,
        power=rng.choice([None, None, _amount(rng, 40.0)]),
    )


def random_message(rng: random.Random, *, pid: str | None = None, attempt: int | None = None,
                   host: str | None = None) -> m.Message:
    """One valid message of any type, with random fields in the schema."""
    pid = pid or rng.choice(PROGRAM_IDS)
    attempt = rng.randint(0, 4) if attempt is None else attempt
    host = host or rng.choice(PEERS)
    kind = rng.randrange(17)
    if kind == 0:
        return random_report(rng)
    if kind == 1:
        return m.OffloadRequest(program_id=pid, attempt=attempt, origin=rng.choice(PEERS), host=host,
                                program=rng.choice(PROGRAMS), args=rng.randbytes(rng.randint(0, 16)),
                                payload_size=random_count(rng), work=_amount(rng, 60.0),
                                expected_runnable=None if rng.random() < 0.5 else _amount(rng),
                                time_budget=None if rng.random() < 0.5 else _amount(rng, 120.0),
                                force=rng.random() < 0.3,
                                resume=rng.choice([None, b"", rng.randbytes(8), b"\0" * m.MAX_CHECKPOINT_BYTES]),
                                resume_fraction=rng.choice([0.0, 1.0, rng.random()]),
                                deadline_in=None if rng.random() < 0.5 else _amount(rng, 120.0),
                                accelerator=rng.choice(["", "", "cuda", "nope"]))
    if kind == 2:
        return m.OffloadAccepted(program_id=pid, attempt=attempt, host=host, accept_seq=random_count(rng))
    if kind == 3:
        return m.OffloadRejected(program_id=pid, attempt=attempt, host=host, reason=rng.choice(REASONS),
                                 permanent=rng.random() < 0.4, detail=rng.choice(["", "why", "d" * m.MAX_TEXT]),
                                 report=random_report(rng, host) if rng.random() < 0.5 else None)
    if kind == 4:
        refs = [m.ProgramRef(rng.choice(PROGRAM_IDS), rng.randint(0, 4)) for _ in range(rng.randint(0, 4))]
        if rng.random() < 0.5:
            refs.append(m.ProgramRef(pid, attempt))
        return m.Heartbeat(host=host, incarnation=random_count(rng), programs=refs)
    if kind == 5:
        ok = rng.random() < 0.6
        return m.ProgramResult(program_id=pid, attempt=attempt, host=host, ok=ok,
                               value=ENCODER.encode(rng.randint(0, 9)) if ok else b"",
                               error="" if ok else "boom", retryable=not ok and rng.random() < 0.5,
                               finish_seq=random_count(rng), result_size=random_count(rng),
                               work_done=rng.choice([None, 0.0, _amount(rng, 100.0), 1e300]) if ok else None)
    if kind == 6:
        return m.ResultAck(program_id=pid, attempt=attempt, origin=rng.choice(PEERS))
    if kind == 7:
        return m.CancelProgram(program_id=pid, attempt=attempt, origin=rng.choice(PEERS))
    if kind == 8:
        return m.SubmitProgram(client=rng.choice(PEERS), request_id=random_count(rng), program=rng.choice(PROGRAMS),
                               args=ENCODER.encode({"seed": rng.randint(0, 9)}), work=_amount(rng),
                               result_size=random_count(rng), local_only=rng.random() < 0.3,
                               policy=rng.choice(["", "ramps", "nope"]),
                               deadline=None if rng.random() < 0.5 else _amount(rng, 60.0),
                               on_miss=rng.choice(["", "run", "local", "fail", "nope"]),
                               accelerator=rng.choice(["", "", "cuda"]), accelerator_work=_amount(rng, 60.0),
                               cpu_fallback=rng.random() < 0.8)
    if kind == 9:
        return m.CancelSubmitted(client=rng.choice(PEERS), request_id=random_count(rng))
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
    if kind == 16:
        pools = [m.ClaimedPool(rng.choice(PEERS), rng.choice(["", "", "cuda"]),
                               [_amount(rng, 60.0) for _ in range(rng.choice([0, 1, 3, m.MAX_LISTED]))])
                 for _ in range(rng.choice([0, 1, 2, m.MAX_LISTED]))]
        return m.BurstClaim(planned=rng.random() < 0.7, pools=pools)
    if kind == 12:
        return m.ProgramUpdate(request_id=random_count(rng), state=rng.choice(["placed", "running", "replaced", ""]),
                               host=rng.choice(["", *PEERS]), attempt=random_count(rng),
                               fraction=rng.choice([None, 0.0, 1.0, rng.random()]), detail=rng.choice(["", "x"]))
    return m.ProgramOutcome(request_id=random_count(rng), ok=rng.random() < 0.5, value=b"\x01", error="e",
                            error_kind=rng.choice(["", "program", "refused"]), host=rng.choice(["", *PEERS]),
                            attempts=random_count(rng), moves=random_count(rng),
                            resumed_from=rng.choice([None, 0.0, rng.random()]), missed_deadline=rng.random() < 0.2)


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
        return rng.choice(FLOATS)
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
    return ENCODER.encode(d)


def _wrong_shape(rng):
    return ENCODER.encode(random_object(rng))


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
    return ENCODER.encode(d)


def _bad_deadlines(rng: random.Random) -> bytes:
    """A message with a deadline field (``OffloadRequest.deadline_in``, ``SubmitProgram.deadline``,
    ``on_miss``, ``ProgramOutcome.missed_deadline``) set to a hostile value."""
    field = rng.choice(["deadline_in", "deadline", "on_miss", "missed_deadline"])
    msg: m.Message
    if field == "deadline_in":
        msg = m.OffloadRequest(program_id="a", attempt=1, origin="p", host=ME, program="noop", deadline_in=1.0)
    elif field == "missed_deadline":
        msg = m.ProgramOutcome(request_id=1, ok=True, missed_deadline=True)
    else:
        msg = m.SubmitProgram(client="p", request_id=1, program="noop", deadline=1.0, on_miss="fail")
    d = msgspec.to_builtins(m.Envelope(v=m.PROTOCOL_VERSION, sender=rng.choice(PEERS), msg=msg),
                            builtin_types=(bytes,))
    d["msg"][field] = rng.choice(WIRE_DEADLINES + ["x" * (m.MAX_NAME + 1), 1.5])
    return ENCODER.encode(d)


def _bad_battery(rng: random.Random) -> bytes:
    """A load report whose battery fields (``battery``, ``low_battery``,
    ``power``) hold a hostile value: only a charge 0..1, a boolean and
    finite watts 0..MAX_LOAD (or None) decode."""
    field = rng.choice(["battery", "low_battery", "power"])
    msg = random_report(rng, robot=rng.choice(PEERS))
    d = msgspec.to_builtins(m.Envelope(v=m.PROTOCOL_VERSION, sender=msg.robot, msg=msg), builtin_types=(bytes,))
    d["msg"][field] = rng.choice(WIRE_DEADLINES + [1.5, -0.5, 1.0 + 1e-9, m.MAX_LOAD * 2, "x", None, 0.5])
    return ENCODER.encode(d)


def oversized(rng):
    """Over the total limit (checked before parsing) or near it."""
    n = m.MAX_MESSAGE_BYTES + rng.choice([1, 2, 1000, 1 << 20])
    if rng.random() < 0.5:
        return b"\x00" * n
    # a real message whose arguments take it over the limit
    return m.encode("p", m.OffloadRequest(program_id="a", attempt=1, origin="p", host=ME, program="x",
                                          args=b"\x00" * n))


def big_fields(rng):
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
    ("bad_deadlines", 4, _bad_deadlines),
    ("bad_battery", 2, _bad_battery),
    ("huge_lengths", 3, _huge_lengths),
    ("ext_types", 2, _ext),
    ("deep_nesting", 1, _deep),
    ("pickle", 1, _pickled),
    ("json", 1, _json),
]
#: rare and costly (megabytes each): drawn once per this many wire inputs
OVERSIZED_EVERY = 500
BIG_FIELDS_EVERY = 1000


__all__ = ["BAD_DEADLINES", "BAD_ON_MISS", "BIG_FIELDS_EVERY", "ENCODER", "FLOATS", "GOOD_DEADLINES", "INTERESTING", "ME",
           "OVERSIZED_EVERY", "PEERS", "PROGRAMS", "PROGRAM_IDS", "REASONS", "WIRE_DEADLINES", "WIRE_KINDS",
           "big_fields", "oversized", "random_count", "random_deadline", "random_message", "random_object",
           "random_report"]
