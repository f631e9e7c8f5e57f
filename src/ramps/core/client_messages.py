"""The records between an application (client) and its robot's node.

How this works: a client sends ``SubmitProgram`` (and ``CancelSubmitted``
to withdraw one) to its node's inbox; the node answers with advisory
``ProgramUpdate``s and exactly one ``ProgramOutcome``. They travel in the
same envelope as the robots' messages (``ramps.core.messages``, which
re-exports them and decodes them).
"""

from __future__ import annotations

from typing import Annotated

from msgspec import Meta

from ramps.core.wirebase import Record
from ramps.core.wirelimits import (
    MAX_OUTCOME_TEXT, Amount, Count, Fraction, Name, OptRobotName, Payload, ProgressText, RobotName, Word,
)


class SubmitProgram(Record, frozen=True, kw_only=True, tag="submit"):
    """An application (client) asks its robot's node to run a program."""

    client: RobotName
    request_id: Count
    program: Name
    args: Payload = b""
    #: expected work in work units (from the program's profile), 0 = default
    work: Amount = 0.0
    result_size: Count = 0
    local_only: bool = False
    #: placement policy for this program ("" = the node's own)
    policy: Word = ""
    #: seconds from the node's receipt by which the result is wanted (None:
    #: no deadline), and what to do when no robot can meet it: "run" (or
    #: ""), "local" or "fail" (``ramps.core.origin``). Added in protocol 1.1
    deadline: Amount | None = None
    on_miss: Word = ""
    #: the kind of accelerator the program can use ("" = none), its work
    #: there in work units (0 = the same as ``work``), and whether it may
    #: run on a CPU where no robot has one free (``ramps.core.accelerators``)
    accelerator: Word = ""
    accelerator_work: Amount = 0.0
    cpu_fallback: bool = True


class CancelSubmitted(Record, frozen=True, kw_only=True, tag="withdraw"):
    client: RobotName
    request_id: Count


class ProgramOutcome(Record, frozen=True, kw_only=True, tag="outcome"):
    """The one result (or error) of a submitted program, for its client."""

    request_id: Count
    ok: bool
    value: Payload = b""
    error: Annotated[str, Meta(max_length=MAX_OUTCOME_TEXT)] = ""
    #: "program" (the program raised), "refused" (no robot will run it),
    #: "cancelled", "failed" (gave up after failures), "shutdown"
    error_kind: Word = ""
    host: OptRobotName = ""
    attempts: Count = 0
    #: times the program was relocated while running (moves after placement)
    moves: Count = 0
    #: the progress of the checkpoint its last attempt resumed from (None:
    #: it ran from the start)
    resumed_from: Fraction | None = None
    #: it had a deadline and was delivered after it (or refused as
    #: unmeetable, ``error_kind`` "deadline"). Added in protocol 1.1
    missed_deadline: bool = False


class ProgramUpdate(Record, frozen=True, kw_only=True, tag="update"):
    """Where a submitted program stands, for its client (node -> client;
    advisory, the one ``ProgramOutcome`` still ends it). ``state`` is
    "placed" (offered to ``host``), "running" (``host`` accepted it),
    "replaced" (offered again after a failure or a refusal), "host_failed"
    (``host`` was written off; it will be placed again) or "progress"."""

    request_id: Count
    state: Word
    host: OptRobotName = ""
    attempt: Count = 0
    #: the latest progress the program reported (None: none yet)
    fraction: Fraction | None = None
    detail: ProgressText = ""
