"""A node under systemd (ramps.runtime.service): readiness, status, the watchdog.

The sd_notify protocol is a datagram per notification on ``$NOTIFY_SOCKET``;
these tests bind that socket themselves. One runs a real ``ramps node``
process as systemd would (``NOTIFY_SOCKET``, ``WATCHDOG_USEC``,
``WATCHDOG_PID``) and SIGTERMs it; one blocks a real node's driver thread and
sees the watchdog go hungry; the rest are the pure parts with a fake clock.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import psutil
import pytest

from ramps.runtime.service import HEALTH_STALE, Notifier, Service, Watchdog, healthy, touch, watchdog_interval
from ramps.runtime.service import main as service_main
from ramps.testing.memory import MemoryBus, MemoryPool, StillSampler


@pytest.fixture
def notify_socket():
    """A bound unix datagram socket, as systemd's notify socket, and its path."""
    d = tempfile.mkdtemp(prefix="ramps-sd-", dir="/tmp")  # short: unix socket paths are at most 107 bytes
    path = os.path.join(d, "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    try:
        yield sock, path
    finally:
        sock.close()
        os.unlink(path)
        os.rmdir(d)


def _receive(sock: socket.socket, until, timeout: float) -> list[str]:
    """Datagrams until ``until(received)`` is true or ``timeout`` passes."""
    got: list[str] = []
    deadline = time.monotonic() + timeout
    while not until(got) and time.monotonic() < deadline:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            got.append(sock.recv(4096).decode())
        except socket.timeout:
            break
    return got


def _drain(sock: socket.socket) -> list[str]:
    sock.settimeout(0)
    got = []
    while True:
        try:
            got.append(sock.recv(4096).decode())
        except BlockingIOError:
            return got


# ------------------------------------------------------------ a real node process
@pytest.mark.slow
def test_real_node_says_ready_feeds_the_watchdog_and_says_stopping(notify_socket, tmp_path):
    sock, path = notify_socket
    env = {**os.environ, "NOTIFY_SOCKET": path, "WATCHDOG_USEC": "400000", "RAMPS_CONFIG": ""}
    env.pop("WATCHDOG_PID", None)
    team = f"svc{uuid.uuid4().hex[:8]}"
    cmd = [sys.executable, "-m", "ramps.cli", "node", "--robot", "svc1", "--team", team, "--no-multicast",
           "--listen", "tcp/127.0.0.1:0", "--speed", "1", "--cores", "1", "--node-nice", "0"]
    # as systemd does: WATCHDOG_PID is the main process, the one that execs ramps
    p = subprocess.Popen(["/bin/sh", "-c", 'WATCHDOG_PID=$$; export WATCHDOG_PID; exec "$@"', "sh", *cmd],
                         env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    try:
        got = _receive(sock, lambda g: any("READY=1" in d for d in g), 60)
        assert got and "READY=1" in got[-1].splitlines(), (got, p.poll())
        assert not any("WATCHDOG=1" in d for d in got[:-1])  # ready comes first
        assert "STATUS=robot svc1 in team " + team in got[-1]
        feeds = _receive(sock, lambda g: sum(d == "WATCHDOG=1" for d in g) >= 3, 30)
        assert sum(d == "WATCHDOG=1" for d in feeds) >= 3, feeds
        # the node's worker processes never see the notify socket
        children = psutil.Process(p.pid).children(recursive=True)
        assert children, "the node started no worker processes"
        for c in children:
            try:
                assert "NOTIFY_SOCKET" not in c.environ() and "WATCHDOG_USEC" not in c.environ()
            except psutil.NoSuchProcess:
                pass
        p.send_signal(signal.SIGTERM)
        rest = _receive(sock, lambda g: any("STOPPING=1" in d for d in g), 30)
        assert any("STOPPING=1" in d.splitlines() for d in rest), rest
        assert p.wait(30) == 0, p.stderr.read() if p.stderr else ""
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(10)
        if p.stderr:
            p.stderr.close()


# ------------------------------------------------------------ a real driver that stalls
@pytest.mark.slow
def test_a_stalled_driver_stops_feeding_the_watchdog_and_resumes(notify_socket, tmp_path):
    from ramps.runtime.node import NodeRuntime
    from ramps.runtime.settings import load_settings

    sock, path = notify_socket
    s = load_settings(flags={"robot": "w1", "team": "svc", "cores": 1, "speed": 1.0}, environ={})
    rt = NodeRuntime(s, transport=MemoryBus().transport("w1"), worker_pool=MemoryPool,
                     load_sampler=StillSampler, incarnation=1).start()
    health = tmp_path / "alive"
    service = Service(Notifier(path), watchdog_s=0.2, health_file=str(health))
    try:
        service.attach(rt)
        fed = _receive(sock, lambda g: len(g) >= 3, 30)
        assert fed[:3] == ["WATCHDOG=1"] * 3, fed
        assert healthy(str(health)) and service_main([str(health)]) == 0  # the container's HEALTHCHECK
        # the driver stalls: a call that does not return holds its loop
        entered, release = threading.Event(), threading.Event()
        with pytest.raises(TimeoutError):  # queued; the driver takes it and stays in it
            rt.call(lambda: (entered.set(), release.wait(30)), timeout=0)
        assert entered.wait(30)
        _drain(sock)  # a feed already on its way
        fed_before = service.watchdog.fed
        time.sleep(0.6)  # three times the interval: systemd would have killed it
        assert _drain(sock) == [] and service.watchdog.fed == fed_before
        assert service.watchdog.quiet_for() >= 0.5
        release.set()  # the loop turns again: fed again
        assert _receive(sock, lambda g: len(g) >= 1, 30) == ["WATCHDOG=1"]
    finally:
        release.set()
        service.close()
        rt.stop()
    assert not health.exists() and service_main([str(health)]) == 1  # a node that left is not healthy


def test_health_file_goes_stale(tmp_path):
    f = tmp_path / "alive"
    touch(str(f))
    assert healthy(str(f))
    os.utime(f, (time.time() - HEALTH_STALE - 1,) * 2)
    assert not healthy(str(f)) and service_main([str(f)]) == 1


# ------------------------------------------------------------ the pure parts
class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_watchdog_feeds_at_half_the_interval_and_only_when_the_loop_turns():
    clock = FakeClock()
    sent: list[float] = []
    wd = Watchdog(lambda: sent.append(clock.t), 10.0, clock=clock)
    for _ in range(100):  # a loop turning every 0.1 s for 10 s
        wd.turned()
        clock.t += 0.1
    assert len(sent) == 2 and sent[1] - sent[0] == pytest.approx(5.0, abs=0.11)
    clock.t += 30.0  # stalled: the loop does not turn, nobody feeds
    assert len(sent) == 2 and wd.quiet_for() >= 30.0
    wd.turned()
    assert len(sent) == 3


def test_waker_wakes_an_idle_loop_but_never_feeds():
    clock = FakeClock()
    fed: list[int] = []
    woken = threading.Event()
    wd = Watchdog(lambda: fed.append(1), 0.2, clock=clock)
    clock.t += 1.0  # the loop has not turned for a while
    wd.start_waker(woken.set)
    try:
        assert woken.wait(10)
        assert fed == []
    finally:
        wd.stop()


def test_watchdog_interval_follows_sd_watchdog_enabled():
    assert watchdog_interval({}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "30000000"}) == 30.0
    assert watchdog_interval({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "soon"}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "500000", "WATCHDOG_PID": str(os.getpid())}) == 0.5
    assert watchdog_interval({"WATCHDOG_USEC": "500000", "WATCHDOG_PID": "1"}, pid=2) is None  # meant for another


