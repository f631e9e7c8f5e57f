"""The parts of a node's driver that stand on their own, as one record.

How this works: ``NodeRuntime`` (``ramps.runtime.node``) makes these
parts first, each from the robot's and team's names and the clock alone
(none of them reads the driver), and hands them as one ``NodeParts`` to a
part that uses most of them (``node_outbound.Outbound``). The record is
frozen: a part that is given it uses these very objects, and none of them
is replaced while the node runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ramps.runtime.node_awake import AwakeClock
    from ramps.runtime.node_intake import WireIntake
    from ramps.runtime.node_name import SameName
    from ramps.runtime.node_outbox import Outbox
    from ramps.runtime.node_revoked import Revoked
    from ramps.runtime.node_team import Membership
    from ramps.runtime.node_trace import NodeTrace
    from ramps.runtime.transport import Clock


@dataclass(frozen=True, slots=True, kw_only=True)
class NodeParts:
    """Robot ``robot`` of team ``team``: its clock and the parts made from them."""

    robot: str
    team: str
    clock: Clock
    #: the core's clock: the time this node was awake, its stalls taken out
    awake: AwakeClock
    #: its publishers, and the threads that send large messages
    outbox: Outbox
    #: its trace file
    trace: NodeTrace
    #: its backlog of received bytes, what it makes of them, and the drops it counts
    intake: WireIntake
    #: its subscriptions, publishers and tokens on the transport
    membership: Membership
    #: secured team: the newest revocation list
    revoked: Revoked
    #: the other nodes under this robot's name
    same_name: SameName
