"""The claims origins exchange about their bursts of one instant (``ramps.core.claims``).

They travel in the same envelope as the robots' other messages
(``ramps.core.messages``, which re-exports them and decodes them). A node
of a release before them drops a claim as an unknown type; it never says
that it submits (``LoadReport.submits``), so no origin waits for its claims.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
from msgspec import Meta

from ramps.core.wirebase import Record
from ramps.core.wirelimits import MAX_LISTED, Amount, Count, RobotName, Word


class ClaimedPool(msgspec.Struct, frozen=True, array_like=True):
    """What a burst's plan puts on one pool of a robot: [robot, accelerator
    kind ("" for its cores), the work of each program planned there]."""

    robot: RobotName
    kind: Word = ""
    work: Annotated[list[Amount], Meta(max_length=MAX_LISTED)] = []


class BurstClaim(Record, frozen=True, kw_only=True, tag="claim"):
    """An origin's burst of one instant, told to the teammates after it in
    the order of names (``ramps.core.claims``): ``planned`` False, it is
    being planned (its claim follows); True, where its programs went."""

    planned: bool = False
    #: the sender's own accepted count once its own programs of the burst
    #: are in (``LoadReport.accepted_total``): a report of it that has
    #: reached this count shows them
    accepted: Count = 0
    pools: Annotated[list[ClaimedPool], Meta(max_length=MAX_LISTED)] = []
