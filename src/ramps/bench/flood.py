"""``ramps bench flood``: a node flooded with malformed messages keeps working.

How this works: a real team on loopback (two ``ramps node`` processes, r1
and r2) runs legitimate programs submitted to r1 (``burn`` and ``echo``,
spread over the flood) while a separate Zenoh session floods r1's inbox
(``ramps/<team>/msg/r1``) and the team's load keys (periodic reports'
keys, which the nodes that place programs hear, and the reports of the
instant's, which every node hears) with malformed messages: random bytes, truncated and
bit-flipped valid messages, other protocol versions, the wrong shape, fields
out of their limits, pickles, deep nesting, and payloads of 1-9 MB (some
over the 8 MiB message limit). Every message in the pool is checked here to
be one ``decode`` refuses, so each one a node receives adds one to its
``bad_messages`` counter, which nodes publish in their load reports.

Zenoh may drop puts under congestion (the flooder, like robot-to-robot
traffic, does not block), so the figures say what was sent and what each
node counted, not an assumed delivery. Measured on r1 (``psutil`` on its
pid, workers excluded): resident memory after warm-up, at its peak during the
flood, and after it; and its private part (resident minus shared: its own
heap, without the Zenoh shared-memory segments that peers' large messages
map into it). Nothing here asserts; tests/test_flood_e2e.py does.
"""

from __future__ import annotations

import json
import random
import threading
import time
from typing import Any, Callable

from ramps.core import messages as m
from ramps.testing import hostile
from ramps.runtime.watch import TeamWatcher

#: how often the load publisher reports (``NodeSettings.publish_period``)
REPORT_PERIOD = 1.0
MB = 1 << 20


# ====================================================================== the malformed messages
def flood_pool(seed: int = 0, *, small: int = 2000, big: int = 24, big_min: int = 1 * MB,
               big_max: int = 9 * MB) -> tuple[list[bytes], list[bytes]]:
    """(small, big) malformed messages, every one refused by ``decode``.

    Small ones come from the fuzzer's makers (deep nesting kept shallow
    enough to be cheap); big ones are 1-9 MB: garbage, zeros, a valid offload
    whose arguments take it over the limit, and a valid-looking one of a few
    MB with one bad field (parsed to the end, then refused)."""
    rng = random.Random(seed)
    makers = [k for k in hostile.WIRE_KINDS if k[0] not in ("valid",)]
    _names, weights, fns = zip(*makers)
    out_small: list[bytes] = []
    while len(out_small) < small:
        data = rng.choices(fns, weights)[0](rng)
        if len(data) > 64 * 1024:  # deep nesting of a million levels: keep the small pool small
            continue
        if _refused(data):
            out_small.append(data)
    out_big: list[bytes] = []
    for i in range(big):
        n = rng.randint(big_min, big_max)
        k = i % 4
        if k == 0:
            data = rng.randbytes(n)
        elif k == 1:
            data = b"\xc1" * n
        elif k == 2:
            data = m.encode("p", m.OffloadRequest(program_id="a", attempt=1, origin="p", host="r1", program="burn",
                                                  args=b"\x00" * max(n, m.MAX_MESSAGE_BYTES + 1)))
        else:
            data = hostile.ENCODER.encode({"v": m.PROTOCOL_VERSION, "sender": "p", "msg": {
                "type": "offload", "program_id": "a", "attempt": 1, "origin": "p", "host": "**",
                "program": "burn", "args": b"\x00" * n}})
        if _refused(data):
            out_big.append(data)
    return out_small, out_big


def _refused(data: bytes) -> bool:
    try:
        m.decode(data)
    except m.WireError:
        return True
    return False


# ====================================================================== watching the nodes
def raw_session(endpoints: list[str], *, shared_memory: bool = False):
    """A plain Zenoh peer session connected to ``endpoints`` (no listening,
    no multicast): what a misbehaving program on the network would open.

    Zenoh passes messages over 3 KB between processes of one host through
    a 16 MiB shared-memory pool that the receiver maps (and counts in its
    resident memory); an attacker on another machine has no such pool, so
    the flood goes over TCP unless ``shared_memory``."""
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("connect/endpoints", json.dumps(endpoints))
    c.insert_json5("scouting/multicast/enabled", "false")
    if not shared_memory:
        c.insert_json5("transport/shared_memory/enabled", "false")
    return zenoh.open(c)


def wait_settled(watcher: TeamWatcher, robots: list[str], timeout: float = 15.0) -> dict[str, int | None]:
    """Each robot's count of dropped messages, once two successive reports of every robot agree."""
    deadline = time.monotonic() + timeout
    last = {r: watcher.bad_messages(r) for r in robots}
    while time.monotonic() < deadline:
        time.sleep(2 * REPORT_PERIOD + 0.2)
        now = {r: watcher.bad_messages(r) for r in robots}
        if now == last and None not in now.values():
            return now
        last = now
    return last


