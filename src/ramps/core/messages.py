"""Wire messages: everything one robot says to another.

How this works: every message is a frozen msgspec Struct, tagged by ``type``,
carried in an ``Envelope`` that names the protocol version and the sender.
``encode`` / ``decode`` are the only way bytes become messages: the size is
checked before anything is parsed, the version before the body, and anything
that does not fit the schema raises ``WireError`` (a remote-input error: the
receiver counts it and drops it; it never takes a node down). Nothing is ever
unpickled; program arguments and results travel as opaque ``bytes`` that the
program's own schema decodes.

Message flow (origin = the robot that submitted the program, host = the
robot that runs it; a robot is both at once for its local programs):

    every robot  --LoadReport-->      every load server   (periodic, broadcast)
    origin       --OffloadRequest-->  host
    host         --OffloadAccepted--> origin   or  --OffloadRejected--> origin
    host         --Heartbeat-->       origin   (periodic while programs run)
    host         --ProgramResult-->   origin   (resent until acknowledged)
    origin       --ResultAck-->       host
    origin       --CancelProgram-->   host     (program done elsewhere / moved)
"""

from __future__ import annotations

from typing import Union

import msgspec

PROTOCOL_VERSION = 1

#: largest encoded message a node accepts, bytes (arguments included)
MAX_MESSAGE_BYTES = 8 * 1024 * 1024
MAX_NAME = 128
MAX_TEXT = 4096
MAX_REFS = 100_000


class WireError(ValueError):
    """Bytes from the network that are not a valid message of this protocol."""


class _Msg(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True, tag_field="type"):
    pass


Name = msgspec.Meta(min_length=1, max_length=MAX_NAME)


class LoadReport(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="load"):
    """A robot's load, as published by its load publisher."""

    robot: str
    #: changes whenever the node restarts, so a report from a new life of a
    #: robot is recognised even though its sequence numbers start over
    incarnation: int
    seq: int
    cores: int
    #: work units per second per core when the core is free
    speed: float
    #: busy cores averaged over the window (0..cores): the paper's CPU load
    cpu_busy: float
    #: runnable tasks averaged over the window (run-queue length, like loadavg)
    runnable: float
    #: ramps programs running at the moment of the report, and averaged
    ramps_running: int
    ramps_avg: float
    #: monotonic counts of programs this incarnation accepted / finished, so
    #: an origin can tell which of its bookings a report already includes
    accepted_total: int
    finished_total: int
    window: float = 1.0
    #: bytes of memory available to new programs
    mem_free: int = 0
    #: CPU use of each core over the window (0..1), and the 1-minute load average
    cpu_per_core: list[float] = []
    load_avg: float = 0.0
    #: robots this robot's load server has written off (for ``ramps status``)
    blacklisted: list[str] = []


class OffloadRequest(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="offload"):
    program_id: str
    attempt: int
    origin: str
    host: str
    program: str
    args: bytes = b""
    #: declared size of the parameters (equals len(args) on a real robot)
    payload_size: int = 0
    #: the origin's estimate of the work, so the host can report progress
    work: float = 0.0
    #: ramps negotiation: runnable tasks the origin expects on the host when
    #: the program arrives; None = no admission check (other policies)
    expected_runnable: float | None = None
    #: set after too many rejections: the host must take it
    force: bool = False


class OffloadAccepted(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="accept"):
    program_id: str
    attempt: int
    host: str
    #: the host's accepted_total after taking this program
    accept_seq: int


class OffloadRejected(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="reject"):
    program_id: str
    attempt: int
    host: str
    #: "busy" (try elsewhere now), "unknown_program", "bad_request" (permanent)
    reason: str
    permanent: bool
    detail: str = ""
    #: the host's load right now, so the origin can place with fresh data
    report: LoadReport | None = None


class ProgramRef(msgspec.Struct, frozen=True, array_like=True):
    program_id: str
    attempt: int


class Heartbeat(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="heartbeat"):
    host: str
    incarnation: int
    programs: list[ProgramRef]


class ProgramResult(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="result"):
    program_id: str
    attempt: int
    host: str
    ok: bool
    value: bytes = b""
    error: str = ""
    result_size: int = 0
    #: the worker died under the program (killed, out of memory): not the
    #: program's own error, so the origin places it again
    retryable: bool = False
    #: the host's finished_total after this program ended
    finish_seq: int = 0


