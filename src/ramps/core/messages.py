"""Wire messages: everything one robot says to another.

How this works: every message is a frozen msgspec Struct, tagged by ``type``,
carried in an ``Envelope`` that names the protocol version and the sender.
``encode`` / ``decode`` are the only way bytes become messages: the size is
checked before anything is parsed, the major version before the body, and every
field against the limits its type declares (name and text lengths, payload
sizes, list lengths, non-negative counts, finite floats, the physical bounds
of a load report), which msgspec enforces while decoding. Anything that does
not fit raises ``WireError`` and nothing else (a remote-input error: the
receiver counts it and drops it; it never takes a node down). Nothing is ever
unpickled; program arguments and results travel as opaque ``bytes`` that the
program's own schema decodes. Limits bind the receiver only: ``encode`` does
not check them, so a sender stays cheap.

Versions (docs/wire-compatibility.md): the protocol is major.minor. Nodes of
one major share a team whatever their minors: a decoder ignores fields it
does not know, ``encode`` leaves out every field at its default (so a
message that uses nothing newer decodes even on protocol 1.0, ramps 0.1.0,
which refuses unknown fields), and a message type it does not know is
``UnknownMessageType``, skipped and counted. A message of another major is
``VersionRefused``, naming both versions; neither is "malformed". Fields
and types are never renamed, removed, retyped or given new defaults within
a major; tests/golden holds every message as each release encoded it.

Message flow (origin = the robot that submitted the program, host = the
robot that runs it; a robot is both at once for its local programs):

    every robot  --LoadReport-->      every load server   (periodic, broadcast)
    origin       --OffloadRequest-->  host
    host         --OffloadAccepted--> origin   or  --OffloadRejected--> origin
    host         --Heartbeat-->       origin   (periodic while programs run)
    host         --ProgramResult-->   origin   (resent until acknowledged)
    origin       --ResultAck-->       host
    origin       --CancelProgram-->   host     (program done elsewhere / moved)
    host         --ProgramProgress--> origin   (what the program reported, with heartbeats)
    host         --ProgramCheckpoint--> origin (the program's latest saved state, for a restart)
    robot        --LinkProbe-->       teammate --LinkProbeReply--> robot  (T_comm: latency, bandwidth)

and between an application (client) and its robot's node:

    client       --SubmitProgram-->   node     --ProgramOutcome--> client  (exactly one)
    client       --CancelSubmitted--> node     --ProgramUpdate-->  client  (placed, running, progress)
"""

from __future__ import annotations

import re
from typing import Annotated, NoReturn, Union

import msgspec
from msgspec import Meta

from ramps.core.wirelimits import (  # the limits and field types, re-exported: ``messages.MAX_CORES`` etc.
    MAX_MESSAGE_BYTES as MAX_MESSAGE_BYTES, MAX_NAME as MAX_NAME, MAX_TEXT as MAX_TEXT,
    MAX_OUTCOME_TEXT as MAX_OUTCOME_TEXT, MAX_REFS as MAX_REFS, MAX_CORES as MAX_CORES, MIN_SPEED as MIN_SPEED,
    MAX_SPEED as MAX_SPEED, MAX_LOAD as MAX_LOAD, MIN_WEIGHT as MIN_WEIGHT, MAX_WEIGHT as MAX_WEIGHT,
    MAX_PROGRESS_TEXT as MAX_PROGRESS_TEXT, MAX_LISTED as MAX_LISTED, MAX_CHECKPOINT_BYTES as MAX_CHECKPOINT_BYTES,
    MAX_ACCELERATOR_KINDS as MAX_ACCELERATOR_KINDS, MAX_PROBE_BYTES as MAX_PROBE_BYTES, RobotName as RobotName,
    OptRobotName as OptRobotName, Name as Name, Word as Word, Text as Text, Payload as Payload, Count as Count,
    Amount as Amount, Load as Load, Weight as Weight, Cores as Cores, Speed as Speed, Fraction as Fraction,
    ProgressText as ProgressText, CheckpointState as CheckpointState, ListedRobotName, KEY_UNSAFE,
)
from ramps.core.wirebase import (  # re-exported: ``messages.WireError`` etc.
    PROTOCOL_MAJOR as PROTOCOL_MAJOR, PROTOCOL_MINOR as PROTOCOL_MINOR, PROTOCOL_VERSION as PROTOCOL_VERSION,
    PROTOCOL as PROTOCOL, WireError as WireError, VersionRefused as VersionRefused,
    UnknownMessageType as UnknownMessageType, Record as _Msg, DECODE_ERRORS, head_decoder, refused, why,
)
from ramps.core.client_messages import (  # re-exported: one schema, ``messages.SubmitProgram`` etc.
    SubmitProgram as SubmitProgram, CancelSubmitted as CancelSubmitted, ProgramOutcome as ProgramOutcome,
    ProgramUpdate as ProgramUpdate,
)
from ramps.core.claim_messages import BurstClaim as BurstClaim, ClaimedPool as ClaimedPool  # re-exported


