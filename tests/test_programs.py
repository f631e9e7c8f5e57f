"""Tests for ramps.programs: route planning (checked against brute force) and the CPU burn."""

from __future__ import annotations

import itertools
import subprocess
import sys

import msgspec
import pytest

from ramps.programs.burn import MAX_UNITS, burn, echo, noop
from ramps.programs.route import (
    ROUTE_SIZES,
    Order,
    Warehouse,
    bfs,
    distance_matrix,
    make_order,
    make_warehouse,
    plan_route,
)
from ramps.runtime.spin import ITERATIONS_PER_UNIT, spin

# ---------------------------------------------------------------- helpers


def brute_force_length(dist: list[list[int]], capacity: int) -> int:
    """Shortest route over nodes 0 = dropoff, 1 = start, 2.. = picks by enumerating every
    visiting order and every split of it into trips of at most ``capacity`` picks."""
    picks = list(range(2, len(dist)))
    best = None
    for perm in itertools.permutations(picks):
        # f[k]: shortest way to deliver perm[:k] and stand at the dropoff
        f = [float("inf")] * (len(perm) + 1)
        for k in range(len(perm) + 1):
            first = perm[:k]
            if len(first) <= capacity:
                hops = [1, *first, 0]
                f[k] = sum(dist[a][b] for a, b in itertools.pairwise(hops))
        for k in range(1, len(perm) + 1):
            for a in range(max(0, k - capacity), k):
                trip = [0, *perm[a:k], 0]
                f[k] = min(f[k], f[a] + sum(dist[x][y] for x, y in itertools.pairwise(trip)))
        best = f[-1] if best is None else min(best, f[-1])
    assert best is not None
    return int(best)


def check_route(result: dict, width: int, height: int, seed: int, picks: int) -> None:
    """The path walks free 4-neighbour steps from start to dropoff and visits every pick."""
    warehouse = make_warehouse(width, height, seed=seed)
    order = make_order(warehouse, picks, seed)
    blocked = warehouse.blocked()
    path = [tuple(c) for c in result["path"]]
    assert path[0] == tuple(result["start"])
    assert path[-1] == order.dropoff == tuple(result["dropoff"])
    assert len(path) - 1 == result["length"]
    for a, b in itertools.pairwise(path):
        assert abs(a[0] - b[0]) + abs(a[1] - b[1]) == 1, (a, b)
    for c in path:
        assert 0 <= c[0] < width and 0 <= c[1] < height and c not in blocked, c
    assert set(order.picks) <= set(path)
    visited = [tuple(c) for trip in result["trips"] for c in trip]
    assert sorted(visited) == sorted(order.picks)
    cap = result["capacity"] or picks
    assert all(len(trip) <= cap for trip in result["trips"])
    stops = [tuple(c) for c in result["order"]]
    assert stops[0] == tuple(result["start"]) and stops[-1] == order.dropoff
    assert [c for c in stops[1:-1] if c != order.dropoff] == visited
    msgspec.json.encode(result)  # travels as plain data


def optimum(width: int, height: int, picks: int, seed: int, capacity: int | None, start=None) -> int:
    warehouse = make_warehouse(width, height, seed=seed)
    order = make_order(warehouse, picks, seed)
    begin = order.start if start is None else tuple(start)
    dist = distance_matrix(warehouse, [order.dropoff, begin, *order.picks])
    return brute_force_length(dist, picks if capacity is None else capacity)


# ---------------------------------------------------------------- route


@pytest.mark.parametrize(
    ("width", "height", "picks", "seed", "capacity"),
    [
        (12, 8, 5, 0, None),
        (12, 8, 6, 1, None),
        (12, 8, 6, 2, 2),
        (12, 8, 6, 3, 4),
        (20, 12, 6, 4, 3),
        (9, 7, 4, 5, 1),
        (15, 9, 1, 6, 4),
    ],
)
def test_plan_route_is_optimal_and_valid(width: int, height: int, picks: int, seed: int, capacity: int | None) -> None:
    result = plan_route(width, height, picks, seed, capacity=capacity)
    assert result["optimal"] is True
    assert result["picks"] == picks
    assert result["length"] == result["bound"] == optimum(width, height, picks, seed, capacity)
    check_route(result, width, height, seed, picks)


def test_plan_route_is_deterministic() -> None:
    first = plan_route(16, 10, 7, 11)
    second = plan_route(16, 10, 7, 11)
    assert first["length"] == second["length"]
    assert first["order"] == second["order"]
    assert first["path"] == second["path"]


def test_different_starts_around_an_obstruction() -> None:
    """The paper's use: one program per free cell next to the robot's blocked position."""
    width, height, picks, seed = 14, 9, 5, 2
    warehouse = make_warehouse(width, height, seed=seed)
    blocked = warehouse.blocked()
    robot = (7, 4)
    starts = [
        (robot[0] + dx, robot[1] + dy)
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))
        if (robot[0] + dx, robot[1] + dy) not in blocked
    ]
    assert len(starts) >= 2
    lengths = []
    for start in starts:
        result = plan_route(width, height, picks, seed, start=list(start), capacity=3)
        assert result["start"] == list(start) and result["optimal"]
        assert result["length"] == optimum(width, height, picks, seed, 3, start=start)
        check_route(result, width, height, seed, picks)
        lengths.append(result["length"])
    assert min(lengths) >= 1


