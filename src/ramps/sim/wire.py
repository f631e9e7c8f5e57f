"""What a message occupies on the simulator's links.

How this works: the simulator hands messages from robot to robot without
encoding them; ``wire_size`` gives the bytes a real robot would send for
one, its declared payload and result sizes standing in for the bytes
(``ramps.sim.engine`` delays each by latency plus size over bandwidth).
"""

from __future__ import annotations

from ramps.core.messages import Heartbeat, LinkProbe, Message, OffloadRequest, ProgramCheckpoint, ProgramResult


def wire_size(msg: Message) -> int:
    """Bytes this message occupies on a link, counting declared payloads.

    The simulator sends messages without encoding them; their declared
    payload and result sizes stand in for the bytes a real robot would send.
    """
    if isinstance(msg, OffloadRequest):
        return 120 + max(msg.payload_size, len(msg.args)) + len(msg.resume or b"")
    if isinstance(msg, ProgramCheckpoint):
        return 120 + len(msg.state)
    if isinstance(msg, ProgramResult):
        return 120 + max(msg.result_size, len(msg.value))
    if isinstance(msg, Heartbeat):
        return 40 + 24 * len(msg.programs)
    if isinstance(msg, LinkProbe):
        return 40 + len(msg.padding)
    return 120
