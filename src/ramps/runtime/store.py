"""A node's durable record of the programs it is origin of (SQLite).

How this works: one SQLite file per robot and team (``STATE_FILE`` under the
node's state directory) in WAL mode. Every commit is in the WAL before the
driver acts on it, so a node killed at any instant (a crash, SIGKILL, the
supervisor's restart) restarts with every program it had accepted from its
clients. How far a commit goes is ``sync`` (the node's ``state_sync``):

- ``normal`` (the default): SQLite's ``synchronous=NORMAL``, the WAL written
  to the operating system at each commit and fsynced at checkpoints. A
  robot that loses power may forget the programs of its last moments; their
  clients, on the same robot, lost power with it. About 0.05 ms a commit.
- ``full``: ``synchronous=FULL``, the WAL fsynced at every commit, for
  clients that outlive their robot's power (they connect from elsewhere).
  0.5-2 ms a commit on the development VM's disk: half an origin's driver
  time in ``ramps bench dispatch``.

Two tables:

- ``programs``: one row per program not yet delivered (its client and
  request, and an ``OriginRecord``, ``ramps.core.durable``), written in one
  transaction per driver round, before anything that tells its client the
  program is taken (``ramps.runtime.node_outbound.before_record``);
- ``outcomes``: what was delivered to each client request, written (and the
  program's row deleted) in the same transaction before the outcome is sent,
  kept ``OUTCOME_KEEP`` seconds and at most ``OUTCOMES_MAX`` rows, so a
  client that asks again after a restart gets the outcome it may have missed.

One node at a time holds a record: the store takes a POSIX lock on a file
beside it (``<robot>.sqlite.lock``, holding the holder's pid) for as long as
it is open, and a second node of the same robot and team on this machine (a
second ``ramps node`` started by mistake) is refused (``ConfigError``, exit 2)
before it reads or writes anything. The kernel drops the lock when its
process ends, however it ends, and a forked worker does not inherit it, so
a restarted node always gets it. A file of another team or robot is refused
(``ConfigError``: pointing two nodes at one directory is a mistake to fix,
not to guess about); a file
SQLite cannot read is set aside beside itself (``.corrupt-<time>``) with a
warning and the node starts with an empty record, so a damaged disk never
makes a supervised node crash in a loop. A row that does not decode (a
record of an unknown format) is skipped and counted.
"""

from __future__ import annotations

import logging
import os
import sqlite3
import time
from dataclasses import dataclass, field
from pathlib import Path

import msgspec

from ramps.core.durable import RECORD_FORMAT, OriginRecord, decode_record, encode_record
from ramps.errors import ConfigError

try:
    import fcntl
except ImportError:  # not a POSIX system: no lock (one node per robot is then the user's to keep)
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger("ramps.node")
#: ``state_sync`` -> SQLite's ``synchronous`` (see the module docstring)
SYNC = {"normal": "NORMAL", "full": "FULL"}
#: the file in the state directory: one per team and robot
STATE_FILE = "{team}/{robot}.sqlite"
#: seconds, and rows, of delivered outcomes kept for clients that ask again
OUTCOME_KEEP = 3600.0
OUTCOMES_MAX = 10_000
#: the tables; ``programs`` is keyed by its primary key alone (``WITHOUT
#: ROWID``: one B-tree, so each write touches a page less). ``outcomes``
#: keeps its rowid, which an older node bounds it by. No statement here names
#: a rowid, so a record made with other tables is read and written the same way
SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS programs (
    program_id TEXT PRIMARY KEY, client TEXT NOT NULL, request_id INTEGER NOT NULL, record BLOB NOT NULL)
    WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS outcomes (
    client TEXT NOT NULL, request_id INTEGER NOT NULL, outcome BLOB NOT NULL, at REAL NOT NULL,
    PRIMARY KEY (client, request_id));