@pytest.mark.parametrize("where", ["pick", "dropoff"])
def test_start_on_a_pick_or_the_dropoff(where: str) -> None:
    order = make_order(make_warehouse(12, 8, seed=1), 5, 1)
    start = order.picks[2] if where == "pick" else order.dropoff
    result = plan_route(12, 8, 5, 1, start=start, capacity=2)
    assert result["length"] == optimum(12, 8, 5, 1, 2, start=start)
    check_route(result, 12, 8, 1, 5)


def test_time_limited_run_still_returns_a_valid_route() -> None:
    result = plan_route(20, 12, 12, 3, time_limit=1e-6)
    check_route(result, 20, 12, 3, 12)
    assert result["bound"] <= result["length"]


def test_tiny_preset() -> None:
    assert set(ROUTE_SIZES) == {"tiny", "small", "medium", "large"}
    preset = ROUTE_SIZES["tiny"]
    result = plan_route(**preset)
    assert result["optimal"]
    assert result["solve_seconds"] < 5
    assert result["length"] == optimum(preset["width"], preset["height"], preset["picks"], preset["seed"], preset["capacity"])
    check_route(result, preset["width"], preset["height"], preset["seed"], preset["picks"])


def test_warehouse_layout() -> None:
    warehouse = make_warehouse(20, 12, seed=3)
    assert warehouse == make_warehouse(20, 12, seed=3)
    blocked = warehouse.blocked()
    border = [(x, y) for x in range(20) for y in range(12) if x in (0, 19) or y in (0, 11)]
    assert not blocked & set(border)
    assert len(warehouse.shelves) > 20 * 12 // 3
    assert len(bfs(warehouse, (0, 0))[0]) == len(warehouse.free_cells())  # all connected
    order = make_order(warehouse, 8, 3)
    assert isinstance(order, Order) and len(set(order.picks)) == 8
    assert order.start not in blocked and order.dropoff == (10, 11)
    raw = msgspec.json.encode(warehouse)
    assert msgspec.json.decode(raw, type=Warehouse) == warehouse


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"width": 4}, "width"),
        ({"height": 3}, "height"),
        ({"width": 1000}, "width"),
        ({"picks": 0}, "picks"),
        ({"width": 5, "height": 5, "picks": 200}, "pick faces"),
        ({"capacity": 0}, "capacity"),
        ({"time_limit": 0}, "time_limit"),
        ({"workers": 0}, "workers"),
        ({"start": [99, 0]}, "start x"),
        ({"start": [1, 2, 3]}, "start"),
        ({"start": [2, 1]}, "not a free cell"),
        ({"width": 10.5}, "width"),
    ],
)
def test_validation(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        plan_route(**kwargs)


def test_importing_programs_does_not_import_ortools() -> None:
    code = (
        "import sys, ramps.programs, ramps.programs.route, ramps.programs.burn; "
        "assert 'ortools' not in sys.modules, 'ortools imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# ---------------------------------------------------------------- burn


def test_burn_does_the_requested_work_deterministically() -> None:
    first = burn(units=0.002)
    assert first["iterations"] == round(0.002 * ITERATIONS_PER_UNIT)
    assert first["units"] == 0.002
    assert burn(units=0.002) == first
    assert burn(0.002) == first  # seconds is shorthand for units
    assert burn(1.0, units=0.002) == first  # units wins
    other = burn(units=0.0021)
    assert other["checksum"] != first["checksum"]


def test_burn_checksum_matches_reference() -> None:
    x = 0x2545F491
    for _ in range(1000):
        x = (x * 1_103_515_245 + 12_345) % 2**32
    assert spin(1000) == x
    assert burn(0) == {"units": 0.0, "iterations": 0, "checksum": 0x2545F491}


@pytest.mark.parametrize("bad", [-1, -0.001, float("nan"), float("inf"), "1", True])
def test_burn_validation(bad: object) -> None:
    with pytest.raises(ValueError):
        burn(bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        burn(units=bad)  # type: ignore[arg-type]


def test_noop_and_echo() -> None:
    assert noop() == {}
    assert noop(a=1, b=[2]) == {}
    assert echo() == {}
    assert echo(a=1, b=[2, 3], c={"d": None}) == {"a": 1, "b": [2, 3], "c": {"d": None}}


def test_a_checkpointing_burn_gives_the_same_checksum_and_checks_its_argument() -> None:
    plain = burn(units=0.003)
    chunked = burn(units=0.003, checkpoint_every=0.001)  # outside a worker: checkpoints do nothing
    assert chunked["checksum"] == plain["checksum"] and chunked["resumed_at"] == 0
    for bad in (-1, float("nan"), "1", True, MAX_UNITS * 2):
        with pytest.raises(ValueError, match="checkpoint_every"):
            burn(units=0.001, checkpoint_every=bad)  # type: ignore[arg-type]
