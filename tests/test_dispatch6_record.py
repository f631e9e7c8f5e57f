"""The durable record's tables (``ramps.runtime.store``): a new record keys
its programs by their primary key alone (``WITHOUT ROWID``) and keeps the
outcomes' rowid, which an older node bounds them by; a record made with
other tables (all rowid tables, or both without) is resumed, written and
bounded the same way."""

from __future__ import annotations

import sqlite3

import pytest

from ramps.core.durable import OriginRecord
from ramps.core.events import Submit
from ramps.runtime.store import OriginStore

#: the tables as records made before ``WITHOUT ROWID`` hold them (rowid tables)
OLD_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE programs (
    program_id TEXT PRIMARY KEY, client TEXT NOT NULL, request_id INTEGER NOT NULL, record BLOB NOT NULL);
CREATE TABLE outcomes (
    client TEXT NOT NULL, request_id INTEGER NOT NULL, outcome BLOB NOT NULL, at REAL NOT NULL,
    PRIMARY KEY (client, request_id));
CREATE INDEX outcomes_at ON outcomes (at);
INSERT INTO meta VALUES ('team', 't'), ('robot', 'r1'), ('format', '1');
"""


def _record(i: int) -> OriginRecord:
    return OriginRecord(submit=Submit(program_id=f"r1#1-{i}", program="echo", args=b"\x80", work=1.0),
                        attempt=1, host="r2", live={1: "r2"}, made=1, ran_on=["r2"])


def _without_rowid(path) -> dict[str, bool]:
    with sqlite3.connect(path) as db:
        return {name: "WITHOUT ROWID" in sql.upper() for name, sql in
                db.execute("SELECT name, sql FROM sqlite_master WHERE type = 'table' AND name != 'meta'")}


def _write_and_bound(store: OriginStore) -> None:
    """Programs written, delivered one by one, their outcomes bounded to the newest 3."""
    store.save({f"r1#1-{i}": ("app", i, _record(i)) for i in range(5)}, [])
    for i in range(5):
        store.save({}, [(f"r1#1-{i}", "app", i, b"o%d" % i)])


def test_a_new_record_keys_its_programs_by_their_primary_key(tmp_path, monkeypatch):
    import ramps.runtime.store as st

    monkeypatch.setattr(st, "OUTCOMES_MAX", 3)
    store = OriginStore(tmp_path, team="t", robot="r1")
    assert _without_rowid(store.path) == {"programs": True, "outcomes": False}
    _write_and_bound(store)
    store.save({"r1#1-9": ("app", 9, _record(9))}, [])
    found = store.load()
    assert list(found.programs) == ["r1#1-9"] and found.programs["r1#1-9"][2] == _record(9)
    assert sorted(found.outcomes) == [("app", 2), ("app", 3), ("app", 4)]
    store.close()
    with sqlite3.connect(store.path) as db:  # an older node's bound of the outcomes
        db.execute("DELETE FROM outcomes WHERE rowid IN (SELECT rowid FROM outcomes ORDER BY at LIMIT 1)")
        assert db.execute("SELECT count(*) FROM outcomes").fetchone()[0] == 2


@pytest.mark.parametrize("without_rowid", [False, True], ids=["rowid-tables", "both-without-rowid"])
def test_a_record_with_other_tables_is_resumed_and_written(tmp_path, monkeypatch, without_rowid):
    import ramps.runtime.store as st

    monkeypatch.setattr(st, "OUTCOMES_MAX", 3)
    path = tmp_path / "t" / "r1.sqlite"
    path.parent.mkdir()
    schema = OLD_SCHEMA.replace("record BLOB NOT NULL);", "record BLOB NOT NULL) WITHOUT ROWID;").replace(
        "PRIMARY KEY (client, request_id));", "PRIMARY KEY (client, request_id)) WITHOUT ROWID;") \
        if without_rowid else OLD_SCHEMA
    with sqlite3.connect(path) as db:
        db.execute("PRAGMA journal_mode=WAL")
        db.executescript(schema)
        db.execute("INSERT INTO programs VALUES ('r1#1-7', 'app', 7, ?)", (st.encode_record(_record(7)),))
    store = OriginStore(tmp_path, team="t", robot="r1")
    assert _without_rowid(store.path) == {"programs": without_rowid, "outcomes": without_rowid}  # as they were
    assert list(store.load().programs) == ["r1#1-7"]
    _write_and_bound(store)
    store.save({}, [("r1#1-7", "app", 7, b"o7")])
    found = store.load()
    assert found.programs == {} and sorted(found.outcomes) == [("app", 3), ("app", 4), ("app", 7)]
    store.close()