class LoadReport(_Msg, frozen=True, kw_only=True, tag="load"):
    """A robot's load, as published by its load publisher."""

    robot: RobotName
    #: changes whenever the node restarts, so a report from a new life of a
    #: robot is recognised even though its sequence numbers start over; since
    #: 0.2.0 the node's start time then random bits, so of two nodes under one
    #: name the one started later has the larger (``ramps.core.identity``)
    incarnation: Count
    seq: Count
    cores: Cores
    #: work units per second per core when the core is free
    speed: Speed
    #: busy cores averaged over the window (0..cores): the paper's CPU load
    cpu_busy: Load
    #: runnable tasks averaged over the window (run-queue length, like loadavg)
    runnable: Load
    #: ramps programs running at the moment of the report, and averaged
    ramps_running: Count
    ramps_avg: Load
    #: monotonic counts of programs this incarnation accepted / finished, so
    #: an origin can tell which of its bookings a report already includes
    accepted_total: Count
    finished_total: Count
    window: Load = 1.0
    #: bytes of memory available to new programs
    mem_free: Count = 0
    #: CPU use of each core over the window (0..1), and the 1-minute load average
    cpu_per_core: Annotated[list[Load], Meta(max_length=MAX_CORES)] = []
    load_avg: Load = 0.0
    #: robots this robot's load server has written off (for ``ramps status``)
    blacklisted: Annotated[list[RobotName], Meta(max_length=MAX_REFS)] = []
    #: messages this node dropped since it started (undecodable, another
    #: major protocol version, an unknown type, a load report about another robot)
    bad_messages: Count = 0
    #: the scheduler weight of this robot's ramps programs against its own
    #: software (CFS: nice 10 workers weigh 110/1024 of a nice-0 process), so
    #: an origin knows what share a program gets next to a busy robot's work
    program_weight: Weight = 1.0
    #: teammates this robot could place a program on when it reported (a
    #: fresh report, neither blacklisted nor lost; on a robot that places
    #: nothing, and so hears no periodic reports, those whose liveliness it
    #: holds), so ``ramps status`` shows a robot that does not see the whole
    #: team; None where not counted
    sees: Count | None = None
    #: the programs running here (at most MAX_LISTED), with their progress,
    #: for ``ramps status`` and the ROS face's diagnostics
    running: Annotated[list["RunningProgram"], Meta(max_length=MAX_LISTED)] = []
    #: work units each running program has left by the host's estimate
    #: (processor sharing since it started), smallest first: an origin's
    #: T_there counts the programs that will end before a new one does
    remaining: Annotated[list[Amount], Meta(max_length=MAX_LISTED)] = []
    #: what this robot measured of its links to teammates (``ramps.core.links``)
    #: and learned of its programs' work (at most MAX_LISTED each), for ``ramps status``
    links: Annotated[list["LinkSeen"], Meta(max_length=MAX_LISTED)] = []
    learned: Annotated[list["LearnedWork"], Meta(max_length=MAX_LISTED)] = []
    #: cores of this robot its node itself used (its threads, not its programs),
    #: averaged over about 10 s: the cost model takes them off the cores a
    #: full robot's programs share (``LoadView.scan``)
    node_cpu: Load = 0.0
    #: programs of this robot moved while running since it started, and moves
    #: abandoned (the new host refused or failed), for ``ramps status``
    moves: Count = 0
    moves_aborted: Count = 0
    #: the accelerators this robot advertises, with the programs on each
    #: (``ramps.core.accelerators``); empty on a robot without any
    accelerators: Annotated[list["AcceleratorSeen"], Meta(max_length=MAX_ACCELERATOR_KINDS)] = []
    #: this robot's battery, its state of charge 0..1 (None: it reports
    #: none), and whether it is below its battery reserve: it then takes no
    #: teammates' programs, and origins leave it out (``ramps.core.battery``)
    battery: Fraction | None = None
    low_battery: bool = False
    #: watts one busy core of this robot draws (None: not known), which
    #: placement weighs with ``RampsConfig.energy_weight``
    power: Load | None = None
    #: this robot's hardware class (its CPU model, or what its operator set)
    #: and its own work units per CPU second, before pooling: robots of one
    #: class go by their median when they differ by no more than noise
    #: (``ramps.core.speed.SpeedClass``). In reports of the instant only
    #: (``Node.current_report``); None in the rest
    speed_class: Name | None = None
    cpu_rate: Speed | None = None
    #: an application submits programs on this robot: its bursts may claim
    #: pools (``ramps.core.claims``). In reports of the instant only
    submits: bool = False


