"""Relocation's kept and batched readings (``ramps.core.relocation``) are
the figures read one robot or one program at a time."""

from __future__ import annotations

import math
import random
from types import SimpleNamespace

from ramps.core.config import RampsConfig
from ramps.core.cost import shared_finish_time
from ramps.core.relocation import host_times, unsettled

from test_sim_scale_relocation import view


def unsettled_one_by_one(origin, now: float) -> frozenset[str]:
    """``unsettled`` read robot by robot through ``report_age`` and ``factor_seen``."""
    cfg = origin.config
    out = set()
    for robot in origin.view.robots():
        if robot == origin.me:
            continue
        age = origin.view.report_age(robot, now)
        seen = origin.factor_seen.get(robot)
        if age is None or age > cfg.relocate_stale or not (seen is None or now - seen[1] >= cfg.relocate_calm):
            out.add(robot)
    return frozenset(out)


def test_unsettled_is_the_robots_read_one_by_one() -> None:
    rng = random.Random(3)
    found = 0
    for seed in range(30):
        v = view(seed)
        seen = {f"r{i}": (1.0, rng.uniform(0.0, 30.0)) for i in range(0, 60, 3)}  # some not in the view
        seen["me"] = (1.0, 19.0)
        origin = SimpleNamespace(config=RampsConfig(), view=v, me="me", factor_seen=seen)
        for now in (15.0, 20.0, 25.0):
            got = unsettled(origin, now)
            assert got == unsettled_one_by_one(origin, now)
            found += len(got)
    assert found > 100


def test_the_program_left_out_of_its_hosts_pool_is_the_first_closest_to_its_estimate() -> None:
    origin = SimpleNamespace(config=RampsConfig(place_by="pool_end"))
    origin.view = view(1)
    now = 16.0
    checked = 0
    for row in origin.view.rows_and_best_rate(now)[0].values():
        host, cores, speed, ramps, bg, w = row
        others = origin.view.remaining_work(host, now, round(ramps), 30.0) or []
        if row[0] == "me" or not others:
            continue
        for left in (0.0, others[0], 30.0, 100.0):
            rest = list(others)
            rest.pop(min(range(len(rest)), key=lambda i: abs(rest[i] - left)))
            ap = SimpleNamespace(host=host, placed_host=host, work=30.0)
            own = host_times(origin, ap, now, row, left)[0]
            assert own == shared_finish_time(left, rest, cores, speed, bg, w) or math.isnan(own)
            checked += 1
    assert checked > 20


def test_rows_and_best_rate_are_the_scans_rows_and_their_fastest_rate() -> None:
    from ramps.core.cost import program_share

    for seed in range(20):
        v = view(seed)
        for now in (12.0, 16.0, 16.0, 25.0):  # twice: the rates kept from the first
            rows, best = v.rows_and_best_rate(now)
            scanned = v.scan(now, frozenset())
            assert list(rows.values()) == scanned
            rates = [s * program_share(c, r + 1.0, b, w) for _, c, s, r, b, w in scanned]
            assert best == max(rates, default=0.0)


def test_host_times_with_a_floor_leave_out_only_an_end_no_move_needs() -> None:
    from ramps.core.relocation import worth_moving

    rng = random.Random(5)
    origin = SimpleNamespace(config=RampsConfig(place_by="pool_end"))
    left_out = kept = 0
    for seed in range(20):
        origin.view = view(seed)
        for row in origin.view.rows_and_best_rate(16.0)[0].values():
            if row[0] == "me":
                continue
            for _ in range(5):
                work = rng.uniform(1.0, 60.0)
                ap = SimpleNamespace(host=row[0], placed_host=row[0], work=work)
                left, floor = rng.uniform(0.0, work), rng.uniform(0.0, 40.0)
                own, stay, freed = host_times(origin, ap, 16.0, row, left)
                with_floor = host_times(origin, ap, 16.0, row, left, floor)
                assert with_floor[:2] == (own, stay)
                wanted = worth_moving(origin, own, floor) or worth_moving(origin, stay, max(freed, floor))
                assert wanted == (worth_moving(origin, own, floor)
                                  or worth_moving(origin, stay, max(with_floor[2], floor)))
                if with_floor[2] == freed:
                    kept += 1
                else:
                    assert with_floor[2] == math.inf and not wanted
                    left_out += 1
    assert left_out > 50 and kept > 50
