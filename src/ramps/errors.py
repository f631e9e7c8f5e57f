"""The errors ramps raises to the people who use it.

    RampsError                    anything ramps reports
    ├── ConfigError               bad settings, flags or config file (local misuse)
    │   └── CredentialsError      missing, mismatched or expired team credentials
    ├── ProgramNotFound           no program of that name is registered here
    ├── BadArguments              arguments do not fit the program's signature,
    │                             cannot be encoded, or are too large
    ├── NoTeam                    no ramps node could be reached in time
    │   └── NotAdmitted           the team would not admit us (TLS: wrong CA,
    │                             certificate refused, or --secure missing)
    ├── TransportError            the middleware (Zenoh) failed; wraps its error
    └── RemoteError               a program ended without a result
        ├── ProgramFailed         the program itself raised (remote traceback text)
        ├── ProgramRefused        every robot that was asked refused it
        ├── ProgramLost           it could not be kept alive (gave up, node shut down)
        └── DeadlineUnmeetable    no robot was expected to meet its deadline and
                                  it asked to fail then (on_miss="fail"): nothing ran

Middleware exceptions are translated once, where ramps calls the middleware
(``raise TransportError(...) from exc``). A cancelled future raises
``concurrent.futures.CancelledError`` as Python users expect.
"""

from __future__ import annotations


class RampsError(Exception):
    """Base class of every error ramps raises."""


class ConfigError(RampsError, ValueError):
    pass


class ProgramNotFound(RampsError, KeyError):
    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class BadArguments(RampsError, TypeError):
    pass


class CredentialsError(ConfigError):
    pass


class NoTeam(RampsError):
    pass


class NotAdmitted(NoTeam):
    pass


class TransportError(RampsError):
    pass


class RemoteError(RampsError):
    """A program ended without a result; ``host`` ran it last."""

    def __init__(self, message: str, *, host: str = "", attempts: int = 0) -> None:
        super().__init__(message)
        self.host = host
        self.attempts = attempts


class ProgramFailed(RemoteError):
    pass


class ProgramRefused(RemoteError):
    pass


class ProgramLost(RemoteError):
    pass


class DeadlineUnmeetable(RemoteError):
    """A program submitted with a deadline and ``on_miss="fail"`` that no
    robot was expected to finish in time; the message names the best
    expected time. It failed before anything ran (or, placed again after a
    failure, when no robot could still make it)."""