class ResultAck(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="ack"):
    program_id: str
    attempt: int
    origin: str


class CancelProgram(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="cancel"):
    program_id: str
    attempt: int
    origin: str


class SubmitProgram(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="submit"):
    """An application (client) asks its robot's node to run a program."""

    client: str
    request_id: int
    program: str
    args: bytes = b""
    #: expected work in work units (from the program's profile), 0 = default
    work: float = 0.0
    result_size: int = 0
    local_only: bool = False
    #: placement policy for this program ("" = the node's own)
    policy: str = ""


class CancelSubmitted(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="withdraw"):
    client: str
    request_id: int


class ProgramOutcome(_Msg, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="outcome"):
    """The one result (or error) of a submitted program, for its client."""

    request_id: int
    ok: bool
    value: bytes = b""
    error: str = ""
    #: "program" (the program raised), "refused" (no robot will run it),
    #: "cancelled", "failed" (gave up after failures), "shutdown"
    error_kind: str = ""
    host: str = ""
    attempts: int = 0


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
]


class Envelope(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    v: int
    sender: str
    msg: Message


class _VersionOnly(msgspec.Struct):
    v: int


_encoder = msgspec.msgpack.Encoder()
_envelope_decoder = msgspec.msgpack.Decoder(Envelope)
_version_decoder = msgspec.msgpack.Decoder(_VersionOnly)


def encode(sender: str, msg: Message) -> bytes:
    """Encode a message for the wire."""
    return _encoder.encode(Envelope(v=PROTOCOL_VERSION, sender=sender, msg=msg))


def decode(data: bytes, *, max_bytes: int = MAX_MESSAGE_BYTES) -> Envelope:
    """Decode bytes from the network, or raise WireError saying why not."""
    if len(data) > max_bytes:
        raise WireError(f"message of {len(data)} bytes exceeds the limit of {max_bytes} bytes")
    try:
        version = _version_decoder.decode(data).v
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        raise WireError(f"not a ramps message: {exc}") from exc
    if version != PROTOCOL_VERSION:
        raise WireError(
            f"protocol version mismatch: message is version {version}, "
            f"this node speaks version {PROTOCOL_VERSION}"
        )
    try:
        env = _envelope_decoder.decode(data)
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        raise WireError(f"malformed ramps message: {exc}") from exc
    _check_limits(env)
    return env


def _check_limits(env: Envelope) -> None:
    if not 0 < len(env.sender) <= MAX_NAME:
        raise WireError(f"sender name of length {len(env.sender)} is out of bounds")
    msg = env.msg
    for field in ("robot", "host", "origin", "program", "program_id", "client"):
        value = getattr(msg, field, None)
        if value is None:
            continue
        # an outcome refused before any placement names no host
        optional = field == "host" and isinstance(msg, ProgramOutcome)
        if len(value) > MAX_NAME or (not value and not optional):
            raise WireError(f"{field} of length {len(value)} is out of bounds")
    for field in ("detail", "error"):
        value = getattr(msg, field, None)
        if value is not None and len(value) > MAX_TEXT:
            raise WireError(f"{field} longer than {MAX_TEXT} characters")
    if isinstance(msg, Heartbeat) and len(msg.programs) > MAX_REFS:
        raise WireError(f"heartbeat lists {len(msg.programs)} programs (limit {MAX_REFS})")
    if isinstance(msg, LoadReport) and (len(msg.blacklisted) > MAX_REFS or len(msg.cpu_per_core) > 4096):
        raise WireError(f"load report lists {len(msg.blacklisted)} blacklisted robots (limit {MAX_REFS})")


def wire_size(msg: Message) -> int:
    """Bytes this message occupies on a link, counting declared payloads.

    The simulator sends messages without encoding them; their declared
    payload and result sizes stand in for the bytes a real robot would send.
    """
    if isinstance(msg, OffloadRequest):
        return 120 + max(msg.payload_size, len(msg.args))
    if isinstance(msg, ProgramResult):
        return 120 + max(msg.result_size, len(msg.value))
    if isinstance(msg, Heartbeat):
        return 40 + 24 * len(msg.programs)
    return 120
