"""A node's durable record of the programs it is origin of: an append-only journal.

How this works: one file per robot and team (``STATE_FILE`` under the
node's state directory): a header naming the team and the robot, then
frames (length, CRC-32, a msgpack body), each a program as it now stands or
an outcome delivered, which ends its program. ``save`` appends a driver
round's frames in one ``write`` before the driver acts on them, so a node
killed at any instant (a crash, SIGKILL, the supervisor's restart) restarts
with every program it had accepted from its clients. How far a save goes
is ``sync`` (the node's ``state_sync``):

- ``normal`` (the default): written to the operating system at each save,
  one ``write`` of a few microseconds. A robot that loses power may forget
  the programs of its last moments; their clients, on the same robot, lost
  power with it.
- ``full``: fsynced at every save, for clients that outlive their robot's
  power (they connect from elsewhere): 0.5-2 ms a save on the development
  VM's disk.

Reading it back, the frames are replayed in order: a program's newest frame
stands until its outcome; outcomes are kept ``OUTCOME_KEEP`` seconds and at
most ``OUTCOMES_MAX`` of them (the newest), so a client that asks again
after a restart gets the outcome it may have missed. A frame cut short or
failing its CRC ends the journal (a write the crash or power loss cut:
what came before stands) and the file is cut there; a program frame whose
record does not decode (a record of an unknown format) is skipped and
counted. The journal is written anew with only what stands (``_compact``:
a new file, fsynced, renamed over the old one) when the node starts and
whenever it has grown past ``COMPACT_BYTES`` and twice what stands.

One node at a time holds a record: the store takes a POSIX lock on a file
beside it (``<robot>.journal.lock``, holding the holder's pid) for as long
as it is open, and a second node of the same robot and team on this
machine (a second ``ramps node`` started by mistake) is refused
(``ConfigError``, exit 2) before it reads or writes anything. The kernel
drops the lock when its process ends, however it ends, and a forked worker
does not inherit it, so a restarted node always gets it. A journal of
another team or robot is refused (``ConfigError``: pointing two nodes at
one directory is a mistake to fix, not to guess about); a file that is no
journal is set aside beside itself (``.corrupt-<time>``) with a warning
and the node starts with an empty record, so a damaged disk never makes a
supervised node crash in a loop. The record of ramps 0.x before the
journal (SQLite, ``<robot>.sqlite``) is read once, copied into a new
journal and set aside (``.imported-<time>``).
"""

from __future__ import annotations

import logging
import os
import struct
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from ramps.core.durable import RECORD_FORMAT, OriginRecord, decode_record, encode_record
from ramps.errors import ConfigError

try:
    import fcntl
except ImportError:  # not a POSIX system: no lock (one node per robot is then the user's to keep)
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger("ramps.node")
#: ``state_sync`` -> whether each save is fsynced (see the module docstring)
SYNC = {"normal": False, "full": True}
#: the file in the state directory: one per team and robot
STATE_FILE = "{team}/{robot}.journal"
#: the record before the journal (SQLite), read once and set aside
OLD_STATE_FILE = "{team}/{robot}.sqlite"
#: seconds, and entries, of delivered outcomes kept for clients that ask again
OUTCOME_KEEP = 3600.0
OUTCOMES_MAX = 10_000
#: a journal grown past this many bytes, and twice what stands in it, is written anew
COMPACT_BYTES = 8 * 1024 * 1024
#: what a journal file starts with, then its header frame
MAGIC = b"RAMPS-JOURNAL\n"
#: a frame: body length, CRC-32 of the body, then the body (msgpack)
_FRAME = struct.Struct("<II")
#: a frame longer than this is no frame (a program's record holds its arguments and checkpoint)
MAX_FRAME = 256 * 1024 * 1024


class _Header(msgspec.Struct):
    team: str
    robot: str
    format: int


_header_decoder = msgspec.msgpack.Decoder(_Header)
_decoder = msgspec.msgpack.Decoder()
_encoder = msgspec.msgpack.Encoder()