class AcceleratorSeen(msgspec.Struct, frozen=True, array_like=True):
    """One kind of accelerator as a load report lists it: [kind, slots, work units per second per slot,
    ramps programs on it now, device memory in bytes (total, free; 0 = not measured), utilisation 0..1
    (None = not measured), the work units each program on it has left by the host's estimate, smallest
    first (``LoadReport.remaining`` for its slots; [] from nodes that do not tell)]."""

    kind: Name
    count: Annotated[int, Meta(ge=1, le=MAX_CORES)]
    speed: Speed
    running: Count = 0
    memory_total: Count = 0
    memory_free: Count = 0
    utilisation: Fraction | None = None
    remaining: Annotated[list[Amount], Meta(max_length=MAX_LISTED)] = []


class LinkSeen(msgspec.Struct, frozen=True, array_like=True):
    """A teammate as a load report lists it: [teammate, one-way latency in
    s, bandwidth in bytes/s, how fast it runs programs relative to the speed
    it reports, as this robot's results showed (``ramps.core.speed``)], None
    where not measured (or not corrected) yet."""

    robot: RobotName
    latency: Amount | None = None
    bandwidth: Amount | None = None
    speed_factor: Amount | None = None


class LearnedWork(msgspec.Struct, frozen=True, array_like=True):
    """A program's work as its origin learned it from completed runs: [program, work units]."""

    program: Name
    work: Amount


class RunningProgram(msgspec.Struct, frozen=True, array_like=True):
    """A program a host runs, as its load report lists it: [program, origin, progress].
    ``decode`` checks ``origin`` against RobotName's pattern once for the whole list."""

    program: Name
    origin: ListedRobotName
    #: the newest progress it reported, None before any
    progress: Fraction | None = None


class OffloadRequest(_Msg, frozen=True, kw_only=True, tag="offload"):
    program_id: Name
    attempt: Count
    origin: RobotName
    host: RobotName
    program: Name
    args: Payload = b""
    #: declared size of the parameters (equals len(args) on a real robot)
    payload_size: Count = 0
    #: the origin's estimate of the work, so the host can report progress
    work: Amount = 0.0
    #: ramps negotiation: runnable tasks the origin expects on the host when
    #: the program arrives; None = no admission check (other policies)
    expected_runnable: Amount | None = None
    #: ramps negotiation: the longest computation here (seconds) that still
    #: beats the best other robot the origin could use; a host busier than
    #: expected still takes the program if it computes it within this time
    #: (eq. 1 checked against the host's true load)
    time_budget: Amount | None = None
    #: set after too many rejections: the host must take it
    force: bool = False
    #: the program's last checkpoint (a move or a restart after a failure):
    #: the program reads it with ``ramps.resume()``; None = a fresh start
    resume: CheckpointState | None = None
    #: how far the program was when it saved ``resume`` (``work`` is what is left)
    resume_fraction: Fraction = 0.0
    #: seconds left before the program's deadline when the origin sent this
    #: (relative: the robots' clocks are not compared); a host that expects
    #: to finish later turns it away ("late"). None: no deadline, or the
    #: origin runs it here whether in time or not. Added in protocol 1.1
    deadline_in: Amount | None = None
    #: run it on this kind of accelerator here ("" = on a CPU); ``work`` is
    #: then its work there. A host without one turns it away ("accelerator")
    accelerator: Word = ""


class OffloadAccepted(_Msg, frozen=True, kw_only=True, tag="accept"):
    program_id: Name
    attempt: Count
    host: RobotName
    #: the host's accepted_total after taking this program
    accept_seq: Count


