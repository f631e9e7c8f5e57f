"""The durable record and a program's messages: offers and programs started
go out while the record of their round is written; nothing that tells a
client its program is taken, nor a host that its result is kept, goes
before it (``ramps.runtime.node_outbound.before_record``), and an outcome
goes before the acknowledgement of its result. The real driver and core
over the in-memory transport (``ramps.testing.memory``)."""

from __future__ import annotations

import msgspec

from ramps.core.events import Deliver, Note, PublishReport, Send, StartProgram
from ramps.core.messages import (
    LoadReport,
    OffloadAccepted,
    OffloadRequest,
    ProgramOutcome,
    ProgramResult,
    ResultAck,
    SubmitProgram,
    decode,
    encode,
)
from ramps.runtime import keys
from ramps.runtime.node_outbound import before_record
from ramps.testing.memory import MemoryTeam


def _offer(pid: str = "p") -> Send:
    return Send(to="r2", msg=OffloadRequest(program_id=pid, attempt=1, origin="r1", host="r2", program="echo",
                                            args=b"", work=1.0))


def test_only_what_tells_nobody_anything_goes_before_the_record():
    """``before_record`` counts the leading actions that tell no client and
    no host anything a restart must keep, and stops at the first other."""
    start = StartProgram(program_id="p", attempt=1, origin="r1", program="echo", args=b"", work=1.0)
    placed = Note(what="placed", program_id="p", robot="r2", attempt=1)
    accepted = Note(what="accepted", program_id="p", robot="r2", attempt=1)
    report = PublishReport(report=LoadReport(
        robot="r1", incarnation=1, seq=1, cores=1, speed=1.0, cpu_busy=0.0, runnable=0.0, ramps_running=0, ramps_avg=0.0,
        accepted_total=0, finished_total=0))
    host_said = Send(to="r1", msg=OffloadAccepted(program_id="q", attempt=1, host="r2", accept_seq=1))
    result = Send(to="r1", msg=ProgramResult(program_id="q", attempt=1, host="r2", ok=True))
    assert before_record([]) == 0
    assert before_record([placed, _offer(), start, accepted, report, host_said, result]) == 7
    ack = Send(to="r2", msg=ResultAck(program_id="p", attempt=1, origin="r1"))
    deliver = Deliver(program_id="p", ok=True, host="r2", attempts=1)
    assert before_record([placed, _offer(), ack, _offer("p2")]) == 2  # the ack waits, and all after it
    assert before_record([deliver, _offer()]) == 0
    # a failover is told to the client at once (``TOLD_AT_ONCE``): after the record
    assert before_record([_offer(), Note(what="failed", program_id="p", robot="r2", attempt=1)]) == 1
    assert before_record([Note(what="placed", program_id="p", robot="r3", attempt=2), _offer()]) == 0


def test_the_offer_goes_before_the_record_and_the_outcome_after_it(tmp_path):
    """The record of a placed program is written after its offer went; its
    outcome goes after the record of its delivery, and before the host's
    acknowledgement of its result."""
    team = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0)}, settings={"state_dir": str(tmp_path)})
    try:
        team.run(3.0)
        events: list[tuple[str, object]] = []
        store = team.nodes["r1"].store
        save, put = store.save, team.bus.put

        def saving(records, finished):
            events.append(("save", (sorted(records), [f[0] for f in finished])))
            save(records, finished)

        def putting(src, key, data):
            if key.startswith(keys.inbox(team.team, "")) or key == keys.client(team.team, "app"):
                events.append(("put", type(decode(data).msg).__name__))
            put(src, key, data)

        store.save, team.bus.put = saving, putting
        t = team.bus.transport("app")
        heard: list = []
        t.subscribe(keys.client(team.team, "app"), lambda data: heard.append(decode(data).msg))
        t.put(keys.inbox(team.team, "r1"), encode("app", SubmitProgram(
            client="app", request_id=1, program="echo", args=msgspec.msgpack.encode({"x": 1}), work=20.0)),
            block=True)
        team.run(30.0, until=lambda: any(isinstance(m, ProgramOutcome) for m in heard))
        [out] = [m for m in heard if isinstance(m, ProgramOutcome)]
        assert out.ok and out.host == "r2"  # heavy: offloaded to the faster robot
        seq = [e for e in events if e[0] == "save" or e[1] != "SubmitProgram"]
        saves = [i for i, e in enumerate(seq) if e[0] == "save"]
        [pid] = seq[saves[0]][1][0]
        offer = seq.index(("put", "OffloadRequest"))
        assert offer < saves[0]  # the offer went while its record was written
        assert seq[saves[-1]][1] == ([], [pid])  # then delivered: the program's row gives way to its outcome
        assert saves[-1] < seq.index(("put", "ProgramOutcome")) < seq.index(("put", "ResultAck"))  # the caller first
        assert store.programs() == 0
    finally:
        team.close()