def _entry(body: bytes) -> tuple[Any, ...] | None:
    """A frame's entry, or None if it is neither kind: ``("p", program id,
    client, request id, record)``, a program as it stands, or ``("o",
    program id, client, request id, outcome, at)``, its outcome delivered
    (``at``: Unix time; client "": an outcome kept without its program)."""
    try:
        e = _decoder.decode(body)
    except (msgspec.DecodeError, RecursionError):
        return None
    if not isinstance(e, list) or len(e) < 5 or not all(isinstance(x, t) for x, t in zip(e, (str, str, str, int, bytes))):
        return None
    if e[0] == "p" and len(e) == 5:
        return tuple(e)
    if e[0] == "o" and len(e) == 6 and isinstance(e[5], (int, float)):
        return tuple(e)
    return None


def frame(body: bytes) -> bytes:
    """One frame of the journal: its length, its CRC-32, then ``body``."""
    return _FRAME.pack(len(body), zlib.crc32(body)) + body


def default_state_dir() -> Path:
    """``$STATE_DIRECTORY`` (systemd's ``StateDirectory=``), else
    ``$XDG_STATE_HOME/ramps`` (``~/.local/state/ramps``)."""
    if os.environ.get("STATE_DIRECTORY"):
        return Path(os.environ["STATE_DIRECTORY"].split(":")[0])
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "ramps"


@dataclass
class Restored:
    """What a node finds in its record when it starts."""

    #: program id -> (client, request id, record)
    programs: dict[str, tuple[str, int, OriginRecord]] = field(default_factory=dict)
    #: (client, request id) -> the encoded outcome delivered
    outcomes: dict[tuple[str, int], bytes] = field(default_factory=dict)
    #: entries that did not decode
    skipped: int = 0


class _NotAJournal(Exception):
    """The file does not start as a journal does."""


