"""Warehouse order-picking route planning, solved exactly with OR-Tools CP-SAT.

The paper's workload: "a warehouse robot encounters an obstruction and
generates RAMPs to explore routes starting from different adjacent
locations". Each program here plans one complete route from one start cell;
the robot's team runs several in parallel (``start`` = each free neighbour of
the obstruction) and keeps the shortest.

How this works:
    * The map is a grid (``Warehouse``): a free border corridor, double rows of
      shelves running north-south separated by one-cell aisles, cross aisles
      every ``aisle_every`` rows, and, from ``seed``, a few gaps in the shelving
      and a few pallets left in aisles (only where every free cell stays
      reachable). Robots move between 4-neighbouring free cells, one move = 1.
    * An ``Order`` is a start cell, ``picks`` distinct pick faces (free cells
      next to a shelf) and the dropoff (packing station, bottom corridor).
    * Distances are exact shortest paths by breadth-first search (pure Python).
    * The robot carries a tote of ``capacity`` items (one per pick). When the
      tote is full it must go back to the dropoff and start another trip; the
      robot starts empty. ``capacity=None`` (or >= picks) is one trip: a
      shortest Hamiltonian path start -> every pick -> dropoff.
    * CP-SAT model: node 0 = dropoff, 1 = start, 2.. = picks; one Boolean per
      arc; ``add_multiple_circuit`` (``add_circuit`` for one trip) with an arc
      dropoff -> start of cost 0 closes the start's trip into a circuit, and
      every other circuit through the dropoff is a further trip. Tote load
      per node: ``load[j] = load[i] + 1`` on a used arc i -> j (``= 1`` after
      the dropoff, ``load[start] = 0``), ``load <= capacity``; the number of
      trips is at least ceil(picks / capacity). The objective is the total
      number of moves. A greedy nearest-pick route is given as a hint and is
      the fallback if the solver stops before finding anything.

Rules:
    * Deterministic: same arguments -> same warehouse, order and optimal
      ``length``. With ``workers=1`` (the default: one program = one core, as in
      the paper) CP-SAT's search is deterministic, so the visiting order is
      the same too. A run stopped by ``time_limit`` returns its best route
      with ``optimal: False``; that route may depend on machine speed.
    * The result is JSON-friendly (ints, lists, bool, float): cells are [x, y].
    * Bad sizes raise ``ValueError`` before any solving.

Size knob: CPU seconds of one solve (``cpu_seconds``), ``workers=1``, on the
development machine (one AMD EPYC core, CPython 3.11, OR-Tools 9.15); median
over seeds 0-4 (0-5 for 13-17, 0-3 for 19) and [min-max]; ">90" = not proved
optimal within a 90 s limit. Grid 20x12, ``capacity=4`` (the default):

    picks   CPU seconds
      6     0.007   [0.007-0.009]
      8     0.013   [0.010-0.014]
     10     0.02    [0.02-0.04]
     12     0.3     [0.03-0.6]
     13     0.2     [0.05-1.0]
     14     0.7     [0.2-1.7]
     15     1.8     [0.4-7.4]
     16     14      [3-18]
     17     2.0     [0.9-16]
     18     68      [2->90]
     19     ~60     [41->90]
     20     >90     (3 of 3 seeds)

Growth is steep and the spread between seeds wide (it is NP-hard); instances
whose picks fill every trip (picks a multiple of ``capacity``, e.g. 16) are
harder than the next size up, which has a spare slot. ``capacity`` 3 or 5
shifts the table little (3: 14 picks 0.7 s; 5: 16 picks 4.5 s). A larger grid
changes little either (30x20, capacity 4: 12 picks 0.4 s, 14 picks 0.4 s, 16
picks 7 s). Without a tote limit (``capacity=None``, a pure shortest path)
CP-SAT is far faster: 20 picks 0.1 s, 30 picks 0.7 s, 40 picks 7 s [1->90]:
the trips are what make it hard. ``ROUTE_SIZES`` fixes seeds with measured,
reproducible times (one worker's search is deterministic, so the same
instance takes the same CPU time +-10% on the same machine).
"""

from __future__ import annotations

import itertools
import random
import time
from collections import deque
from typing import Any

import msgspec

from ramps.extras import require

Cell = tuple[int, int]