class RssSampler:
    """Resident memory of one process, sampled every ``period`` seconds."""

    def __init__(self, pid: int, period: float = 0.05) -> None:
        import psutil

        self.proc = psutil.Process(pid)
        self.period = period
        self.peak = self.rss()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rss-sampler", daemon=True)

    def rss(self) -> int:
        return self.proc.memory_info().rss

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            try:
                self.peak = max(self.peak, self.rss())
            except Exception:
                return

    def __enter__(self) -> "RssSampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(2)


# ====================================================================== the flood
def _legit_calls(n: int) -> list[tuple[str, dict]]:
    calls: list[tuple[str, dict]] = []
    for i in range(n):
        if i % 2 == 0:
            calls.append(("burn", {"seconds": 0.2}))
        else:
            calls.append(("echo", {"i": i, "text": "x" * (i % 7), "nested": {"a": [i, -i]}}))
    return calls


def _check(program: str, args: dict, value: Any) -> bool:
    from ramps.runtime.spin import ITERATIONS_PER_UNIT

    if program == "echo":
        return value == args
    return isinstance(value, dict) and value.get("iterations") == round(args["seconds"] * ITERATIONS_PER_UNIT)


def flood_team(*, team: str, endpoints: list[str], target: str, pids: dict[str, int], client,
               messages: int = 10_000, seconds: float = 10.0, programs: int = 40, big_share: float = 0.01,
               load_share: float = 0.25, seed: int = 0, result_timeout: float = 120.0, block: bool = False,
               log: Callable[[str], None] | None = None) -> dict:
    """Flood a running team's ``target`` node while ``client`` (a Team whose
    origin is ``target``) runs ``programs`` legitimate programs; return the figures.

    ``pids``: robot -> node pid, for resident memory. ``load_share`` of the
    flood goes to the load keys (half to periodic reports', which the target
    hears, half to those of the instant, which every node hears), the rest to
    the target's inbox; ``big_share`` of it is 1-9 MB. ``block``: the
    flooder waits when Zenoh's queues are full instead of dropping (so every
    message reaches the nodes, at whatever rate they take them)."""
    say = log or (lambda _msg: None)
    small, big = flood_pool(seed)
    rng = random.Random(seed)
    robots = sorted(pids)
    calls = _legit_calls(programs)
    with raw_session(endpoints) as session:
        watcher = TeamWatcher(session, team)
        try:
            inbox = f"ramps/{team}/msg/{target}"
            _warm_up(client, calls, session, watcher, inbox, target, result_timeout)
            before = wait_settled(watcher, robots)
            time.sleep(1.0)
            rss_before, private_before = _memory(pids)
            say(f"flooding {target}: {messages} messages in {seconds:g} s while {programs} programs run ...")
            futures: list = []
            sent = {"inbox": 0, "load": 0, "now": 0, "big": 0, "bytes": 0, "errors": 0}
            gap = seconds / max(1, programs)

            def submit_all() -> None:
                start = time.monotonic()
                for i, (p, a) in enumerate(calls):
                    time.sleep(max(0.0, start + i * gap - time.monotonic()))
                    futures.append((p, a, client.submit(p, **a)))

            submitter = threading.Thread(target=submit_all, name="flood-legit", daemon=True)
            with RssSampler(pids[target]) as sampler:
                started = time.monotonic()
                submitter.start()
                flood_seconds = _send_flood(session, team, target, inbox, sent, small, big, rng, started=started,
                                            messages=messages, seconds=seconds, big_share=big_share,
                                            load_share=load_share, block=block)
                submitter.join()
                ok, wrong, failed, failures = _outcomes(futures, result_timeout)
                programs_seconds = time.monotonic() - started
            hosts: dict[str, int] = {}
            for _p, _a, f in futures:
                h = getattr(f, "host", "?")
                hosts[h] = hosts.get(h, 0) + 1
            after = wait_settled(watcher, robots)
            time.sleep(1.0)
            rss_after, private_after = _memory(pids)
            counted = {r: (after[r] or 0) - (before[r] or 0) for r in robots}
        finally:
            watcher.close()
    return {
        "benchmark": "flood", "target": target, "blocking_sender": block, "robots": robots,
        "messages_sent": sent["inbox"] + sent["load"] + sent["now"],
        "to_inbox": sent["inbox"], "to_load_key": sent["load"] + sent["now"], "big_messages": sent["big"],
        "bytes_sent": sent["bytes"], "send_errors": sent["errors"], "flood_seconds": flood_seconds,
        "send_rate_per_s": (sent["inbox"] + sent["load"] + sent["now"]) / flood_seconds if flood_seconds else 0.0,
        # periodic reports' keys reach the nodes that place programs (the target: its client submits
        # there), reports of the instant every node
        "expected_at_target": sent["inbox"] + sent["load"] + sent["now"], "expected_at_others": sent["now"],
        "dropped_counted": counted, "bad_messages_total": after,
        "programs": len(calls), "programs_ok": ok, "programs_wrong": wrong, "programs_failed": failed,
        "program_hosts": hosts, "programs_seconds": programs_seconds, "failures": failures[:10],
        "rss_before_mb": {r: v / MB for r, v in rss_before.items()},
        "rss_after_mb": {r: v / MB for r, v in rss_after.items()},
        "rss_growth_mb": {r: (rss_after[r] - rss_before[r]) / MB for r in robots},
        "private_before_mb": {r: v / MB for r, v in private_before.items()},
        "private_after_mb": {r: v / MB for r, v in private_after.items()},
        "private_growth_mb": {r: (private_after[r] - private_before[r]) / MB for r in robots},
        "rss_peak_mb": sampler.peak / MB,
        "alive": {r: _alive(pid) for r, pid in pids.items()},
    }