class OriginStore:
    """The record of one robot's programs in one team."""

    def __init__(self, directory: str | os.PathLike[str], *, team: str, robot: str, sync: str = "normal") -> None:
        if sync not in SYNC:
            raise ConfigError(f"state_sync must be one of {', '.join(SYNC)}, got {sync!r}")
        self.path = Path(directory) / STATE_FILE.format(team=team, robot=robot)
        self.team, self.robot, self.sync = team, robot, sync
        self._fsync = SYNC[sync]
        #: saves written, and the seconds they took
        self.writes = 0
        self.commit_s = 0.0
        #: what stands, by where its newest frame lies in the file: program id ->
        #: (offset, size); (client, request id) -> (offset, size, at), oldest first
        self._programs: dict[str, tuple[int, int]] = {}
        self._outcomes: dict[tuple[str, int], tuple[int, int, float]] = {}
        self._size = 0  # the file's length: where the next frame goes
        self._live = 0  # bytes of the frames that stand, and of the header
        self._fd = -1
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"cannot use state directory {self.path.parent}: {exc.strerror or exc}") from None
        self._lock = self._take_lock(self.lock_path)
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    @property
    def lock_path(self) -> Path:
        return Path(f"{self.path}.lock")

    def _take_lock(self, path: Path) -> int | None:
        """Lock ``path`` for this process (see the module docstring): the lock
        file's descriptor, or ConfigError if another process holds it."""
        if fcntl is None:
            return None
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise ConfigError(f"cannot use state directory {self.path.parent}: {exc.strerror or exc}") from None
        try:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(fd, 32).decode("ascii", "replace").strip()
            os.close(fd)
            raise ConfigError(
                f"a node of robot {self.robot!r} of team {self.team!r} already runs on this machine"
                f"{f' (pid {holder})' if holder.isdigit() else ''} and holds its record {self.path}: give this node "
                f"its own robot name (--robot NAME or RAMPS_ROBOT=NAME), or stop the other one first") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        return fd

    # ------------------------------------------------------------ opening
    def _open(self) -> None:
        """Read the journal (or the record before it), then write it anew."""
        old = self.path.parent / Path(OLD_STATE_FILE.format(team=self.team, robot=self.robot)).name
        entries: list[bytes] = []
        if self.path.exists():
            try:
                entries = self._replay()
            except _NotAJournal as exc:
                aside = self.path.with_name(f"{self.path.name}.corrupt-{int(time.time())}")
                self.path.rename(aside)
                log.error("node %s: its record %s could not be read (%s): set aside as %s; starting with an "
                          "empty record (programs it had are lost to it)", self.robot, self.path, exc, aside)
            self._write_anew(entries)
        elif old.exists():
            self._import(old)
        else:
            self._write_anew([])

    def _replay(self) -> list[bytes]:
        """The frames that stand in the journal, in order; ``_NotAJournal``
        if it is none, ``ConfigError`` if it is another robot's."""
        with open(self.path, "rb") as f:
            data = f.read()
        if not data.startswith(MAGIC):
            raise _NotAJournal("it does not start as a ramps journal")
        pos = len(MAGIC)
        body, pos = _next_frame(data, pos)
        try:
            head = _header_decoder.decode(body) if body is not None else None
        except (msgspec.DecodeError, msgspec.ValidationError):
            head = None
        if head is None:
            raise _NotAJournal("its header is unreadable")
        if (head.team, head.robot) != (self.team, self.robot):
            raise ConfigError(
                f"{self.path} is the record of robot {head.robot!r} of team {head.team!r}, not of "
                f"robot {self.robot!r} of team {self.team!r}: give this node its own --state-dir")
        programs: dict[str, bytes] = {}
        outcomes: dict[tuple[str, int], bytes] = {}
        while pos < len(data):
            body, end = _next_frame(data, pos)
            if body is None:  # cut short, or not what was written: the journal ends here
                log.warning("node %s: its record %s ends in %d bytes that are no whole entry (a write cut "
                            "short): dropped", self.robot, self.path, len(data) - pos)
                break
            pos = end
            entry = _entry(body)
            if entry is None:
                continue
            if entry[0] == "p":
                programs[entry[1]] = body
            elif entry[0] == "o":
                programs.pop(entry[1], None)
                if entry[2]:
                    outcomes.pop((entry[2], entry[3]), None)
                    outcomes[(entry[2], entry[3])] = body
        return list(programs.values()) + list(outcomes.values())

    def _import(self, old: Path) -> None:
        """Copy the record before the journal (SQLite) into a new journal, then
        set it aside; one that cannot be read is set aside as corrupt."""
        import sqlite3

        held = self._take_lock(Path(f"{old}.lock"))  # a node of the earlier version may still write it
        try:
            try:
                db = sqlite3.connect(f"file:{old}?mode=ro", uri=True)
                try:
                    meta = dict(db.execute("SELECT key, value FROM meta").fetchall())
                    if (meta.get("team"), meta.get("robot")) != (self.team, self.robot):
                        raise ConfigError(
                            f"{old} is the record of robot {meta.get('robot')!r} of team {meta.get('team')!r}, "
                            f"not of robot {self.robot!r} of team {self.team!r}: give this node its own --state-dir")
                    entries = [_encoder.encode(("p", pid, client, rid, bytes(rec))) for pid, client, rid, rec in
                               db.execute("SELECT program_id, client, request_id, record FROM programs")]
                    entries += [_encoder.encode(("o", "", client, rid, bytes(data), at)) for client, rid, data, at
                                in db.execute("SELECT client, request_id, outcome, at FROM outcomes ORDER BY at")]
                    what = "imported"
                finally:
                    db.close()
            except sqlite3.DatabaseError as exc:
                log.error("node %s: its record %s could not be read (%s): set aside; starting with an empty "
                          "record (programs it had are lost to it)", self.robot, old, exc)
                entries, what = [], "corrupt"
            self._write_anew(entries)  # the journal first: a crash now leaves both, and the journal is read
            stamp = int(time.time())
            for suffix in ("", "-wal", "-shm"):
                src = Path(str(old) + suffix)
                if src.exists():
                    src.rename(f"{old}.{what}-{stamp}{suffix}")
        finally:
            if held is not None:
                os.close(held)
        Path(f"{old}.lock").unlink(missing_ok=True)
        if what == "imported":
            log.info("node %s: its record %s is now the journal %s (%d entries)", self.robot, old, self.path,
                     len(entries))

    def _write_anew(self, entries: list[bytes]) -> None:
        """Write a journal holding ``entries`` (bodies, in order) over this one,
        and index what stands in it."""
        header = frame(_encoder.encode(_Header(team=self.team, robot=self.robot, format=RECORD_FORMAT)))
        frames = [frame(body) for body in entries]
        tmp = self.path.with_name(self.path.name + ".new")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            _write_all(fd, MAGIC + header + b"".join(frames))
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, self.path)
        _sync_dir(self.path.parent)
        if self._fd >= 0:
            os.close(self._fd)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        self._programs, self._outcomes = {}, {}
        offset = self._live = len(MAGIC) + len(header)
        for body, fr in zip(entries, frames):
            self._index(_entry(body), offset, len(fr))
            offset += len(fr)
        self._size = offset

    def _index(self, entry: Any, offset: int, size: int) -> None:
        """Take the entry at ``offset`` as the newest of its program, or of its outcome."""
        old = self._programs.pop(entry[1], None)
        if old is not None:
            self._live -= old[1]
        if entry[0] == "p":
            self._programs[entry[1]] = (offset, size)
            self._live += size
        elif entry[2]:
            key = (entry[2], entry[3])
            was = self._outcomes.pop(key, None)
            if was is not None:
                self._live -= was[1]
            self._outcomes[key] = (offset, size, entry[5])
            self._live += size
            while len(self._outcomes) > OUTCOMES_MAX:  # the oldest beyond the bound
                self._live -= self._outcomes.pop(next(iter(self._outcomes)))[1]

    def _compact(self) -> None:
        """Write the journal anew with only the frames that stand."""
        with open(self.path, "rb") as f:
            def body(offset: int, size: int) -> bytes:
                f.seek(offset + _FRAME.size)
                return f.read(size - _FRAME.size)

            entries = [body(o, s) for o, s in self._programs.values()]
            entries += [body(o, s) for o, s, _ in self._outcomes.values()]
        self._write_anew(entries)

    # ------------------------------------------------------------ using
    def load(self, now: float | None = None) -> Restored:
        """Every program and kept outcome in the record (outcomes older than
        ``OUTCOME_KEEP`` are dropped first)."""
        now = time.time() if now is None else now
        for key, (_, size, at) in list(self._outcomes.items()):
            if at < now - OUTCOME_KEEP:
                del self._outcomes[key]
                self._live -= size
        found = Restored()
        with open(self.path, "rb") as f:
            def entry(offset: int, size: int) -> Any:
                f.seek(offset + _FRAME.size)
                return _entry(f.read(size - _FRAME.size))

            for pid, (offset, size) in self._programs.items():
                _, _, client, rid, data = entry(offset, size)
                try:
                    found.programs[pid] = (client, rid, decode_record(data))
                except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                    found.skipped += 1
                    log.warning("node %s: skipped program %s in its record: %s", self.robot, pid, exc)
            for key, (offset, size, _) in self._outcomes.items():
                found.outcomes[key] = entry(offset, size)[4]
        return found

    def save(self, records: dict[str, tuple[str, int, OriginRecord]], finished: list[tuple[str, str, int, bytes]]) -> None:
        """In one write, on disk (as ``sync`` says) when this returns: write
        ``records`` (program id -> client, request, record), and for each of
        ``finished`` (program id, client, request, outcome) end the program
        and keep its outcome."""
        if not records and not finished:
            return
        t0 = time.perf_counter()
        at = time.time()
        entries: list[Any] = [("p", pid, c, r, encode_record(rec)) for pid, (c, r, rec) in records.items()]
        entries += [("o", pid, c, r, data, at) for pid, c, r, data in finished]
        frames = [frame(_encoder.encode(e)) for e in entries]
        _write_all(self._fd, b"".join(frames))
        if self._fsync:
            os.fsync(self._fd)
        offset = self._size
        for e, fr in zip(entries, frames):
            self._index(e, offset, len(fr))
            offset += len(fr)
        self._size = offset
        self.writes += 1
        self.commit_s += time.perf_counter() - t0
        if self._size > COMPACT_BYTES and self._size > 2 * self._live:
            self._compact()

    def programs(self) -> int:
        return len(self._programs)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        if self._lock is not None:  # closing it drops the lock
            os.close(self._lock)
            self._lock = None


def _next_frame(data: bytes, pos: int) -> tuple[bytes | None, int]:
    """The body of the frame at ``pos`` and where the next begins; None if
    there is no whole, sound frame there."""
    if pos + _FRAME.size > len(data):
        return None, pos
    size, crc = _FRAME.unpack_from(data, pos)
    start, end = pos + _FRAME.size, pos + _FRAME.size + size
    if size > MAX_FRAME or end > len(data):
        return None, pos
    body = data[start:end]
    if zlib.crc32(body) != crc:
        return None, pos
    return body, end


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _sync_dir(path: Path) -> None:
    """fsync a folder, so a file renamed into it stays there after a power loss."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
