"""A node's side of its clients: submissions checked, outcomes sent once, answers again.

How this works: ``ClientAnswers`` is a part of the node's driver
(``ramps.runtime.node``), with the state it keeps of clients' requests,
given the parts it answers through; of the driver it reads only the core
and the node's incarnation (``ClientsDriver``). A client
(``ramps.connect()``) sends ``SubmitProgram`` to its robot's node;
``submit`` checks the program's name, arguments
(against its signature and annotated types, ``ramps.runtime.argtypes``),
policy and size before the core places anything,
so a bad call fails at the caller with a clear error and nothing runs. Each
request is one program however often it is resent; the node keeps recent
outcomes (``OUTCOMES_KEPT_BYTES``) and answers a request asked again with
where it stands or its outcome again. An outcome is sent once, held while
its client is not reachable (``OUTCOME_HOLD`` at most); progress updates are
advisory and dropped under congestion.

With a durable record (``--state-dir``, ``ramps.runtime.store``) every
program a client submitted here is written down with its request in the
driver round that placed it, after each change that a restart must know
(placed, moved, checkpointed), and replaced by its outcome before that is
sent: a node restarted after a crash resumes them (``restore``), answers
their clients' requests as the old one would, and sends each outcome once.
A round's offers and programs started go out while its record is written
(``ramps.runtime.node_outbound.before_record``); nothing that tells the
client its program is taken goes before it, so a program a node died
before writing down is one its client submits again.
"""

from __future__ import annotations

import logging
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import msgspec

from ramps.core.deadlines import ON_MISS
from ramps.core.durable import OriginRecord, program_of, record_of, same_to_restore
from ramps.core.events import (
    Action,
    Deliver,
    Submit,
)
from ramps.core.messages import (
    ProgramOutcome,
    ProgramUpdate,
    SubmitProgram,
    encode,
)
from ramps.core.policy import POLICIES
from ramps.core.program import FINAL, ProgramState
from ramps.errors import ProgramNotFound
from ramps.runtime import keys
from ramps.runtime.registry import decode_args
from ramps.runtime.transport import Clock, Publisher

if TYPE_CHECKING:
    from ramps.core.node import Node
    from ramps.runtime.node_awake import AwakeClock
    from ramps.runtime.node_outbox import Outbox
    from ramps.runtime.registry import Registry
    from ramps.runtime.settings import NodeSettings
    from ramps.runtime.store import OriginStore

log = logging.getLogger("ramps.node")
#: answered client requests remembered, so a resent submission is not run twice
ANSWERED_KEPT = 65536
#: bytes of recent outcomes kept, so one a client asks for again (its link
#: lapsed while it was sent: it went nowhere) is sent again
OUTCOMES_KEPT_BYTES = 16 * 1024 * 1024
#: seconds an outcome waits for its client to be reachable, and between two looks
OUTCOME_HOLD = 30.0
OUTCOME_RETRY = 0.05
#: seconds a program's update to its client waits (then its newest state goes):
#: most programs end sooner, and their outcome says all an update would; one
#: that runs longer is told within this (a client resends a submission that
#: nothing acknowledged only after ``ramps.runtime.pending.SUBMIT_RESEND``)
UPDATE_HOLD = 0.1
#: states a client hears at once, never folded into a later one: its program's
#: host failed and it is placed again (a ROS goal's feedback shows the failover)
TOLD_AT_ONCE = frozenset({"host_failed", "replaced"})
#: a client's request: (client, request id)
RequestKey = tuple[str, int]


class ClientsDriver(Protocol):
    """What a node's answers to its clients (``node_clients.ClientAnswers``)
    read of its driver: what the driver has once started."""

    node: Node | None
    incarnation: int


