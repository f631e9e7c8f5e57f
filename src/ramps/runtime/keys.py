"""Zenoh key expressions of a ramps team.

Everything a team says lives under ``ramps/<team>/``, so teams on one network
never hear each other:

    ramps/<team>/load/<robot>      load reports (pub/sub, every period; heard by
                                   the robots that place programs, applications
                                   and the robot's own name), and a queryable
                                   answering with the robot's newest report
                                   (an origin's first views of its teammates)
    ramps/<team>/load/<robot>/now  reports of the instant (its programs changed),
                                   for its teammates' nodes only
    ramps/<team>/msg/<robot>       protocol messages addressed to a robot
    ramps/<team>/client/<client>   outcomes for an application (client)
    ramps/<team>/alive/<robot>     liveliness token of a robot's node
    ramps/<team>/leaving/<robot>   liveliness token a node declares as it stops
                                   (it hands its programs back): not a crash
    ramps/<team>/app/<robot>/<client>
                                   liveliness token of an application connected
                                   to a robot's node to submit programs there
    ramps/<team>/where/<robot>/<incarnation>/<endpoints>
                                   liveliness token naming where a node listens
                                   (endpoints joined by ","), so a node that
                                   meets another under its name can say where
"""

from __future__ import annotations

import re

_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


def check_name(kind: str, name: str) -> str:
    """Team and robot names become key-expression chunks: keep them plain."""
    if not _NAME.match(name):
        raise ValueError(
            f"{kind} name {name!r} must be 1-64 characters of letters, digits, '_', '-' or '.'"
        )
    return name


def load(team: str, robot: str = "*") -> str:
    return f"ramps/{team}/load/{robot}"


def load_now(team: str, robot: str = "*") -> str:
    """Reports of the instant: a node's decisions read them, applications do not."""
    return f"ramps/{team}/load/{robot}/now"


def inbox(team: str, robot: str) -> str:
    return f"ramps/{team}/msg/{robot}"


def client(team: str, client_id: str) -> str:
    return f"ramps/{team}/client/{client_id}"


def alive(team: str, robot: str = "*") -> str:
    return f"ramps/{team}/alive/{robot}"


def leaving(team: str, robot: str = "*") -> str:
    return f"ramps/{team}/leaving/{robot}"


def app(team: str, robot: str, client_id: str = "*") -> str:
    """The token of an application (``client_id``) that submits through
    ``robot``'s node; with the default, the expression matching every one's."""
    return f"ramps/{team}/app/{robot}/{client_id}"


def where(team: str, robot: str = "*", incarnation: int | None = None, endpoints: list[str] | None = None) -> str:
    """The token naming where a node of ``robot`` listens; with the defaults,
    the expression that matches every robot's."""
    if incarnation is None:
        return f"ramps/{team}/where/{robot}/**"
    shown = ",".join(e for e in endpoints or [] if e and not set(e) & set("*$?#")) or "unknown"
    return f"ramps/{team}/where/{robot}/{incarnation:x}/{shown}"


def where_of(key: str) -> tuple[str, int, list[str]] | None:
    """(robot, incarnation, endpoints) of a ``where`` token's key, or None."""
    parts = key.split("/", 5)
    if len(parts) < 6 or parts[2] != "where":
        return None
    try:
        incarnation = int(parts[4], 16)
    except ValueError:
        return None
    return parts[3], incarnation, [e for e in parts[5].split(",") if e and e != "unknown"]


def robot_of(key: str) -> str:
    """The last chunk of a key: the robot a load report or token is about."""
    return key.rsplit("/", 1)[-1]


def keys_safe_id(name: str) -> str:
    """Turn any string (a host name, say) into a valid key chunk."""
    cleaned = "".join(c if c.isalnum() or c in "_-." else "-" for c in name)[:64]
    return cleaned or "x"