def test_from_environ_takes_the_variables_out_and_is_a_noop_without_a_socket(notify_socket):
    sock, path = notify_socket
    env = {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "1000000", "WATCHDOG_PID": str(os.getpid()), "OTHER": "x"}
    svc = Service.from_environ(env)
    try:
        assert env == {"OTHER": "x"} and svc.active and svc.watchdog_s == 1.0
        svc.ready("joined")
        svc.status("busy")
        svc.stopping()
        assert _receive(sock, lambda g: len(g) >= 3, 10) == ["READY=1\nSTATUS=joined", "STATUS=busy", "STOPPING=1"]
    finally:
        svc.close()
    quiet = Service.from_environ({})
    assert not quiet.active
    quiet.ready("nobody listens")  # no-op
    quiet.attach(object())  # no watchdog: nothing to attach
    quiet.close()


def test_abstract_socket_and_a_manager_that_went_away():
    name = f"ramps-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    n = Notifier("@" + name)
    try:
        assert n.notify("READY=1")
        assert sock.recv(100) == b"READY=1"
    finally:
        sock.close()
    assert not n.notify("WATCHDOG=1")  # nobody listens any more: counted, never raised
    assert n.failed == 1
    n.close()
    with pytest.raises(ValueError):
        Notifier("relative/path")


def test_unit_files_name_what_the_runtime_does():
    """The shipped unit is Type=notify with a watchdog, and runs `ramps node`."""
    root = Path(__file__).resolve().parents[1] / "packaging" / "systemd"
    for unit in ("ramps-node.service", "ramps-node@.service"):
        text = (root / unit).read_text()
        assert "Type=notify" in text and "WatchdogSec=" in text and "ramps node" in text
        assert "KillMode=mixed" in text  # SIGTERM to the node only: it hands its programs back
