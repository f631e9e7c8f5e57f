"""``ramps top`` (and ``Team.status()``) tell a robot that left (its node
stopped: Ctrl-C, SIGTERM; it handed its programs back) from one that
crashed: real nodes and client over the in-memory team
(``ramps.testing.memory``), in milliseconds."""

from __future__ import annotations

import msgspec
from rich.console import Console

from ramps.observe.top import TopModel, render
from ramps.testing.memory import MemoryTeam

from test_same_name import clone


def _events(model: TopModel, kind: str) -> list[str]:
    return [e.text for e in model.events if e.kind == kind]


def test_a_robot_that_stops_is_shown_as_left_and_one_killed_as_gone():
    team = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0), "r3": (4, 4.0)})
    client = None
    try:
        team.run(3.0)
        client = team.connect("r1")
        model = TopModel()
        model.update(client.status(), team.clock.t)
        futs = [client.options(work=20.0).submit("echo", x=i) for i in range(4)]
        team.run(2.0, complete=False, until=lambda: bool(team.pools["r2"].jobs and team.pools["r3"].jobs))
        team.run(1.1, complete=False)  # a client hears each robot's periodic report, the one that lists its programs
        model.update(client.status(), team.clock.t)
        team.stop("r2")  # as on SIGINT/SIGTERM: it hands its programs back
        team.run(0.5, complete=False)
        model.update(client.status(), team.clock.t)
        team.kill("r3")
        team.run(0.5, complete=False)
        model.update(client.status(), team.clock.t)
        status = {r.robot: r for r in client.status().robots}
        assert (status["r2"].alive, status["r2"].leaving) == (False, True)
        assert (status["r3"].alive, status["r3"].leaving) == (False, False)
        [left] = _events(model, "left")
        assert left.startswith("r2 left (its node stopped and handed ") and "back to their origins" in left
        [gone] = _events(model, "gone")
        assert gone.startswith("r3 gone (liveliness lost")
        moved = _events(model, "moved")
        assert any("r2 -> " in m and m.endswith("after r2 left") for m in moved)
        assert any("r3 -> " in m and m.endswith("after r3 was lost") for m in moved)
        c = Console(record=True, width=250, color_system=None)
        c.print(render(model, team.clock.t))
        table = c.export_text()
        rows = {line.strip("│ ").split()[0]: line for line in table.splitlines() if line[1:3] in ("r1", "r2", "r3")}
        assert " left 0.5 s ago " in rows["r2"] and " gone 0.0 s ago " in rows["r3"], table
        team.run(30.0, until=lambda: all(f.done() for f in futs))
        assert all(f.result(0)["x"] == i for i, f in enumerate(futs))
    finally:
        if client is not None:
            client.close()
        team.close()


def test_a_goodbye_heard_after_the_liveliness_went_turns_gone_into_left():
    team = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0)})
    try:
        team.run(3.0)
        client = team.connect("r1")
        team.run(1.5)  # the client hears load reports
        model = TopModel()
        model.update(client.status(), team.clock.t)
        team.kill("r2")
        st = client.status()
        model.update(st, team.clock.t)
        assert _events(model, "gone") and not _events(model, "left")
        late = msgspec.structs.replace(st, robots=[msgspec.structs.replace(r, leaving=r.robot == "r2")
                                                   for r in st.robots])
        model.update(late, team.clock.t + 0.1)
        assert not _events(model, "gone") and _events(model, "left") == ["r2 left (its node stopped)"]
        client.close()
    finally:
        team.close()


def test_a_node_refused_for_a_taken_name_does_not_make_the_holder_look_leaving():
    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})
    try:
        team.run(3.0)
        client = team.connect("r1")
        newcomer = clone(team, "r2", 99)  # started after r2: it leaves
        team.run(5.0)
        assert newcomer.wait(0) and newcomer.name_taken
        r2 = {r.robot: r for r in client.status().robots}["r2"]
        assert not r2.leaving  # (its alive flag is the memory bus's business: one key, two tokens)
        client.close()
    finally:
        team.close()