class OffloadRejected(_Msg, frozen=True, kw_only=True, tag="reject"):
    program_id: Name
    attempt: Count
    host: RobotName
    #: "busy" (try elsewhere now), "unknown_program", "bad_request" (permanent)
    reason: Word
    permanent: bool
    detail: Text = ""
    #: the host's load right now, so the origin can place with fresh data
    report: LoadReport | None = None


class ProgramRef(msgspec.Struct, frozen=True, array_like=True):
    program_id: Name
    attempt: Count


class Heartbeat(_Msg, frozen=True, kw_only=True, tag="heartbeat"):
    host: RobotName
    incarnation: Count
    programs: Annotated[list[ProgramRef], Meta(max_length=MAX_REFS)]


class ProgramResult(_Msg, frozen=True, kw_only=True, tag="result"):
    program_id: Name
    attempt: Count
    host: RobotName
    ok: bool
    value: Payload = b""
    error: Text = ""
    result_size: Count = 0
    #: the worker died under the program (killed, out of memory): not the
    #: program's own error, so the origin places it again
    retryable: bool = False
    #: the host's finished_total after this program ended
    finish_seq: Count = 0
    #: the work the program took by the host's estimate (its run time times
    #: the share of a core processor sharing gave it, in work units), which
    #: the origin learns from; None where the host did not estimate it
    work_done: Amount | None = None
    #: (with ``retryable``) the program's worker died by itself while the
    #: host lived, how is in ``error`` (``ProgramFinished.worker_died``): the
    #: origin counts it towards calling the program a poison pill. Added in
    #: protocol 1.1; an origin that ignores it places the program again
    worker_died: bool = False


class ResultAck(_Msg, frozen=True, kw_only=True, tag="ack"):
    program_id: Name
    attempt: Count
    origin: RobotName


class CancelProgram(_Msg, frozen=True, kw_only=True, tag="cancel"):
    program_id: Name
    attempt: Count
    origin: RobotName


class ProgramProgress(_Msg, frozen=True, kw_only=True, tag="progress"):
    """A running program said how far it is (host -> origin, at most once a
    heartbeat period per program; advisory: never resent)."""

    program_id: Name
    attempt: Count
    host: RobotName
    fraction: Fraction
    detail: ProgressText = ""


class ProgramCheckpoint(_Msg, frozen=True, kw_only=True, tag="checkpoint"):
    """A running program saved its state (host -> origin): the origin keeps
    the latest and sends it with the program when it moves or restarts
    after a failure, so the program resumes instead of starting over."""

    program_id: Name
    attempt: Count
    host: RobotName
    state: CheckpointState
    #: the program's progress when it saved, None if it never reported any
    fraction: Fraction | None = None


class LinkProbe(_Msg, frozen=True, kw_only=True, tag="probe"):
    """How long a message takes to a teammate and back (``ramps.core.links``);
    ``sent_at`` is the sender's own clock, echoed, and ``padding`` bytes
    (sometimes) measure the link's bandwidth."""

    sent_at: Amount
    padding: Annotated[bytes, Meta(max_length=MAX_PROBE_BYTES)] = b""


class LinkProbeReply(_Msg, frozen=True, kw_only=True, tag="probe_reply"):
    sent_at: Amount
    #: padding bytes the probe carried
    size: Annotated[int, Meta(ge=0, le=MAX_PROBE_BYTES)] = 0


Message = Union[
    LoadReport,
    OffloadRequest,
    OffloadAccepted,
    OffloadRejected,
    Heartbeat,
    ProgramResult,
    ResultAck,
    CancelProgram,
    SubmitProgram,
    CancelSubmitted,
    ProgramOutcome,
    ProgramProgress,
    ProgramUpdate,
    LinkProbe,
    LinkProbeReply,
    ProgramCheckpoint,
    BurstClaim,
]


