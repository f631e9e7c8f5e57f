"""Local events that drive a node's core, and the actions it asks for.

Rules: the core's inputs are wire messages (``ramps.core.messages``) and
the local events of ``Event`` (those below, ``Stalled`` from
``ramps.core.relink`` and ``SpeedMeasured`` from ``ramps.core.speed``,
``BatteryMeasured`` from ``ramps.core.battery``), each
with ``now`` passed alongside; its outputs are the actions below. A driver (the simulator, or the Zenoh runtime) applies the
actions: it sends, starts and stops programs, and hands results to the
application. ``Note`` actions carry no obligation: they exist so a driver can
trace what the core decided (placements, blacklisting) without the core
logging anything itself.
"""

from __future__ import annotations

import msgspec

from ramps.core.battery import BatteryMeasured
from ramps.core.messages import LoadReport, Message, ProgramResult
from ramps.core.relink import Stalled
from ramps.core.speed import SpeedMeasured


class _Rec(msgspec.Struct, frozen=True, kw_only=True):
    pass


# ---------------------------------------------------------------- events in
class Submit(_Rec, frozen=True, kw_only=True):
    """The application on this robot asks for a computation."""

    program_id: str
    program: str
    args: bytes = b""
    payload_size: int = 0
    #: expected work in work units (from the program's declared profile)
    work: float = 1.0
    result_size: int = 0
    #: never leave this robot (e.g. the program drives hardware)
    local_only: bool = False
    #: placement policy for this program ("" = the node's own)
    policy: str = ""
    #: bytes of memory the program needs: a robot reporting less free memory
    #: (after the programs booked there) is not a candidate; 0 = no need stated
    memory: int = 0
    #: when the result is wanted, in the core's time (absolute, like ``now``);
    #: None = no deadline. ``on_miss``: what to do when no robot is expected
    #: to meet it: "run" (where it ends soonest anyway), "local" (on this
    #: robot) or "fail" (at once, ``error_kind`` "deadline")
    deadline: float | None = None
    on_miss: str = "run"
    #: the kind of accelerator the program can use ("" = none) and its work
    #: there (work units at slot speed 1); robots that have one run it there,
    #: the others on a CPU (``work``) unless ``cpu_fallback`` is False, when
    #: only robots with one are candidates (``ramps.core.accelerators``)
    accelerator: str = ""
    accelerator_work: float = 0.0
    cpu_fallback: bool = True


class Cancel(_Rec, frozen=True, kw_only=True):
    """The application withdraws a computation it submitted."""

    program_id: str


class ProgramFinished(_Rec, frozen=True, kw_only=True):
    """A program the executor started has ended (driver -> core)."""

    program_id: str
    attempt: int
    ok: bool
    value: bytes = b""
    error: str = ""
    result_size: int = 0
    #: the worker died (killed, out of memory) rather than the program failing
    retryable: bool = False
    #: CPU seconds the program used (its worker's own clock, executables
    #: included), or None where the driver cannot tell (the simulator): the
    #: work it reports is then what processor sharing at this robot's
    #: speed and load says it did
    cpu_s: float | None = None
    #: seconds it held a slot of its accelerator, where the driver's slots are
    #: exclusive and it measured them (``ramps.runtime.accelerators``); None:
    #: its work there is what processor sharing of the slots did for it (the
    #: simulator shares them so)
    slot_s: float | None = None
    #: (with ``retryable``) the worker died by itself while this robot's
    #: executor lived: the program exited, crashed or was killed on its own,
    #: how is in ``error``; not a worker stopped because the node shuts down
    #: or was killed with its fork server. Its origin counts these towards
    #: calling the program a poison pill (``ramps.core.origin``)
    worker_died: bool = False


class ProgressReported(_Rec, frozen=True, kw_only=True):
    """A program the executor runs reported how far it is (driver -> core)."""

    program_id: str
    attempt: int
    fraction: float
    detail: str = ""


class CheckpointSaved(_Rec, frozen=True, kw_only=True):
    """A program the executor runs saved its state (driver -> core)."""

    program_id: str
    attempt: int
    state: bytes
    #: the program's progress when it saved, if it reported any
    fraction: float | None = None


class PeerLost(_Rec, frozen=True, kw_only=True):
    """The transport says a teammate is gone (Zenoh liveliness DELETE)."""

    robot: str


class PeerAlive(_Rec, frozen=True, kw_only=True):
    """The transport says a teammate is (back) in the team."""

    robot: str


