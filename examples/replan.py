"""Writing a ramps program: an ordinary function in a module that is
installed on every robot. Only its name and its arguments travel (msgpack,
checked against this signature before anything is sent); the code never does.

Register it on every robot's node:

    PYTHONPATH=examples ramps node --robot r1 --program replan:shortest_path

Then any robot's code can run it on the team (see submit_and_map.py), and
you can call it directly in a test, as here:

    >>> shortest_path(grid=["..", ".."], start=[0, 0], goal=[1, 1])["length"]
    2
"""

from __future__ import annotations

from collections import deque

import ramps


@ramps.program(work=0.5)  # declared cost in work units; origins learn the real one from finished runs
def shortest_path(grid: list[str], start: list[int], goal: list[int]) -> dict:
    """Breadth-first search on a grid of '.' (free) and '#' (blocked) cells.

    Returns {"length": steps, "path": [[row, col], ...]}, or length None and
    an empty path when the goal cannot be reached. Raise for bad input: the
    caller gets ProgramFailed with this traceback."""
    rows, cols = len(grid), len(grid[0]) if grid else 0
    for name, (r, c) in (("start", start), ("goal", goal)):
        if not (0 <= r < rows and 0 <= c < cols) or grid[r][c] != ".":
            raise ValueError(f"{name} {[r, c]} is not a free cell of the {rows}x{cols} grid")
    came: dict[tuple[int, int], tuple[int, int] | None] = {(start[0], start[1]): None}
    todo = deque([(start[0], start[1])])
    while todo:
        cell = todo.popleft()
        if cell == (goal[0], goal[1]):
            path = []
            at: tuple[int, int] | None = cell
            while at is not None:
                path.append(list(at))
                at = came[at]
            return {"length": len(path) - 1, "path": path[::-1]}
        r, c = cell
        for nxt in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
            if 0 <= nxt[0] < rows and 0 <= nxt[1] < cols and grid[nxt[0]][nxt[1]] == "." and nxt not in came:
                came[nxt] = cell
                todo.append(nxt)
    return {"length": None, "path": []}
