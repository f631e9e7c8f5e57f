"""Arguments are checked against the program's annotated types at the
caller: in the client when it has the program (nothing is sent), in the
origin's node for a client that has not (nothing is placed). Both raise
``BadArguments`` naming the argument and the type it expects."""

from __future__ import annotations

import time
from typing import Annotated, Any

import msgspec
import pytest

from ramps.core.messages import SubmitProgram, decode
from ramps.errors import BadArguments
from ramps.runtime import argtypes
from ramps.runtime.client import Team
from ramps.runtime.registry import Registry
from ramps.runtime.settings import load_settings
from ramps.testing.memory import MemoryTeam


class Pose(msgspec.Struct):
    x: float
    y: float


class Robot:  # a class of its own: msgspec cannot check it, the program judges
    pass


def plan(seed: int, goals: list[tuple[float, float]], speed: float = 1.0, pose: Pose | None = None,
         budget: Annotated[int, msgspec.Meta(ge=0)] = 0, note=None, anything: Any = None,
         robot: Robot | None = None, **tags: str) -> None:
    """Its annotations are strings here (``from __future__ import annotations``)."""


def problem(**kwargs) -> str:
    try:
        argtypes.check(plan, dict({"seed": 1, "goals": []}, **kwargs))
    except TypeError as exc:
        return str(exc)
    return ""


def test_a_wrong_type_names_the_argument_and_the_type_it_expects():
    assert problem(seed="3") == "argument 'seed' must be int: Expected `int`, got `str`"
    assert problem(goals=[[1.0, 2.0], [3.0, "x"]]) == (
        "argument 'goals' must be list[tuple[float, float]]: Expected `float`, got `str` - at `goals[1][1]`")
    assert problem(seed=2.0) == "argument 'seed' must be int: Expected `int`, got `float`"
    assert problem(budget=-1) == "argument 'budget' must be int: Expected `int` >= 0"
    assert "argument 'pose'" in problem(pose={"x": 1.0}) and "missing required field `y`" in problem(pose={"x": 1})
    assert problem(colour=3) == "argument 'colour' must be str: Expected `str`, got `int`"  # **tags: str
    with pytest.raises(TypeError, match="unexpected keyword argument 'sed'"):  # names, as before
        argtypes.check(lambda seed: None, {"seed": 1, "sed": 1})


def test_what_a_node_decodes_fits_and_untyped_parameters_take_anything():
    # msgpack has no tuples nor classes: lists and dicts stand for them; an int is a fine float
    assert problem(goals=[[1, 2]], speed=2, pose={"x": 1, "y": 2.5}, colour="red") == ""
    assert problem(goals=[(1.0, 2.0)], pose=Pose(1.0, 2.0)) == ""
    assert problem(note=object(), anything={"a": [1]}, robot=Robot()) == ""
    assert problem(pose=None) == ""


def _sent_submits(client: Team) -> list[SubmitProgram]:
    return [m for m in (decode(data).msg for _, data, _ in client.transport.sent) if isinstance(m, SubmitProgram)]


def test_the_team_api_refuses_a_wrong_type_before_anything_is_sent():
    team = MemoryTeam({"r1": (2, 1.0)})
    app = team.connect("r1")
    try:
        team.run(1.0)
        t0 = time.perf_counter()
        with pytest.raises(BadArguments, match=r"'burn': argument 'seconds' must be float: Expected `float`, got `str`"):
            app.submit("burn", seconds="fast")  # burn(seconds: float = 1.0, ...)
        took = time.perf_counter() - t0
        print(f"\nwrong-type argument refused by the client in {took * 1e3:.3f} ms, nothing sent")
        assert _sent_submits(app) == [] and team.pools["r1"].ran == []
        assert app.pending() == 0
        fut = app.submit("burn", seconds=0)  # an int is a fine float
        team.run(1.0, until=fut.done)
        assert fut.result(0)["units"] == 0
    finally:
        app.close()
        team.close()


def test_a_node_refuses_a_wrong_type_from_a_client_without_the_program():
    team = MemoryTeam({"r1": (2, 1.0)})
    s = load_settings(flags={"team": team.team}, environ={}, default_robot=False)
    app = Team(s, robot="r1", timeout=1.0, transport=team.bus.transport("ros"), clock=team.clock,
               registry=Registry())  # knows no program: sends whatever it is given
    try:
        fut = app.submit("burn", seconds="fast")
        team.run(1.0, until=fut.done)
        with pytest.raises(BadArguments, match=r"'burn': argument 'seconds' must be float"):
            fut.result(0)
        assert len(_sent_submits(app)) == 1 and team.pools["r1"].ran == []  # sent, never placed
    finally:
        app.close()
        team.close()