class ClientAnswers:
    """The answers of ``driver``'s node, of settings ``s``, to its clients,
    and what it keeps of them: it checks submissions against ``registry``
    and answers through ``outbox``."""

    def __init__(self, driver: ClientsDriver, s: NodeSettings, *, clock: Clock, awake: AwakeClock,
                 registry: Registry, outbox: Outbox) -> None:
        self.d = driver
        self.s, self.robot, self.team = s, s.robot, s.team
        self.clock, self.awake, self.registry, self.outbox = clock, awake, registry, outbox
        #: programs resumed from the durable record at start
        self.restored = 0
        #: client requests: program id -> request, and request -> program id, while they run
        self.clients: dict[str, RequestKey] = {}
        self.requests: dict[RequestKey, str] = {}
        #: requests already answered (the newest ANSWERED_KEPT), in answer order, with
        #: their outcome as sent while it is among the newest OUTCOMES_KEPT_BYTES
        self.answered: dict[RequestKey, bytes | None] = {}
        self._kept_outcomes: deque[RequestKey] = deque()
        self.kept_bytes = 0
        #: the newest progress of programs this node is origin of, until delivered
        self.progress: dict[str, tuple[float, str]] = {}
        self._seq = 0
        #: the durable record last written of each program not delivered yet, and the
        #: outcomes written to it that are about to be sent
        self._recorded: dict[str, OriginRecord] = {}
        self._outcomes_ready: dict[str, bytes] = {}
        #: outcomes waiting for their client to be reachable: (key, bytes, monotonic deadline, block)
        self.held_outcomes: list[tuple[str, bytes, float, bool]] = []
        #: clients' updates waiting for their moment, as they fall due: program id -> [core time, state, host, attempt]
        self.held_updates: dict[str, list[Any]] = {}
        #: publishers of clients' advisory updates (never blocking), apart from their outcomes' (blocking)
        self._update_pubs: dict[str, Publisher] = {}

    def restore(self, store: OriginStore, now: float) -> list[Action]:
        """Resume what the durable record holds (at start, before the driver runs)."""
        d = self.d
        assert d.node is not None
        found = store.load()
        prefix = f"{self.robot}#{d.incarnation % 100000}-"
        aps = []
        for pid, (client, rid, rec) in found.programs.items():
            self.requests[(client, rid)] = pid
            self.clients[pid] = (client, rid)
            self._recorded[pid] = rec
            aps.append(program_of(rec, now))
            if pid.startswith(prefix):  # an old incarnation's ids that this one's could repeat
                tail = pid[len(prefix):]
                self._seq = max(self._seq, int(tail) if tail.isdigit() else 0)
        for rkey, data in found.outcomes.items():
            self.answered[rkey] = data
        out: list[Action] = []
        d.node.origin.restore(aps, now, out)  # as recorded: nothing to write back
        if aps or found.skipped:
            log.warning("node %s resumed %d program(s) from its record %s%s", self.robot, len(aps), store.path,
                        f" ({found.skipped} unreadable, skipped)" if found.skipped else "")
        self.restored = len(aps)
        return out

    def persist(self, store: OriginStore, actions: list[Action]) -> None:
        """Write what changed to the durable record ``store``, before
        ``actions`` are applied: programs as they now stand, and the outcome
        of each one delivered (sent once written, by ``tell``)."""
        assert self.d.node is not None
        origin = self.d.node.origin
        if not origin.changed and not any(type(a) is Deliver for a in actions):
            return  # nothing to write (a host's rounds, most of an origin's)
        changed, origin.changed = origin.changed or set(), set()
        records = {}
        written = self._recorded
        for pid in changed:
            ap = origin.programs.get(pid)
            target = self.clients.get(pid)
            if ap is not None and target is not None and ap.state not in FINAL:
                rec = record_of(ap)
                old = written.get(pid)
                if old is None or not same_to_restore(old, rec):  # an acceptance alone needs no write
                    records[pid] = (target[0], target[1], rec)
                    written[pid] = rec
        finished = []
        for a in actions:
            if isinstance(a, Deliver):
                written.pop(a.program_id, None)
                target = self.clients.get(a.program_id)
                data = b""
                if target is not None:
                    t = self.as_told(a)
                    data = self._outcome(target[1], ok=t.ok, value=t.value, error=t.error, kind=t.error_kind,
                                         host=t.host, attempts=t.attempts, moves=t.moves, resumed_from=t.resumed_from,
                                         missed_deadline=t.missed_deadline)
                self._outcomes_ready[a.program_id] = data
                finished.append((a.program_id, target[0] if target else "", target[1] if target else 0, data))
        store.save(records, finished)

    def _outcome(self, request_id: int, *, ok: bool, value: bytes = b"", error: str = "", kind: str = "",
                 host: str = "", attempts: int = 0, moves: int = 0, resumed_from: float | None = None,
                 missed_deadline: bool = False) -> bytes:
        """A request's outcome, encoded as its client receives it."""
        return encode(self.robot, ProgramOutcome(
            request_id=request_id, ok=ok, value=value, error=error, error_kind=kind, host=host, attempts=attempts,
            moves=moves, resumed_from=resumed_from, missed_deadline=missed_deadline))

    def submit(self, m: SubmitProgram, now: float) -> list[Action]:
        """A client's submission: checked, then to the core, once per request."""
        d = self.d
        rkey = (m.client, m.request_id)
        if rkey in self.requests or rkey in self.answered:
            # a repeated request (clients resend until acknowledged, and ask again after
            # their link to this node lapsed): one program per request; answer where it stands
            return self._answer_again(rkey)
        self._seq += 1
        pid = f"{self.robot}#{d.incarnation % 100000}-{self._seq}"
        self.requests[rkey] = pid
        self.clients[pid] = rkey
        if len(m.args) > self.s.max_args_bytes:  # before anything is decoded
            return self.tell(pid, ok=False, kind="bad_arguments",
                             error=f"arguments are {len(m.args)} bytes; the limit is {self.s.max_args_bytes}")
        try:
            spec = self.registry.get(m.program)
            kwargs = decode_args(m.args)
            spec.check_args(kwargs)
            work = m.work or spec.declared_work(kwargs)
            accelerator = m.accelerator or spec.accelerator
            accelerator_work = (m.accelerator_work or spec.declared_accelerator_work(kwargs)) if accelerator else 0.0
        except ProgramNotFound as exc:
            return self.tell(pid, ok=False, error=str(exc), kind="refused", host=self.robot)
        except Exception as exc:  # signature mismatch, undecodable arguments
            return self.tell(pid, ok=False, kind="bad_arguments", error=f"bad arguments for program {m.program!r}: {exc}")
        if m.policy and m.policy not in POLICIES:
            return self.tell(pid, ok=False, kind="bad_arguments",
                             error=f"unknown policy {m.policy!r}; choose one of {', '.join(POLICIES)}")
        on_miss = m.on_miss or "run"
        if on_miss not in ON_MISS:
            return self.tell(pid, ok=False, kind="bad_arguments",
                             error=f"unknown on_miss {m.on_miss!r}; choose one of {', '.join(ON_MISS)}")
        assert d.node is not None
        return d.node.handle(Submit(
            program_id=pid, program=m.program, args=m.args, payload_size=len(m.args),
            work=work, result_size=m.result_size or spec.result,
            local_only=m.local_only or spec.local_only, policy=m.policy, memory=spec.memory,
            deadline=None if m.deadline is None else now + m.deadline, on_miss=on_miss,
            accelerator=accelerator, accelerator_work=accelerator_work,
            cpu_fallback=(m.cpu_fallback and spec.cpu_fallback) or not accelerator,
        ), now)

    def deliver(self, a: Deliver) -> None:
        """The core delivers a program's outcome: its client is told (as ``as_told``)."""
        t = self.as_told(a)
        self.tell(t.program_id, ok=t.ok, value=t.value, error=t.error, kind=t.error_kind, host=t.host,
                  attempts=t.attempts, moves=t.moves, resumed_from=t.resumed_from, missed_deadline=t.missed_deadline)

    def as_told(self, a: Deliver) -> Deliver:
        """An outcome as its client is told it: a program cancelled because
        this node is shutting down ends as ``shutdown``."""
        assert self.d.node is not None
        if self.d.node.executor.closing and a.error_kind == "cancelled":
            return msgspec.structs.replace(a, error_kind="shutdown", error=f"origin {self.robot} shut down")
        return a

    def tell(self, pid: str, *, ok: bool, value: bytes = b"", error: str = "", kind: str = "",
             host: str = "", attempts: int = 0, moves: int = 0, resumed_from: float | None = None,
             missed_deadline: bool = False) -> list[Action]:
        """Send program ``pid``'s outcome to its client, once, and keep it for a request asked again."""
        target = self.clients.pop(pid, None)
        if target is None:
            return []
        self.held_updates.pop(pid, None)  # the outcome says all of it
        client, request_id = target
        self.requests.pop(target, None)
        self.progress.pop(pid, None)
        data = self._outcomes_ready.pop(pid, None) or self._outcome(  # the one written to the record, if any
            request_id, ok=ok, value=value, error=error, kind=kind, host=host, attempts=attempts, moves=moves,
            resumed_from=resumed_from, missed_deadline=missed_deadline)
        self.answered[target] = data  # a resend still in flight must not run it again
        self._kept_outcomes.append(target)
        self.kept_bytes += len(data)
        while self._kept_outcomes and (self.kept_bytes > OUTCOMES_KEPT_BYTES
                                       or len(self._kept_outcomes) > ANSWERED_KEPT):
            old_key = self._kept_outcomes.popleft()
            old = self.answered.get(old_key)
            if old is not None:
                self.kept_bytes -= len(old)
                self.answered[old_key] = None
        if len(self.answered) > ANSWERED_KEPT:
            old = self.answered.pop(next(iter(self.answered)))
            self.kept_bytes -= len(old) if old is not None else 0
        self.send_outcome(keys.client(self.team, client), data)
        return []

    def _answer_again(self, rkey: tuple[str, int]) -> list[Action]:
        """A client asked again about a request: its program's state if it
        runs (an update acknowledges the request), its outcome again if this
        node still keeps it (the first may have gone nowhere: the client's
        link lapsed while this node was stalled, and Zenoh may still report a
        match through another peer), else an outcome saying it is lost."""
        pid = self.requests.get(rkey)
        if pid is not None:
            assert self.d.node is not None
            ap = self.d.node.origin.programs.get(pid)
            if ap is None:
                self._send_update(pid, "placed", "", 0)
            else:
                self._send_update(pid, "running" if ap.state is ProgramState.RUNNING else "placed",
                                    ap.host or "", ap.attempt)
            return []
        data = self.answered.get(rkey)
        robot = self.robot
        if data is None:
            data = encode(robot, ProgramOutcome(
                request_id=rkey[1], ok=False, error_kind="", host=robot, attempts=0,
                error=f"node {robot} answered this request long ago and no longer keeps its outcome"))
        self.send_outcome(keys.client(self.team, rkey[0]), data)
        return []

    def send_outcome(self, key: str, data: bytes) -> None:
        """An outcome is sent once, never resent. If no subscriber of that
        client matches its key right now (after this node stalled, the
        client's link to it is being rebuilt: an outcome published then was
        lost, and the client waited for ever), it is held until one does, for
        OUTCOME_HOLD at most, then sent regardless."""
        until, block = self.clock.monotonic() + OUTCOME_HOLD, True
        if any(k == key for k, _, _, _ in self.held_outcomes) or not self.outbox.reachable(key, block):
            self.held_outcomes.append((key, data, until, block))
            return
        self.outbox.put(key, data, block=block)

    def held_due(self, now: float) -> float:
        """The core's time at which something held is due: an outcome to look
        at again, a client's update (inf: none)."""
        due = now + OUTCOME_RETRY if self.held_outcomes else float("inf")
        if self.held_updates:
            due = min(due, next(iter(self.held_updates.values()))[0])
        return due

    def flush(self, now: float) -> None:
        """Send what is held and due by the core's time ``now``."""
        if self.held_outcomes:
            self.flush_outcomes()
        if self.held_updates:
            self._flush_updates(now)

    def flush_outcomes(self, *, leaving: bool = False) -> None:
        """Send what was held, per key in order, once its receiver is
        reachable or its time is up; every one when this node is ``leaving``
        (the last chance to send them)."""
        held, self.held_outcomes = self.held_outcomes, []
        now = self.clock.monotonic()
        waiting: set[str] = set()
        for key, data, until, block in held:
            if not leaving and (key in waiting or (now < until and not self.outbox.reachable(key, block))):
                waiting.add(key)
                self.held_outcomes.append((key, data, until, block))
            else:
                self.outbox.put(key, data, block=block)

    def progressed(self, pid: str, fraction: float, detail: str, host: str, attempt: int) -> None:
        """Program ``pid`` reported its progress: its client is told (``update``)."""
        self.progress[pid] = (fraction, detail)
        self.update(pid, "progress", host, attempt)

    def update(self, pid: str, state: str, host: str, attempt: int) -> None:
        """Tell the program's client where it stands, ``UPDATE_HOLD`` seconds
        from the first change not yet told: the newest state then, and none
        if its outcome went first (advisory; see ProgramUpdate); a failover
        (``TOLD_AT_ONCE``) at once."""
        if state in TOLD_AT_ONCE:  # a failover is news the client must see, whatever follows it
            self._send_update(pid, state, host, attempt)
            return
        held = self.held_updates.get(pid)
        if held is not None:
            held[1:] = [state, host, attempt]
        elif pid in self.clients:
            self.held_updates[pid] = [self.awake.now() + UPDATE_HOLD, state, host, attempt]

    def _flush_updates(self, now: float) -> None:
        """Send the held updates that are due by the core's time ``now``
        (held in the order they are due)."""
        held = self.held_updates
        while held:
            pid, (due, state, host, attempt) = next(iter(held.items()))
            if due > now:
                return
            del held[pid]
            self._send_update(pid, state, host, attempt)

    def _send_update(self, pid: str, state: str, host: str, attempt: int) -> None:
        """Tell the program's client where it stands now (advisory; see ProgramUpdate)."""
        self.held_updates.pop(pid, None)
        target = self.clients.get(pid)
        if target is None or not self.outbox.connected():
            return
        fraction, detail = self.progress.get(pid, (None, ""))
        data = encode(self.robot, ProgramUpdate(request_id=target[1], state=state, host=host, attempt=attempt,
                                                fraction=fraction, detail=detail))
        try:  # advisory: dropped rather than let a stalled client stall this driver (outcomes block)
            self.outbox.publisher(keys.client(self.team, target[0]), False, self._update_pubs).put(data)
        except Exception as exc:
            log.debug("node %s could not send a program update: %s", self.robot, exc)


def close_record(store: OriginStore) -> None:
    """Close the durable record; with nothing in it to resume, leave no file
    behind (nor the team's folder, if it was the last)."""
    keep = store.programs()
    store.close()
    if not keep:
        for suffix in ("", "-wal", "-shm", ".lock"):
            Path(str(store.path) + suffix).unlink(missing_ok=True)
        try:
            store.path.parent.rmdir()
        except OSError:
            pass