MAX_SIDE = 100
MAX_PICKS = 300
_MOVES: tuple[Cell, ...] = ((1, 0), (-1, 0), (0, 1), (0, -1))  # fixed order: deterministic paths

# Presets for plan_route(**ROUTE_SIZES[name]); CPU seconds of one solve,
# workers=1, measured twice each on the development machine (AMD EPYC core):
ROUTE_SIZES: dict[str, dict[str, Any]] = {
    "tiny": {"width": 12, "height": 8, "picks": 5, "capacity": 4, "seed": 0},  # 0.012 s, length 32
    "small": {"width": 20, "height": 12, "picks": 15, "capacity": 4, "seed": 4},  # 0.69-0.73 s, length 109
    "medium": {"width": 20, "height": 12, "picks": 16, "capacity": 4, "seed": 2},  # 3.1-3.5 s, length 126
    "large": {"width": 20, "height": 12, "picks": 19, "capacity": 4, "seed": 2},  # 41.0-41.1 s, length 138
}


class Warehouse(msgspec.Struct, frozen=True):
    """A grid map; every cell not in ``shelves`` or ``obstacles`` is free."""

    width: int
    height: int
    shelves: tuple[Cell, ...]
    obstacles: tuple[Cell, ...] = ()

    def blocked(self) -> frozenset[Cell]:
        return frozenset(self.shelves) | frozenset(self.obstacles)

    def free_cells(self) -> list[Cell]:
        blocked = self.blocked()
        return [(x, y) for y in range(self.height) for x in range(self.width) if (x, y) not in blocked]

    def pick_faces(self) -> list[Cell]:
        """Free cells next to a shelf, where a robot stands to pick an item."""
        shelves = frozenset(self.shelves)
        blocked = self.blocked()
        return [
            (x, y)
            for y in range(self.height)
            for x in range(self.width)
            if (x, y) not in blocked and any((x + dx, y + dy) in shelves for dx, dy in _MOVES)
        ]


class Order(msgspec.Struct, frozen=True):
    """Where the robot is, the cells it must visit, and where it must end."""

    start: Cell
    picks: tuple[Cell, ...]
    dropoff: Cell


