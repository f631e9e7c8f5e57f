"""A team-size burst on emulated robots beside the simulator's run of the same team.

How this works: with ``ramps bench team-size --cpu-quota Q``, every node of
the team runs in a cpu cgroup of ``Q`` host cores (a robot of one emulated
core), told the speed of that core as measured here before the team starts
(``robot_speed``). The burst's programs are ``burn`` programs of
``program_seconds`` alone on such a core. ``compare`` then runs the
simulator on the same configuration (N robots of one core at that speed,
the same programs from the same origins, all submitted at once) and gives
three simulated makespans beside the real one:

* ``ideal``: robots whose ramps node costs nothing, the simulator's default;
* ``with_node``: each robot's node taking ``node_cpu`` of its core (what the
  nodes cost idle, measured on this team: on a robot of a fiftieth of a host
  core an idle node is a sizeable part of it);
* ``corrected``: the ideal run with robots slower by the ratio of the real
  programs' median turnaround to the simulator's (the speed the programs
  actually got, the node's share and the host's load included), as the
  testbed experiments correct for the host;
* ``busy_node``: each robot's node taking what it took during the burst,
  robot by robot (an origin's node handles its application's calls and
  watches its programs on other robots: on a robot of a fiftieth of a host
  core that is a tenth of its core, or more), the rest as in ``corrected``. The
  simulator takes at most half a core for a node (``NODE_CPU_MAX``).

A ratio is real over simulated. The distribution (programs per robot) is
given for both, since with identical programs it is what placement decides.
"""

from __future__ import annotations

import statistics
from collections import Counter
from typing import Any

from ramps.core.config import RampsConfig
from ramps.core.cost import NODE_CPU_MAX
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, PublisherSpec, RobotSpec, Scenario


def robot_speed(quota: float) -> float:
    """Work units a second of one emulated core of ``quota`` host cores, measured here."""
    from ramps.runtime.speed_probe import measure_speed

    return round(measure_speed(0.5, quota=quota, cores=1), 5)


def scenario(n: int, per_origin: dict[str, int], units: float, speed: float, node_cpu: float = 0.0,
             seed: int = 0, nodes: dict[str, float] | None = None) -> Scenario:
    """``n`` robots r1..rN of one core at ``speed``, each origin submitting its
    programs of ``units`` at once; ``nodes``: each robot's node's share of its core
    (else ``node_cpu`` each). Periodic reports go every ``PublisherSpec``'s period, or
    every ``RampsConfig.report_period`` where that is longer, as the real nodes' do in a
    team of ``n``."""
    programs = [ProgramSpec(program="burn", count=k, work=units, payload=50, result=100, origin=o, at=0.0)
                for o, k in per_origin.items() if k]
    robots = ([RobotSpec(name=f"r{i}", cores=1, speed=speed, node_cpu=min(nodes.get(f"r{i}", 0.0), NODE_CPU_MAX))
               for i in range(1, n + 1)] if nodes is not None else
              [RobotSpec(name="r{i}", count=n, cores=1, speed=speed, node_cpu=node_cpu)])
    config = RampsConfig()
    return Scenario(name=f"team-size-{n}r-{sum(per_origin.values())}p", seed=seed, robots=robots,
                    programs=programs, config=config,
                    publisher=PublisherSpec(period=max(PublisherSpec().period, config.report_period(1.0, n - 1))))


def _run(sc: Scenario) -> dict[str, Any]:
    res = simulate(sc)
    if res.lost or res.duplicated or res.completed != sum(p.count for p in sc.programs):
        raise RuntimeError(f"the simulator lost or duplicated programs of {sc.name}")
    turn = [p.delivered_at - p.submitted_at for p in res.programs if p.delivered_at is not None]
    return {"makespan_s": round(res.makespan, 2), "median_turnaround_s": round(statistics.median(turn), 2),
            "robots_by_programs": {str(k): v for k, v in sorted(Counter(res.distribution.values()).items())}}


def compare(burst: dict[str, Any], *, n: int, per_origin: dict[str, int], units: float, speed: float,
            node_cpu: float, burst_node_cpu: dict[str, float] | None = None) -> dict[str, Any]:
    """The simulator's makespans for the configuration of ``burst`` (``run_burst``'s
    figures from the emulated team), and the real one over each; ``burst_node_cpu``:
    each node's share of its core during the burst."""
    ideal = _run(scenario(n, per_origin, units, speed))
    with_node = _run(scenario(n, per_origin, units, speed, node_cpu=min(node_cpu, NODE_CPU_MAX)))
    out: dict[str, Any] = {"speed": speed, "units": units, "node_cpu": round(node_cpu, 3),
                           "ideal": ideal, "with_node": with_node}
    real, turn = burst.get("makespan_s"), burst.get("median_turnaround_s")
    if real and turn:
        factor = turn / ideal["median_turnaround_s"]
        corrected = _run(scenario(n, per_origin, units, speed / factor))
        out["host_factor"] = round(factor, 3)
        out["corrected"] = corrected
        keys = ["ideal", "with_node", "corrected"]
        if burst_node_cpu:
            # the corrected speed already lost a median node's share: the core's speed without it
            mid = statistics.median(burst_node_cpu.values())
            out["burst_node_cpu"] = {"median": round(mid, 3), "max": round(max(burst_node_cpu.values()), 3)}
            out["busy_node"] = _run(scenario(n, per_origin, units, speed / factor / (1.0 - min(mid, NODE_CPU_MAX)),
                                             nodes=burst_node_cpu))
            keys.append("busy_node")
        for key in keys:
            out[f"ratio_{key}"] = round(real / out[key]["makespan_s"], 3)
    return out
