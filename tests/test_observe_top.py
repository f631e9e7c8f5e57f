"""``ramps top`` against a real team: the model fed with real team views, and the command itself.

The model (ramps.observe.top.TopModel) is fed ``Team.status()`` of a real
three-robot team (tests/runtime_team.py) while a robot joins, programs run,
and a robot is killed under its programs: the view must show the join, grey
the dead robot with how long ago it was heard, and list the programs that
moved. The command runs as a subprocess: live until Ctrl-C, until the team
disappears, and in ``--frames`` mode on a secured team.
"""

from __future__ import annotations

import os
import pty
import re
import select
import signal
import subprocess
import sys
import time

import pytest
from rich.console import Console
from runtime_team import LocalTeam

from ramps.observe.top import TopModel, render

pytestmark = pytest.mark.slow


def watch_until(model: TopModel, team, cond, timeout: float, what: str) -> float:
    """Feed the model every 0.1 s until ``cond()``; returns the seconds it took."""
    start = time.monotonic()
    while True:
        model.update(team.status(), time.monotonic())
        if cond():
            return time.monotonic() - start
        if time.monotonic() - start > timeout:
            raise AssertionError(f"{what} not seen within {timeout} s; events: "
                                 + "; ".join(e.text for e in model.events))
        time.sleep(0.1)


def text_of(model: TopModel) -> str:
    c = Console(record=True, width=250, color_system=None)
    c.print(render(model, time.monotonic()))
    return c.export_text()


def top_cmd(t: LocalTeam, *extra: str, secure: bool = True) -> list[str]:
    creds = ["--secure", "--credentials", str(t.credentials("app"))] if secure else []
    return [sys.executable, "-m", "ramps.cli", "top", "--team", t.team, "--no-multicast",
            *sum((["--connect", e] for e in t.endpoints()), []), *creds, *extra]


def top_in_a_terminal(cmd: list[str], shown: bytes = rb"[1-9]\d* of \d+ robots alive",
                      timeout: float = 30.0) -> tuple[str, str, int]:
    """Run ``ramps top`` with a pseudo-terminal as its output, press Ctrl-C
    (SIGINT) a second after it first shows a match of the pattern ``shown``
    (by default: a frame with at least one robot heard; the first frame may
    come before any liveliness token on a loaded host), and return what it
    showed, its stderr and its exit status."""
    master, slave = pty.openpty()
    p = subprocess.Popen(cmd, stdout=slave, stderr=subprocess.PIPE, text=True, start_new_session=True,
                         env=dict(os.environ, COLUMNS="250", LINES="60"))
    os.close(slave)
    buf = b""
    try:
        deadline = time.monotonic() + timeout
        sent_at = None
        while p.poll() is None or select.select([master], [], [], 0)[0]:
            if select.select([master], [], [], 0.1)[0]:
                try:
                    buf += os.read(master, 1 << 16)  # keep draining: a full pty would block it
                except OSError:
                    break
            now = time.monotonic()
            if sent_at is None and re.search(shown, buf) and now > deadline - timeout + 1:
                time.sleep(1)
                p.send_signal(signal.SIGINT)
                sent_at = now
            if (sent_at is None and now > deadline) or (sent_at is not None and now > sent_at + 15):
                break
        assert sent_at is not None, f"ramps top showed no {shown!r} within {timeout:g} s"
        p.wait(15)
        err = p.stderr.read() if p.stderr else ""
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        os.close(master)
    return buf.decode(errors="replace"), err, p.returncode


def test_top_on_a_secured_team_shows_a_join_a_crash_and_programs_moving_then_quits(tmp_path):
    with LocalTeam(3, tmp_path, secure=True) as t:
        r = subprocess.run(top_cmd(t, "--frames", "3", "--interval", "0.3"), capture_output=True, text=True,
                           timeout=60)
        assert r.returncode == 0, r.stderr
        # three frames; the first may come before top has heard every robot's
        # liveliness token (on a loaded host r3's came 0.3 s after r1's and r2's)
        frames = [line for line in r.stdout.splitlines() if "robots alive" in line]
        assert len(frames) == 3 and "3 of 3 robots alive" in frames[-1], r.stdout
        # without credentials: a clear error, no traceback
        r = subprocess.run(top_cmd(t, secure=False), capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "secure mode" in r.stderr and "Traceback" not in r.stderr

        team = t.client("r1")
        model = TopModel()
        watch_until(model, team, lambda: len(model.alive()) == 3, 20, "three robots")
        t.start_node("r4")
        watch_until(model, team, lambda: any(e.kind == "joined" and e.robot == "r4" for e in model.events), 20,
                    "r4 joining")
        rr = team.options(policy="round_robin")
        futs = [rr.submit("sleepy", seconds=6.0, tag=f"t{i}") for i in range(8)]
        watch_until(model, team, lambda: model.robots["r3"].running, 30, "a program on r3")
        assert model.in_flight("r1") >= 1
        assert "sleepy" in text_of(model)
        killed_at = time.monotonic()
        t.kill_node("r3")
        watch_until(model, team, lambda: not model.robots["r3"].alive, 15, "r3 greyed")
        print(f"r3 greyed {time.monotonic() - killed_at:.2f} s after the SIGKILL was sent")
        gone = [e for e in model.events if e.kind == "gone" and e.robot == "r3"]
        assert gone and "program(s) were running there" in gone[0].text
        displaced = int(gone[0].text.split(", ")[-1].split()[0])  # "..., 2 program(s) were running there"
        watch_until(model, team, lambda: sum(e.kind == "moved" for e in model.events) >= displaced, 30,
                    f"the {displaced} programs of r3 moving")
        moved = [e for e in model.events if e.kind == "moved"]
        assert len(moved) == displaced and all("r3 ->" in e.text for e in moved)
        for f in futs:
            f.result(60)
        watch_until(model, team, lambda: any(e.kind == "finished" for e in model.events), 10, "a program finishing")
        page = text_of(model)
        row = next(line for line in page.splitlines() if line.lstrip("│┃ ").startswith("r3"))
        assert "gone" in row and "ago" in row  # still listed, with how long ago it was heard
        assert time.monotonic() - killed_at < 120

        # the command, in a terminal (a pty: rich draws live frames only there):
        # live until Ctrl-C, pressed once it shows the team
        out, err, rc = top_in_a_terminal(top_cmd(t, "--interval", "0.25"))
        assert rc == 0, err
        assert "r1" in out and "r3" in out and "Traceback" not in err and "interrupted" in err

        # and by itself when the team disappears
        p = subprocess.Popen(top_cmd(t, "--interval", "0.25", "--exit-after", "2"), stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, start_new_session=True)
        try:
            time.sleep(4)
            for name in t.alive():
                t.kill_node(name)
            out, err = p.communicate(timeout=30)
        finally:
            if p.poll() is None:
                p.kill()
        assert p.returncode == 0, err
        assert "gone: no robot alive" in err and "Traceback" not in err