CREATE INDEX IF NOT EXISTS outcomes_at ON outcomes (at);
"""


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
    #: rows that did not decode
    skipped: int = 0


class OriginStore:
    """The record of one robot's programs in one team."""

    def __init__(self, directory: str | os.PathLike[str], *, team: str, robot: str, sync: str = "normal") -> None:
        if sync not in SYNC:
            raise ConfigError(f"state_sync must be one of {', '.join(SYNC)}, got {sync!r}")
        self.path = Path(directory) / STATE_FILE.format(team=team, robot=robot)
        self.team, self.robot, self.sync = team, robot, sync
        self.writes = 0
        self.commit_s = 0.0
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"cannot use state directory {self.path.parent}: {exc.strerror or exc}") from None
        self._lock = self._take_lock()
        try:
            self._db = self._open_or_set_aside()
        except BaseException:
            self._release()
            raise
        #: outcome rows, at least (a replaced one counts twice): the oldest go once there are too many
        self._outcome_rows = self._count_outcomes()

    def _open_or_set_aside(self) -> sqlite3.Connection:
        """The record, opened; one SQLite cannot read is set aside first."""
        try:
            return self._open()
        except sqlite3.DatabaseError as exc:  # not a database, or damaged: keep it for a post-mortem, start afresh
            aside = self.path.with_name(f"{self.path.name}.corrupt-{int(time.time())}")
            for suffix in ("", "-wal", "-shm"):
                src = Path(str(self.path) + suffix)
                if src.exists():
                    src.rename(str(aside) + suffix)
            log.error("node %s: its record %s could not be read (%s): set aside as %s; starting with an empty "
                      "record (programs it had are lost to it)", self.robot, self.path, exc, aside)
            return self._open()

    def _release(self) -> None:
        if self._lock is not None:  # closing it drops the lock
            os.close(self._lock)
            self._lock = None

    @property
    def lock_path(self) -> Path:
        return Path(f"{self.path}.lock")

    def _take_lock(self) -> int | None:
        """Lock the record for this process (see the module docstring):
        the lock file's descriptor, or ConfigError if another process holds it."""
        if fcntl is None:
            return None
        try:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
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

    def _count_outcomes(self) -> int:
        return int(self._db.execute("SELECT count(*) FROM outcomes").fetchone()[0])

    def _open(self) -> sqlite3.Connection:
        db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        try:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute(f"PRAGMA synchronous={SYNC[self.sync]}")
            db.executescript(SCHEMA)
            meta = dict(db.execute("SELECT key, value FROM meta").fetchall())
            if not meta:
                db.executemany("INSERT INTO meta VALUES (?, ?)", [
                    ("team", self.team), ("robot", self.robot), ("format", str(RECORD_FORMAT))])
            elif (meta.get("team"), meta.get("robot")) != (self.team, self.robot):
                db.close()
                raise ConfigError(
                    f"{self.path} is the record of robot {meta.get('robot')!r} of team {meta.get('team')!r}, not of "
                    f"robot {self.robot!r} of team {self.team!r}: give this node its own --state-dir")
            db.execute("PRAGMA quick_check").fetchone()
        except sqlite3.DatabaseError:
            db.close()
            raise
        return db

    def load(self, now: float | None = None) -> Restored:
        """Every program and kept outcome in the record (outcomes older than
        ``OUTCOME_KEEP`` are dropped first)."""
        now = time.time() if now is None else now
        self._db.execute("DELETE FROM outcomes WHERE at < ?", (now - OUTCOME_KEEP,))
        self._outcome_rows = self._count_outcomes()
        found = Restored()
        for pid, client, rid, data in self._db.execute("SELECT program_id, client, request_id, record FROM programs"):
            try:
                found.programs[pid] = (client, rid, decode_record(data))
            except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                found.skipped += 1
                log.warning("node %s: skipped program %s in its record: %s", self.robot, pid, exc)
        for client, rid, data in self._db.execute("SELECT client, request_id, outcome FROM outcomes ORDER BY at"):
            found.outcomes[(client, rid)] = data
        return found

    def save(self, records: dict[str, tuple[str, int, OriginRecord]], finished: list[tuple[str, str, int, bytes]]) -> None:
        """In one transaction, on disk when this returns: write ``records``
        (program id -> client, request, record), and for each of
        ``finished`` (program id, client, request, outcome) delete the
        program and keep its outcome."""
        if not records and not finished:
            return
        t0 = time.perf_counter()
        db = self._db
        db.execute("BEGIN")
        try:
            db.executemany("INSERT OR REPLACE INTO programs VALUES (?, ?, ?, ?)",
                           [(pid, c, r, encode_record(rec)) for pid, (c, r, rec) in records.items()])
            if finished:
                db.executemany("DELETE FROM programs WHERE program_id = ?", [(f[0],) for f in finished])
                at = time.time()
                kept = [(c, r, data, at) for _, c, r, data in finished if c]
                db.executemany("INSERT OR REPLACE INTO outcomes VALUES (?, ?, ?, ?)", kept)
                rows = self._outcome_rows + len(kept)
                if rows > OUTCOMES_MAX:  # the oldest beyond the bound, through the index on ``at``
                    db.execute("DELETE FROM outcomes WHERE (client, request_id) IN (SELECT client, request_id "
                               "FROM outcomes ORDER BY at LIMIT ?)", (rows - OUTCOMES_MAX,))
                    rows = OUTCOMES_MAX
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        if finished:
            self._outcome_rows = rows
        self.writes += 1
        self.commit_s += time.perf_counter() - t0

    def programs(self) -> int:
        return int(self._db.execute("SELECT count(*) FROM programs").fetchone()[0])

    def close(self) -> None:
        try:
            self._db.close()
        except sqlite3.Error:
            pass
        self._release()