class Envelope(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    v: int
    sender: RobotName
    msg: Message


class _TypeOnly(msgspec.Struct):
    type: Annotated[str, Meta(max_length=MAX_NAME)]


class _Unknown(msgspec.Struct):
    """An envelope of this major whose message type is all that is read."""

    v: int
    sender: RobotName
    msg: _TypeOnly


#: every message type this node knows, by its tag
KNOWN_TYPES: frozenset[str] = frozenset(t.__struct_config__.tag for t in Message.__args__)  # type: ignore[attr-defined]



class _CheckedRunningProgram(RunningProgram, frozen=True, array_like=True):
    """RunningProgram with RobotName's pattern on its origin, as msgspec checks it (``_refuse``)."""

    origin: RobotName


class _CheckedLoadReport(LoadReport, frozen=True, kw_only=True, tag="load"):
    running: Annotated[list[_CheckedRunningProgram], Meta(max_length=MAX_LISTED)] = []  # type: ignore[assignment]


#: every message, load reports with their listed origins' pattern checked by msgspec
_CheckedMessage = Union[tuple(_CheckedLoadReport if t is LoadReport else t for t in Message.__args__)]  # type: ignore


class _CheckedEnvelope(msgspec.Struct, frozen=True, kw_only=True):
    v: int
    sender: RobotName
    msg: _CheckedMessage  # type: ignore[valid-type]


_encoder = msgspec.msgpack.Encoder()
_envelope_decoder = msgspec.msgpack.Decoder(Envelope)
_checked_decoder = msgspec.msgpack.Decoder(_CheckedEnvelope)
_unknown_decoder = msgspec.msgpack.Decoder(_Unknown)
#: how msgspec words a value outside its field's declared limits
_CONSTRAINT = re.compile(r"Expected `[a-z]+` (of length|matching|[<>]=?)")


def encode(sender: str, msg: Message) -> bytes:
    """Encode a message for the wire: ``v`` is the major, and fields at their
    defaults are left out (what a 1.0 node can decode, docs/wire-compatibility.md)."""
    return _encoder.encode(Envelope(v=PROTOCOL_MAJOR, sender=sender, msg=msg))


def decode(data: bytes, *, max_bytes: int = MAX_MESSAGE_BYTES) -> Envelope:
    """Decode bytes from the network, or raise WireError saying why not.

    In order: the size (before anything is parsed), the major version
    (another version's message is ``VersionRefused`` naming both), then the
    body against the schema with every field's limits; fields this node does
    not know are ignored, and a type it does not know is
    ``UnknownMessageType``. The envelope is parsed once when it is good; only
    bytes it refuses are read again (``_refuse``) to say why, as the full
    check words it."""
    if len(data) > max_bytes:
        raise WireError(f"message of {len(data)} bytes exceeds the limit of {max_bytes} bytes")
    try:
        env = _envelope_decoder.decode(data)
    except DECODE_ERRORS:
        _refuse(data)
    msg = env.msg
    if env.v != PROTOCOL_MAJOR or (
            type(msg) is LoadReport and msg.running and KEY_UNSAFE.search("".join([r.origin for r in msg.running]))):
        _refuse(data)
    return env


def _refuse(data: bytes) -> NoReturn:
    """Raise the WireError for bytes ``decode`` refuses: the version first
    (read from the head alone), then the body against the full schema
    (``_checked_decoder``: RobotName's pattern on every listed origin too), so
    the error names the first field that breaks a limit in the order it came."""
    try:
        head = head_decoder.decode(data)
    except DECODE_ERRORS as exc:
        raise WireError(f"not a ramps message: {why(exc)}") from exc
    if head.v != PROTOCOL_MAJOR:
        raise refused(head)
    try:
        _checked_decoder.decode(data)
    except DECODE_ERRORS as exc:
        if isinstance(exc, msgspec.ValidationError):
            if _CONSTRAINT.match(str(exc)):
                raise WireError(f"ramps message field out of bounds: {exc}") from exc
            unknown = _unknown_type(data)
            if unknown is not None:
                raise unknown from exc
        raise WireError(f"malformed ramps message: {why(exc)}") from exc
    raise WireError("malformed ramps message")  # pragma: no cover (the full check takes less than decode)


def _unknown_type(data: bytes) -> UnknownMessageType | None:
    """A well-formed envelope of this major whose message type is unknown
    here (a newer minor's), or None if the failure was anything else."""
    try:
        env = _unknown_decoder.decode(data)
    except DECODE_ERRORS:
        return None
    if env.msg.type in KNOWN_TYPES:
        return None
    return UnknownMessageType(
        f"unknown message type {env.msg.type!r} from {env.sender!r} (a newer protocol {PROTOCOL_MAJOR}.x "
        f"node's, skipped; this node speaks {PROTOCOL})", tag=env.msg.type, sender=env.sender)