def _warm_up(client: Any, calls: list[tuple[str, dict]], session: Any, watcher: TeamWatcher, inbox: str,
             target: str, result_timeout: float) -> None:
    """Run a few of the programs (their code paths, the workers, the Zenoh routes), then probe
    ``target``'s inbox until it counts a bad message: a put made before Zenoh matched the
    subscriber may vanish."""
    warm = [client.submit(p, **a) for p, a in calls[:min(len(calls), 10)]]
    for f in warm:
        f.result(timeout=result_timeout)
    deadline = time.monotonic() + 30
    while (watcher.bad_messages(target) or 0) < 1:
        if time.monotonic() > deadline:
            raise RuntimeError(f"{target} never counted a probe message (no load reports heard?)")
        session.put(inbox, b"\xc1probe")
        time.sleep(0.3)


def _send_flood(session: Any, team: str, target: str, inbox: str, sent: dict[str, int], small: list[bytes],
                big: list[bytes], rng: random.Random, *, started: float, messages: int, seconds: float,
                big_share: float, load_share: float, block: bool) -> float:
    """Send the flood, paced over ``seconds`` from ``started``, counting what went where in
    ``sent``; return the seconds it took."""
    import zenoh

    cc = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
    pub_inbox = session.declare_publisher(inbox, congestion_control=cc)
    for i in range(messages):
        if rng.random() < big_share:
            data = big[sent["big"] % len(big)]
            sent["big"] += 1
        else:
            data = small[i % len(small)]
        try:
            if rng.random() < load_share:  # a periodic report's key or one of the instant's
                kind = rng.choice(("load", "now"))
                key = f"ramps/{team}/load/{rng.choice([target, 'r9', 'x'])}"
                session.put(key + "/now" if kind == "now" else key, data, congestion_control=cc)
                sent[kind] += 1
            else:
                pub_inbox.put(data)
                sent["inbox"] += 1
            sent["bytes"] += len(data)
        except Exception:
            sent["errors"] += 1
        if i % 50 == 49:  # pace: the whole flood over `seconds`
            time.sleep(max(0.0, started + (i + 1) * seconds / messages - time.monotonic()))
    flood_seconds = time.monotonic() - started
    pub_inbox.undeclare()
    return flood_seconds


def _outcomes(futures: list, result_timeout: float) -> tuple[int, int, int, list[str]]:
    """The legitimate programs' outcomes: (right, wrong, failed, what went wrong)."""
    ok = wrong = failed = 0
    failures: list[str] = []
    for p, a, f in futures:
        try:
            value = f.result(timeout=result_timeout)
        except Exception as exc:
            failed += 1
            failures.append(f"{p}: {type(exc).__name__}: {exc}"[:300])
            continue
        if _check(p, a, value):
            ok += 1
        else:
            wrong += 1
            failures.append(f"{p}({a}) returned {value!r}"[:300])
    return ok, wrong, failed, failures


def _memory(pids: dict[str, int]) -> tuple[dict[str, int], dict[str, int]]:
    """Each node's resident and private memory now, bytes."""
    return {r: _rss(pid) for r, pid in pids.items()}, {r: _private(pid) for r, pid in pids.items()}


def _rss(pid: int) -> int:
    import psutil

    return psutil.Process(pid).memory_info().rss


def _private(pid: int) -> int:
    """Resident memory of the process's own (anonymous) pages: its heap and
    the backlog in it, not the files it maps nor the Zenoh shared-memory
    segments of the peers that sent it messages (``RssShmem``: 16-19 MiB per
    segment, mapped when a peer's first large message arrives, flood or no
    flood; the flooder itself has shared memory off)."""
    import psutil

    mi = psutil.Process(pid).memory_info()
    return mi.rss - getattr(mi, "shared", 0)


def _alive(pid: int) -> bool:
    import psutil

    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def bench_flood(*, messages: int = 10_000, seconds: float = 10.0, programs: int = 40, seed: int = 0,
                log: Callable[[str], None] | None = None) -> dict:
    """``ramps bench flood``: two real nodes on loopback, r1 flooded."""
    from ramps.bench.simulator import machine
    from ramps.testing import LocalTeam

    with LocalTeam(2, cores=2, speed=1.0, keep_logs=True) as team:
        client = team.client("r1")
        try:
            res = flood_team(team=team.team, endpoints=[team.endpoint(n) for n in team.names], target="r1",
                             pids={n: team.procs[n].pid for n in team.names}, client=client,
                             messages=messages, seconds=seconds, programs=programs, seed=seed, log=log)
        finally:
            client.close()
        res["node_logs"] = str(team.log_dir)
    res["machine"] = machine()
    return res


__all__ = ["RssSampler", "bench_flood", "flood_pool", "flood_team", "raw_session", "wait_settled"]
