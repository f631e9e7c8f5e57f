"""Inside a robot of the peers experiment: Ray's or Dask's node, a driver, and their program.

How this works: ``ramps.lab.peers_engines.PeerBed`` starts ``python -m
ramps.lab.peers_robot node ENGINE ...`` as each robot's node (``_node``:
a Ray head or node, or a Dask scheduler and workers, in the robot's
namespace and cgroup, at nice 0 as ``ramps node``), and ``... drive ...``
inside each origin (``_drive``: connect, wait for every worker, say
``ready``, wait for ``go``, submit the origin's programs ``SPACING`` s
apart, write what each did). Their program is ``peer_burn``:
``ramps.programs.burn`` at the niceness of ramps' workers, marking on the
host's disk where it runs, when it starts and ends.

Rules: files in the run's work folder are the only channel to the host;
results are written whole (a temporary file, then renamed).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from ramps.lab.peers_scenarios import SPACING, WORKER_NICE

RAY_PORT, DASK_PORT = 6379, 8786


def peer_burn(units: float, origin: str, index: int, marks: str, nice: int = WORKER_NICE) -> dict[str, Any]:
    """``burn`` as Ray's and Dask's program: at niceness ``nice`` (as ramps' workers run theirs; the
    worker process stays there, it only ever runs these), marking where it runs (start and end)
    on the host's disk."""
    from ramps.programs.burn import burn

    if os.getpriority(os.PRIO_PROCESS, 0) < nice:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    robot = os.environ.get("RAMPS_ROBOT", socket.gethostname())
    key = f"{origin}_{index}_{robot}_{os.getpid()}"
    Path(marks, f"start-{key}").touch()
    out = burn(units=units)
    Path(marks, f"end-{key}").touch()
    return {"robot": robot, "checksum": out["checksum"]}


def _node(engine: str, robot: str, ip: str, head: str, cores: int, work_dir: str) -> int:
    """A robot's node of ``engine``, at nice 0 as ``ramps node`` (its programs set their own
    niceness: ``peer_burn``); this process waits on it (the testbed's node pid)."""
    os.makedirs(work_dir, exist_ok=True)
    exe = Path(sys.executable).parent
    cmds: list[list[str]] = []
    if engine == "ray":
        common = ["--block", "--node-ip-address", ip, "--num-cpus", str(cores), "--num-gpus", "0",
                  "--object-store-memory", str(100 * 2**20), "--disable-usage-stats",
                  "--temp-dir", f"{work_dir}/ray"]  # a robot's own: sockets named alike in one session dir
        if ip == head:
            cmds.append([str(exe / "ray"), "start", "--head", "--port", str(RAY_PORT), "--include-dashboard",
                                "false", *common])
        else:
            _wait_port(head, RAY_PORT)
            cmds.append([str(exe / "ray"), "start", "--address", f"{head}:{RAY_PORT}", *common])
    elif engine == "dask":
        if ip == head:
            cmds.append([str(exe / "dask"), "scheduler", "--host", ip, "--port", str(DASK_PORT), "--no-dashboard"])
        cmds.append([str(exe / "dask"), "worker", f"tcp://{head}:{DASK_PORT}", "--host", ip, "--nthreads", "1",
                            "--nworkers", str(cores), "--no-dashboard", "--name", robot,
                            "--local-directory", work_dir])
    else:
        raise SystemExit(f"unknown engine {engine!r}")
    procs = [subprocess.Popen(c) for c in cmds]
    while all(p.poll() is None for p in procs):
        time.sleep(0.5)
    for p in procs:
        if p.poll() is None:
            p.kill()
    return 1


def _wait_port(host: str, port: int, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection((host, port), timeout=1.0).close()
            return
        except OSError:
            time.sleep(0.3)


def _drive(engine: str, origin: str, head: str, count: int, work: float, workers: int, work_dir: str,
           nice: int) -> None:
    """One origin's programs through ``engine``: connect, wait for every worker, write ``ready-<origin>``,
    wait for ``go`` (the first submission's monotonic time), submit ``count`` programs ``SPACING``
    apart, and write ``result-<origin>.json``: per program ok, robot and end time (and
    ``result-<origin>.partial`` after each completion, for a burst whose time runs out)."""
    d = Path(work_dir)
    marks = str(d / "marks")
    programs: list[dict[str, Any]] = []
    error = None

    def save(suffix: str) -> None:
        tmp = d / f"result-{origin}.tmp"
        tmp.write_text(json.dumps({"programs": programs, "error": error}))
        tmp.replace(d / f"result-{origin}.{suffix}")

    try:
        if engine == "ray":
            import ray

            ray.init(address=f"{head}:{RAY_PORT}", log_to_driver=False)
            while ray.cluster_resources().get("CPU", 0) < workers:
                time.sleep(0.5)
            task = ray.remote(num_cpus=1)(peer_burn)
        else:
            from distributed import Client, as_completed

            client = Client(f"tcp://{head}:{DASK_PORT}", timeout=120)
            client.wait_for_workers(workers, timeout=240)
        (d / f"ready-{origin}").touch()
        while not (d / "go").exists():
            time.sleep(0.01)
        t0 = float((d / "go").read_text())
        time.sleep(max(0.0, t0 - time.monotonic()))
        refs: list[Any] = []
        for i in range(count):
            if engine == "ray":
                refs.append(task.remote(work, origin, i, marks, nice))
            else:
                refs.append(client.submit(peer_burn, work, origin, i, marks, nice, pure=False,
                                          key=f"burn-{origin}-{i}"))
            time.sleep(max(0.0, t0 + (i + 1) * SPACING - time.monotonic()))
        programs = [{"ok": False, "pending": True} for _ in refs]
        if engine == "ray":
            index = {r: i for i, r in enumerate(refs)}
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for r in done:
                    i, end = index[r], time.monotonic()
                    try:
                        programs[i] = {"ok": True, "robot": ray.get(r)["robot"], "end": end}
                    except Exception as exc:
                        programs[i] = {"ok": False, "error": f"{type(exc).__name__}: {exc}"[:300]}
                    save("partial")
        else:
            index = {f.key: i for i, f in enumerate(refs)}
            for f in as_completed(refs):
                i, end = index[f.key], time.monotonic()
                try:
                    programs[i] = {"ok": True, "robot": f.result()["robot"], "end": end}
                except Exception as exc:
                    programs[i] = {"ok": False, "error": f"{type(exc).__name__}: {exc}"[:300]}
                save("partial")
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"[:1000]
    save("json")


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["node"] and len(args) == 7:
        raise SystemExit(_node(args[1], args[2], args[3], args[4], int(args[5]), args[6]))
    if args[:1] == ["drive"] and len(args) == 9:
        _drive(args[1], args[2], args[3], int(args[4]), float(args[5]), int(args[6]), args[7], int(args[8]))
        os._exit(0)  # a client's threads must not hold the robot's process up
    print("usage: python -m ramps.lab.peers_robot node|drive ...  (started by ramps testbed experiment peers)",
          file=sys.stderr)
    raise SystemExit(2)


if __name__ == "__main__":
    main()