def _check_int(name: str, value: Any, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < low or (high is not None and value > high):
        bound = f">= {low}" if high is None else f"between {low} and {high}"
        raise ValueError(f"{name} must be {bound}, got {value}")
    return value


def bfs(warehouse: Warehouse, source: Cell) -> tuple[dict[Cell, int], dict[Cell, Cell]]:
    """Shortest-path distances and parents from ``source`` over free cells (4-neighbour moves)."""
    blocked = warehouse.blocked()
    w, h = warehouse.width, warehouse.height
    dist: dict[Cell, int] = {source: 0}
    parent: dict[Cell, Cell] = {}
    queue = deque([source])
    while queue:
        cell = queue.popleft()
        x, y = cell
        for dx, dy in _MOVES:
            nxt = (x + dx, y + dy)
            if 0 <= nxt[0] < w and 0 <= nxt[1] < h and nxt not in blocked and nxt not in dist:
                dist[nxt] = dist[cell] + 1
                parent[nxt] = cell
                queue.append(nxt)
    return dist, parent


def distance_matrix(warehouse: Warehouse, cells: list[Cell]) -> list[list[int]]:
    """Exact shortest-path distances between ``cells``; ValueError if one is unreachable."""
    rows = []
    for a in cells:
        dist, _ = bfs(warehouse, a)
        for b in cells:
            if b not in dist:
                raise ValueError(f"cell {list(b)} cannot be reached from {list(a)}")
        rows.append([dist[b] for b in cells])
    return rows


def _connected(width: int, height: int, blocked: set[Cell], source: Cell) -> bool:
    free = width * height - len(blocked)
    return len(bfs(Warehouse(width, height, tuple(blocked)), source)[0]) == free


def make_warehouse(width: int, height: int, *, aisle_every: int = 6, seed: int = 0) -> Warehouse:
    """A deterministic warehouse: border corridor, double shelf rows, aisles, a few seeded variations."""
    _check_int("width", width, 5, MAX_SIDE)
    _check_int("height", height, 5, MAX_SIDE)
    _check_int("aisle_every", aisle_every, 2)
    rng = random.Random(f"warehouse:{width}:{height}:{aisle_every}:{seed}")
    shelves: set[Cell] = set()
    for x in range(1, width - 1):
        if (x - 1) % 3 == 0:  # north-south aisle, then two shelf columns back to back
            continue
        for y in range(1, height - 1):
            if y % aisle_every != 0:  # cross aisles every aisle_every rows
                shelves.add((x, y))
    for cell in sorted(shelves):  # a few gaps in the shelving
        if rng.random() < 0.04:
            shelves.discard(cell)
    aisles = [
        (x, y)
        for y in range(1, height - 1)
        for x in range(1, width - 1)
        if (x, y) not in shelves
    ]
    obstacles: set[Cell] = set()
    for cell in rng.sample(aisles, min(len(aisles), width * height // 60)):  # pallets left in aisles
        trial = shelves | obstacles | {cell}
        if _connected(width, height, trial, (0, 0)):
            obstacles.add(cell)
    return Warehouse(width, height, tuple(sorted(shelves)), tuple(sorted(obstacles)))


def make_order(warehouse: Warehouse, picks: int, seed: int = 0) -> Order:
    """``picks`` distinct pick faces, a free start cell and the dropoff (middle of the bottom corridor)."""
    _check_int("picks", picks, 1, MAX_PICKS)
    dropoff = (warehouse.width // 2, warehouse.height - 1)
    faces = [c for c in warehouse.pick_faces() if c != dropoff]
    if picks > len(faces):
        raise ValueError(
            f"picks={picks} exceeds the {len(faces)} pick faces of a "
            f"{warehouse.width}x{warehouse.height} warehouse"
        )
    rng = random.Random(f"order:{picks}:{seed}")
    chosen = rng.sample(faces, picks)
    taken = set(chosen) | {dropoff}
    others = [c for c in warehouse.free_cells() if c not in taken]
    start = rng.choice(others) if others else dropoff
    return Order(start=start, picks=tuple(chosen), dropoff=dropoff)


def _greedy(dist: list[list[int]], capacity: int) -> list[int]:
    """Nearest-pick route over nodes (0 dropoff, 1 start, 2.. picks) as a node sequence from 1 to 0."""
    left = list(range(2, len(dist)))
    seq, here, load = [1], 1, 0
    while left:
        if load == capacity:
            seq.append(0)
            here, load = 0, 0
        nxt = min(left, key=lambda j: (dist[here][j], j))
        left.remove(nxt)
        seq.append(nxt)
        here, load = nxt, load + 1
    seq.append(0)
    return seq


def _solve(dist: list[list[int]], capacity: int, time_limit: float, workers: int) -> tuple[list[int], str, int]:
    """Exact CP-SAT solve; returns (node sequence from start to dropoff, status name, best bound)."""
    # lazy: importing ramps.programs stays cheap
    from ortools.sat.python import cp_model

    n = len(dist)
    picks = n - 2
    trips_allowed = capacity < picks
    model = cp_model.CpModel()
    load = [model.new_int_var(0, min(capacity, picks), f"load{i}") for i in range(n)]
    model.add(load[1] == 0)
    arcs: dict[tuple[int, int], Any] = {}
    for i in range(n):
        for j in range(n):
            if i == j or (j == 1 and i != 0):
                continue  # only the closing arc dropoff -> start enters the start
            if i == 0 and j != 1 and not trips_allowed:
                continue  # one trip: the dropoff is entered once, at the end
            if i == 1 and j == 0 and not trips_allowed:
                continue
            arcs[i, j] = model.new_bool_var(f"x{i}_{j}")
    for (i, j), lit in arcs.items():
        if j >= 2:
            if i == 0:
                model.add(load[j] == 1).only_enforce_if(lit)
            else:
                model.add(load[j] == load[i] + 1).only_enforce_if(lit)
    circuit = [(i, j, lit) for (i, j), lit in arcs.items()]
    if trips_allowed:
        model.add_multiple_circuit(circuit)
        model.add(sum(lit for (i, _), lit in arcs.items() if i == 0) >= -(-picks // capacity))
    else:
        model.add_circuit(circuit)
    model.minimize(sum(dist[i][j] * lit for (i, j), lit in arcs.items() if (i, j) != (0, 1)))

    hint = _greedy(dist, capacity)
    used = set(itertools.pairwise(hint)) | {(0, 1)}
    for key, lit in arcs.items():
        model.add_hint(lit, key in used)

    solver = cp_model.CpSolver()
    solver.parameters.num_workers = workers
    solver.parameters.max_time_in_seconds = time_limit
    solver.parameters.random_seed = 0
    status = solver.solve(model)
    name = solver.status_name(status)
    if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        return hint, name, 0
    succ: dict[int, list[int]] = {}
    for (i, j), lit in arcs.items():  # arcs in insertion order: deterministic trip order
        if (i, j) != (0, 1) and solver.boolean_value(lit):
            succ.setdefault(i, []).append(j)
    seq, here = [1], 1
    while True:
        here = succ[here].pop(0)
        seq.append(here)
        if here == 0 and not succ.get(0):
            break
    return seq, name, round(solver.best_objective_bound)


def plan_route(
    width: int = 20,
    height: int = 12,
    picks: int = 8,
    seed: int = 0,
    start: tuple[int, int] | list[int] | None = None,
    time_limit: float = 60.0,
    workers: int = 1,
    *,
    capacity: int | None = 4,
    aisle_every: int = 6,
) -> dict[str, Any]:
    """Plan the shortest route for the order of ``make_order(make_warehouse(width, height), picks, seed)``.

    ``start`` overrides the order's start cell (a free cell, [x, y]). Returns
    ``{"length", "order", "trips", "path", "optimal", "status", "bound",
    "solve_seconds", "picks", "capacity", "start", "dropoff"}``: ``order`` is
    the stops in visiting order (start, picks, the dropoff after each trip),
    ``path`` every cell walked (``len(path) - 1 == length``).
    """
    warehouse = make_warehouse(width, height, aisle_every=aisle_every, seed=seed)
    order = make_order(warehouse, picks, seed)
    if capacity is not None:
        _check_int("capacity", capacity, 1)
    if isinstance(time_limit, bool) or not isinstance(time_limit, (int, float)) or not time_limit > 0:
        raise ValueError(f"time_limit must be a positive number of seconds, got {time_limit!r}")
    _check_int("workers", workers, 1, 64)
    begin: Cell = order.start
    if start is not None:
        if not isinstance(start, (tuple, list)) or len(start) != 2:
            raise ValueError(f"start must be [x, y], got {start!r}")
        sx = _check_int("start x", start[0], 0, width - 1)
        sy = _check_int("start y", start[1], 0, height - 1)
        begin = (sx, sy)
        if begin in warehouse.blocked():
            raise ValueError(f"start {list(begin)} is a shelf or obstacle, not a free cell")
    cells = [order.dropoff, begin, *order.picks]
    dist = distance_matrix(warehouse, cells)
    cap = picks if capacity is None else min(capacity, picks)

    require("ortools", "route_plan")  # the `route` extra: one clear line when it is missing
    import ortools.sat.python.cp_model  # noqa: F401  (lazy; imported before the clock starts)

    wall0, cpu0 = time.perf_counter(), time.process_time()
    seq, status, bound = _solve(dist, cap, float(time_limit), workers)
    solve_seconds, cpu_seconds = time.perf_counter() - wall0, time.process_time() - cpu0

    length = sum(dist[a][b] for a, b in itertools.pairwise(seq))
    trips: list[list[list[int]]] = [[]]
    for node in seq[1:-1]:
        if node == 0:
            trips.append([])
        else:
            trips[-1].append(list(cells[node]))
    path: list[list[int]] = [list(begin)]
    for a, b in itertools.pairwise(seq):
        _, parent = bfs(warehouse, cells[a])
        leg, cell = [], cells[b]
        while cell != cells[a]:
            leg.append(list(cell))
            cell = parent[cell]
        path.extend(reversed(leg))
    return {
        "length": length,
        "order": [list(cells[node]) for node in seq],
        "trips": trips,
        "path": path,
        "optimal": status == "OPTIMAL",
        "status": status,
        "bound": bound if status == "OPTIMAL" else min(bound, length),
        "solve_seconds": round(solve_seconds, 4),
        "cpu_seconds": round(cpu_seconds, 4),
        "picks": picks,
        "capacity": capacity,
        "start": list(begin),
        "dropoff": list(order.dropoff),
    }
