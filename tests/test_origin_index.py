"""An origin's indexes of live programs by host (``by_host``, ``offered``) let go of a
program when it is delivered, through the hosts it was put under (``hosts_of``), without
a walk over every host: through the real core (``FakeTeam``), a program written off on
one host and finished on another."""

from __future__ import annotations

from corehelpers import busy_origin_team, submit

from ramps.core.events import PeerLost


def test_a_delivered_program_leaves_every_host_index() -> None:
    team = busy_origin_team()
    submit(team, "p")
    team.deliver()
    origin = team.nodes["o"].origin
    first = team.program("p").host
    assert "p" in origin.by_host[first] and origin.hosts_of["p"] == {first}
    team.handle("o", PeerLost(robot=first))  # written off there: placed again elsewhere
    team.advance(team.now + 30.0)
    team.deliver()
    second = team.program("p").host
    assert second != first and origin.hosts_of["p"] >= {first, second}
    team.finish(second, "p", team.program("p").attempt, ok=True)
    assert team.delivered("p")
    assert "p" not in origin.hosts_of
    assert all("p" not in ids for ids in origin.by_host.values())
    assert all("p" not in ids for ids in origin.offered.values())
