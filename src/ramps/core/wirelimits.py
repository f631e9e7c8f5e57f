"""The wire's limits and field types: what every message field may hold.

msgspec checks these while it decodes (never when a message is built), so a
message that breaks one is a ``WireError`` at the receiver and never reaches
the core (``ramps.core.messages``, which re-exports every name here).
"""

from __future__ import annotations

import re
import sys
from typing import Annotated

from msgspec import Meta

#: largest encoded message a node accepts, bytes (arguments included)
MAX_MESSAGE_BYTES = 8 * 1024 * 1024
#: longest robot, client, program and program-id name
MAX_NAME = 128
#: longest free text (a rejection's detail, a program's error)
MAX_TEXT = 4096
#: longest error in an outcome: it may quote a host's detail and a registry listing
MAX_OUTCOME_TEXT = 64 * 1024
#: most program references in a heartbeat, robots in a blacklist
MAX_REFS = 100_000
#: physical bounds of a load report: the cost model divides work by
#: ``speed * min(1, cores / (runnable + 1))``, which must stay a positive float
MAX_CORES = 1 << 16
MIN_SPEED = 1e-9
MAX_SPEED = 1e9
#: run-queue lengths, busy cores, load averages and windows (seconds)
MAX_LOAD = 1e9
#: scheduler weights of programs against nice 0 (CFS: nice 19 .. nice -20)
MIN_WEIGHT = 15 / 1024
MAX_WEIGHT = 88761 / 1024
#: longest progress text a program may attach to a fraction
MAX_PROGRESS_TEXT = 256
#: most running programs a load report lists
MAX_LISTED = 256
#: largest state a program may checkpoint (``ramps.checkpoint``), bytes
MAX_CHECKPOINT_BYTES = 256 * 1024
#: most kinds of accelerator a load report lists (``ramps.core.accelerators``)
MAX_ACCELERATOR_KINDS = 8
#: most padding a link probe may carry (bandwidth probes use ramps.core.links.PADDED_BYTES)
MAX_PROBE_BYTES = 64 * 1024


# ---------------------------------------------------------------- field types
# msgspec checks these while it decodes (never when a message is built), so a
# message that breaks one is a WireError at the receiver and never reaches the
# core. Robot and client names become Zenoh key chunks (``ramps/<team>/msg/<host>``):
# a wildcard in one would make an honest node publish to every robot's inbox.
_KEY_UNSAFE_CHARS = r"*$?#\x00-\x1f\x7f"
_KEY_SAFE = rf"\A[^{_KEY_UNSAFE_CHARS}]*\Z"
#: a robot or client name
RobotName = Annotated[str, Meta(min_length=1, max_length=MAX_NAME, pattern=_KEY_SAFE)]
#: a robot name in a long list (a load report's ``running``): msgspec checks
#: its length; ``ramps.core.messages.decode`` checks RobotName's pattern for
#: the whole list at once (``KEY_UNSAFE`` over the names joined), which is one
#: regex call instead of one per name and refuses exactly what the pattern does
ListedRobotName = Annotated[str, Meta(min_length=1, max_length=MAX_NAME)]
#: any character RobotName's pattern refuses
KEY_UNSAFE = re.compile(f"[{_KEY_UNSAFE_CHARS}]")
#: a robot name that may be empty (an outcome refused before any placement)
OptRobotName = Annotated[str, Meta(max_length=MAX_NAME, pattern=_KEY_SAFE)]
#: a program's name or id
Name = Annotated[str, Meta(min_length=1, max_length=MAX_NAME)]
#: a short keyword ("busy", "program", a policy name), may be empty
Word = Annotated[str, Meta(max_length=MAX_NAME)]
Text = Annotated[str, Meta(max_length=MAX_TEXT)]
Payload = Annotated[bytes, Meta(max_length=MAX_MESSAGE_BYTES)]
#: counters, sequence numbers, attempts, sizes
Count = Annotated[int, Meta(ge=0)]
#: a finite, non-negative float (NaN and infinities refused)
Amount = Annotated[float, Meta(ge=0.0, le=sys.float_info.max)]
Load = Annotated[float, Meta(ge=0.0, le=MAX_LOAD)]
#: a scheduler weight relative to nice 0 (the kernel's range is 15/1024 .. 88761/1024)
Weight = Annotated[float, Meta(ge=MIN_WEIGHT, le=MAX_WEIGHT)]
Cores = Annotated[int, Meta(ge=1, le=MAX_CORES)]
Speed = Annotated[float, Meta(ge=MIN_SPEED, le=MAX_SPEED)]
#: how far a program is, 0..1
Fraction = Annotated[float, Meta(ge=0.0, le=1.0)]
ProgressText = Annotated[str, Meta(max_length=MAX_PROGRESS_TEXT)]
#: a program's saved state (``ramps.checkpoint``)
CheckpointState = Annotated[bytes, Meta(max_length=MAX_CHECKPOINT_BYTES)]
