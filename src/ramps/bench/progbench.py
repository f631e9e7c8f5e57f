"""``python -m ramps.bench.progbench``: what executables, progress and the ROS face cost.

How this works: a real three-robot team on this machine (``LocalTeam``, 2
cores each) registers two executables next to the built-in Python ``echo``:
``shecho`` (``/bin/sh`` running ``cat``: the JSON arguments come back as the
result) and ``pyecho`` (a Python script doing the same: an interpreter
start per call). Robot r1's client calls each ``--calls`` times, one after
the other, and times submit -> result. ``progress`` reports
``RAMPS_PROGRESS 0.5 <wall time>`` and sleeps: the delay until the client's
future shows it is the progress latency (same host, same clock). With the
``ros`` extra, ``ramps ros`` is started for r1 and a plain rclpy client
sends ``echo`` goals: goal -> result over ROS + ramps. Last, the start-up of
``import ramps.cli`` with rclpy importable and with it hidden (the ROS
extra must not slow ramps). Prints the figures and saves them as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

SHECHO = "#!/bin/sh\nexec cat\n"
#: starts a grandchild, says both pids in the file named by its "mark" argument, waits
HANG = ("#!/bin/sh\nmark=$(sed 's/.*\"mark\": *\"\\([^\"]*\\)\".*/\\1/')\nsleep 300 &\n"
        "echo $$ $! > \"$mark.tmp\"\nmv \"$mark.tmp\" \"$mark\"\nwait\n")
PYECHO = f"#!{sys.executable}\nimport json, sys\njson.dump(json.load(sys.stdin), sys.stdout)\n"
PROGRESS = (f"#!{sys.executable}\nimport json, sys, time\njson.load(sys.stdin)\n"
            "print(f'RAMPS_PROGRESS 0.5 {time.time():.6f}', file=sys.stderr, flush=True)\n"
            "time.sleep(1.0)\nprint('null')\n")


def _summary(xs: list[float]) -> dict[str, float]:
    xs = sorted(xs)
    return {"n": len(xs), "min_ms": 1000 * xs[0], "p50_ms": 1000 * statistics.median(xs),
            "p95_ms": 1000 * xs[min(len(xs) - 1, int(0.95 * len(xs)))], "max_ms": 1000 * xs[-1]}


def _timed(team, program: str, calls: int, **args) -> list[float]:
    out = []
    for i in range(calls):
        t0 = time.perf_counter()
        team.submit(program, i=i, **args).result(60)
        out.append(time.perf_counter() - t0)
    return out


def _progress_latency(team, calls: int) -> list[float]:
    out = []
    for _ in range(calls):
        seen = threading.Event()
        lat: list[float] = []

        def on_update(f, lat=lat, seen=seen):
            if f.progress is not None and not lat:
                lat.append(time.time() - float(f.progress_detail))
                seen.set()

        fut = team.submit("progress")
        fut.add_update_callback(on_update)
        fut.result(60)
        if lat:
            out.append(lat[0])
    return out


def _withdrawal(team, tmp: str, calls: int) -> list[float]:
    """fut.cancel() of a running executable -> its process group gone from the process table."""
    import psutil

    out = []
    for i in range(calls):
        mark = Path(tmp) / f"hang{i}"
        fut = team.submit("hang", mark=str(mark))
        deadline = time.monotonic() + 60
        while not mark.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        pids = [int(x) for x in mark.read_text().split()]
        t0 = time.perf_counter()
        fut.cancel()
        while any(psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE for p in pids):
            if time.perf_counter() - t0 > 30:
                raise RuntimeError(f"processes {pids} of a withdrawn executable survived 30 s")
            time.sleep(0.002)
        out.append(time.perf_counter() - t0)
    return out


def _ros_latency(lt, calls: int) -> dict | None:
    from ramps.ros import missing

    if missing() is not None:
        return {"skipped": missing()}
    import random
    import uuid

    os.environ["ROS_DOMAIN_ID"] = str(random.randint(1, 100))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    face = subprocess.Popen([sys.executable, "-m", "ramps.cli", "ros", "--team", lt.team, "--robot", "r1",
                             "--no-multicast", "--connect", lt.seed], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=dict(os.environ), start_new_session=True)
    rclpy.init()
    node = rclpy.create_node(f"bench_{uuid.uuid4().hex[:6]}")
    try:
        rel = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        pub = node.create_publisher(String, "/r1/ramps/goal", rel)
        results: dict[str, float] = {}

        def heard(msg: String) -> None:
            results.setdefault(json.loads(msg.data)["goal_id"], time.perf_counter())

        node.create_subscription(String, "/r1/ramps/result", heard, latched)
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        time.sleep(1.0)  # let the result subscription match too
        out = []
        for i in range(calls):
            gid = f"b{i}"
            t0 = time.perf_counter()
            pub.publish(String(data=json.dumps({"goal_id": gid, "program": "echo", "args": {"i": i}})))
            end = time.monotonic() + 60
            while gid not in results and time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.01)
            if gid in results:
                out.append(results[gid] - t0)
        topics = _summary(out) if out else {"skipped": "no result came back"}
        return {"topics": topics, "action": _action_latency(node, calls)}
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        face.terminate()
        try:
            face.wait(20)
        except subprocess.TimeoutExpired:
            face.kill()


def _action_latency(node, calls: int) -> dict:
    """send_goal -> result of the RunProgram action (echo), if it is built."""
    try:
        from ramps_interfaces.action import RunProgram
    except ImportError:
        return {"skipped": "ramps_interfaces not built (ramps ros --build-interfaces)"}
    import rclpy
    from rclpy.action import ActionClient

    # RunProgram is generated by ramps ros --build-interfaces, without type hints
    client: ActionClient[Any, Any, Any] = ActionClient(node, RunProgram, "/r1/ramps/run")
    if not client.wait_for_server(timeout_sec=30):
        return {"skipped": "no RunProgram action server"}
    out = []
    for i in range(calls):
        t0 = time.perf_counter()
        sent = client.send_goal_async(RunProgram.Goal(program="echo", args_json=json.dumps({"i": i})))
        rclpy.spin_until_future_complete(node, sent, timeout_sec=60)
        handle = sent.result()
        if handle is None:  # the goal was not answered in time
            continue
        res = handle.get_result_async()
        rclpy.spin_until_future_complete(node, res, timeout_sec=60)
        answer = res.result() if res.done() else None
        if answer is not None and answer.result.ok:
            out.append(time.perf_counter() - t0)
    client.destroy()
    return _summary(out) if out else {"skipped": "no result came back"}


def _import_times(runs: int = 15) -> tuple[dict[str, float], dict[str, float]]:
    """``import ramps.cli`` in a fresh interpreter, with rclpy importable and
    hidden, the two interleaved so that a busy moment hits both alike."""
    hide = "import sys; sys.modules['rclpy'] = None; "
    plain: list[float] = []
    hidden: list[float] = []
    for _ in range(runs):
        for code, out in (("", plain), (hide, hidden)):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", code + "import ramps.cli"], check=True)
            out.append(time.perf_counter() - t0)
    return _summary(plain), _summary(hidden)


def startup(pythons: list[str], runs: int = 15) -> dict:
    """``python -c pass`` and ``import ramps.cli`` under each interpreter
    (e.g. one venv without the ros extra, one with it), interleaved."""
    res: dict = {py: {"python -c pass": [], "import ramps.cli": []} for py in pythons}
    for _ in range(runs):
        for py in pythons:
            for what, code in (("python -c pass", "pass"), ("import ramps.cli", "import ramps.cli")):
                t0 = time.perf_counter()
                subprocess.run([py, "-c", code], check=True)
                res[py][what].append(time.perf_counter() - t0)
    return {py: {w: _summary(v) for w, v in d.items()} for py, d in res.items()}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=30, help="calls of each program (default 30)")
    ap.add_argument("--out", default="", help="save the figures as JSON here")
    ap.add_argument("--startup", nargs="+", metavar="PYTHON", default=None,
                    help="only compare interpreter start-up of these pythons (venvs with and without the ros extra)")
    a = ap.parse_args(argv)
    if a.startup:
        times = startup(a.startup)
        for py, d in times.items():
            print(f"{py}: " + ", ".join(f"{w} p50 {v['p50_ms']:.0f} ms (min {v['min_ms']:.0f})" for w, v in d.items()))
        saved = {"date": time.strftime("%Y-%m-%d"), "startup": times}
        if a.out:
            Path(a.out).write_text(json.dumps(saved, indent=2) + "\n")
        return saved
    from ramps.testing import LocalTeam

    res: dict = {"date": time.strftime("%Y-%m-%d"), "calls": a.calls, "host_cpus": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="ramps-progbench-") as tmp:
        cmds = []
        for name, text in (("shecho", SHECHO), ("pyecho", PYECHO), ("progress", PROGRESS), ("hang", HANG)):
            p = Path(tmp) / name
            p.write_text(text)
            p.chmod(0o755)
            cmds.append(f"{name}={p}")
        env = dict(os.environ, RAMPS_COMMANDS=",".join(cmds))
        with LocalTeam(3, cores=2, env=env) as lt:
            team = lt.client("r1")
            try:
                _timed(team, "echo", 3)  # warm up
                for program in ("echo", "shecho", "pyecho"):
                    res[program] = _summary(_timed(team, program, a.calls, payload="x" * 100))
                    print(f"{program:>8}: submit -> result p50 {res[program]['p50_ms']:.1f} ms, "
                          f"p95 {res[program]['p95_ms']:.1f} ms ({a.calls} calls)")
                pl = _progress_latency(team, max(3, a.calls // 5))
                res["progress_latency"] = _summary(pl)
                print(f"progress: line on stderr -> fut.progress p50 {res['progress_latency']['p50_ms']:.0f} ms, "
                      f"max {res['progress_latency']['max_ms']:.0f} ms ({len(pl)} programs)")
                wd = _withdrawal(team, tmp, max(3, a.calls // 5))
                res["withdrawal"] = _summary(wd)
                print(f"withdrawn executable: fut.cancel() -> its process group gone p50 "
                      f"{res['withdrawal']['p50_ms']:.0f} ms, max {res['withdrawal']['max_ms']:.0f} ms ({len(wd)} programs)")
            finally:
                team.close()
            ros = _ros_latency(lt, a.calls)
            res["ros_echo"] = ros
            for way in ("topics", "action"):
                r = (ros or {}).get(way, ros)
                if r and "p50_ms" in r:
                    print(f"ROS {way}: goal -> result (echo via ramps ros): p50 {r['p50_ms']:.1f} ms, "
                          f"p95 {r['p95_ms']:.1f} ms")
                else:
                    print(f"ROS {way}: {r}")
    res["import_ramps_cli"], res["import_ramps_cli_ros_hidden"] = _import_times()
    print(f"import ramps.cli: p50 {res['import_ramps_cli']['p50_ms']:.0f} ms with rclpy installed, "
          f"{res['import_ramps_cli_ros_hidden']['p50_ms']:.0f} ms with it hidden")
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=2) + "\n")
        print(f"saved {a.out}")
    return res


if __name__ == "__main__":
    main()