class ApplicationHere(_Rec, frozen=True, kw_only=True):
    """An application connected to this robot's node to submit programs:
    this robot is an origin from now on, before its first ``Submit``."""


class OfferSending(_Rec, frozen=True, kw_only=True):
    """The driver sends this attempt's offer whole, on a thread of its own
    (a large one: ``ramps.runtime.bulk``), or is through with it (``done``:
    sent, failed or dropped). Its host cannot accept it before it is
    through, however slow the link: the connect timeout waits
    (``ramps.core.silence``)."""

    program_id: str
    attempt: int
    done: bool = False


class Received(_Rec, frozen=True, kw_only=True):
    """A wire message from a teammate."""

    sender: str
    msg: Message
    #: when it arrived, where the driver read it at a later round (a
    #: heartbeat: the program's silence counts from then); None: now
    at: float | None = None


Event = (Submit | Cancel | ProgramFinished | ProgressReported | CheckpointSaved | PeerLost | PeerAlive | Received
         | Stalled | SpeedMeasured | BatteryMeasured | ApplicationHere | OfferSending)


# ---------------------------------------------------------------- actions out
class Send(_Rec, frozen=True, kw_only=True):
    to: str
    msg: Message


class StartProgram(_Rec, frozen=True, kw_only=True):
    """Run a registered program in the executor (its own worker)."""

    program_id: str
    attempt: int
    origin: str
    program: str
    args: bytes
    work: float
    #: the checkpoint to resume from (``ramps.resume()``), None = fresh start
    resume: bytes | None = None
    #: how far the program was at that checkpoint (0..1)
    resume_fraction: float = 0.0
    #: the kind of accelerator it runs on here ("" = a CPU): the driver gives
    #: the program one of that kind's devices (``ramps.accelerator()``)
    accelerator: str = ""


class StopProgram(_Rec, frozen=True, kw_only=True):
    """Kill a running program: it was cancelled or is no longer wanted."""

    program_id: str
    attempt: int


class Deliver(_Rec, frozen=True, kw_only=True):
    """The one and only outcome of a submitted program, for the application."""

    program_id: str
    ok: bool
    value: bytes = b""
    error: str = ""
    #: why there is no result: "program" (the program raised), "refused"
    #: (a host will never run it), "cancelled", "failed" (gave up)
    error_kind: str = ""
    host: str = ""
    attempts: int = 0
    #: relocations after placement, and the progress the last attempt resumed from
    moves: int = 0
    resumed_from: float | None = None
    #: it had a deadline and was delivered after it (or refused as unmeetable)
    missed_deadline: bool = False


class Progress(_Rec, frozen=True, kw_only=True):
    """A program this robot is origin of reported progress on ``host``."""

    program_id: str
    host: str
    attempt: int
    fraction: float
    detail: str = ""


class PublishReport(_Rec, frozen=True, kw_only=True):
    """Publish this load report to the team now: the robot's programs changed
    since its last report (see ``Node``'s prompt reports)."""

    report: LoadReport


class Note(_Rec, frozen=True, kw_only=True):
    """Something the core decided, for traces and logs. ``what`` is one of:
    placed, accepted, rejected, blacklisted, unblacklisted, failed, backoff,
    discarded, anomaly, isolated, revived, suspected, moving, moved, move_aborted,
    checkpoint, restored, deadline_unmet, deadline_missed, battery_low, battery_ok,
    one_way, two_way (``ramps.core.oneway``)."""

    what: str
    program_id: str = ""
    robot: str = ""
    attempt: int = 0
    detail: str = ""


class NameTaken(_Rec, frozen=True, kw_only=True):
    """Another node runs under this robot's name (``ramps.core.identity``).
    ``leave``: this node started later and must leave the team (the driver
    takes it out and says why); else the other node leaves and this one
    stays. ``other`` is the other node's incarnation."""

    other: int
    leave: bool


Action = Send | StartProgram | StopProgram | Deliver | Progress | PublishReport | Note | NameTaken

__all__ = [
    "Submit", "Cancel", "ProgramFinished", "ProgressReported", "CheckpointSaved", "PeerLost", "PeerAlive", "Received",
    "ApplicationHere", "Event",
    "Send", "StartProgram", "StopProgram", "Deliver", "Progress", "PublishReport", "Note", "NameTaken", "Action",
    "ProgramResult",
]
