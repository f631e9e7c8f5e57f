"""Prometheus metrics of real nodes (``ramps node --metrics``), scraped over HTTP.

A three-robot team (tests/runtime_team.py), every node serving metrics on a
free loopback port. r1 is the origin: its counters must move as programs
complete, its latency histograms must gain observations (dispatch, and
failure detection / recovery once r3 is killed under a program), and every
scrape must parse as Prometheus exposition format.
"""

from __future__ import annotations

import json
import time
import urllib.request
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families
from runtime_team import LocalTeam

from ramps.runtime.localteam import free_port
from ramps.runtime.settings import parse_metrics_address

RESULT_TIMEOUT = 60.0


def scrape(port: int) -> dict[str, list]:
    """name -> samples, from a real HTTP GET of /metrics (parsing fails on bad text)."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as resp:
        assert resp.status == 200
        assert resp.headers["Content-Type"].startswith("text/plain")
        text = resp.read().decode()
    out: dict[str, list] = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out.setdefault(s.name, []).append(s)
    return out


def total(samples: dict[str, list], name: str, **labels) -> float:
    return sum(s.value for s in samples.get(name, []) if all(s.labels.get(k) == v for k, v in labels.items()))


def check_report_of_node_trace(trace: Path, tmp: Path) -> None:
    """The timeline of a real origin's trace: r3's attempts end where r1 wrote them off (the trace's
    "failed" lines), each is placed again on a live robot after that and delivered from there."""
    from ramps.observe.report import make_report, write_html
    from ramps.observe.timeline import build_timeline, load_run

    lines = [json.loads(x) for x in trace.read_text().splitlines()]
    t0 = min(x["wall"] for x in lines)
    failed = {(x["program_id"], x["attempt"]): x["wall"] - t0 for x in lines if x["what"] == "failed"
              and x["other"] == "r3"}
    delivered = {x["program_id"]: (x["wall"] - t0, x["other"]) for x in lines if x["what"] == "delivered"}
    assert failed, "r1's trace has no attempt on r3 written off"
    tl = build_timeline(*load_run([trace]))
    on_r3 = {(a.program_id, a.attempt): a for a in tl.attempts if a.host == "r3" and a.outcome == "failed"}
    assert set(on_r3) == set(failed)
    for key, a in on_r3.items():
        assert a.end == pytest.approx(failed[key], abs=1e-6) and a.detail in ("host_lost", "heartbeat_timeout")
    moved = {prev.program_id: nxt for prev, nxt in tl.replacements() if (prev.program_id, prev.attempt) in failed}
    assert set(moved) == {pid for pid, _ in failed}
    for pid, nxt in moved.items():
        assert nxt.host in ("r1", "r2") and nxt.start >= failed[(pid, nxt.attempt - 1)]
        assert nxt.outcome == "delivered" and (nxt.end, nxt.host) == pytest.approx(delivered[pid])
    assert sum(tl.distribution.values()) == len(delivered) - 1  # the program that raised is not in it
    page = write_html(make_report([trace]), tmp / "r1.html").read_text()
    assert page.count("data:image/png;base64,") == 3
    assert "host_lost" in page or "heartbeat_timeout" in page


def test_grafana_dashboard_queries_only_metrics_a_node_serves():
    """docs/grafana/ramps-team.json: valid JSON, every panel has a query, and every ramps_* series
    it names is one NodeMetrics exposes (a renamed metric would leave a panel empty)."""
    import json
    import re
    from pathlib import Path

    from ramps.runtime.metrics import NodeMetrics

    dash = json.loads((Path(__file__).resolve().parent.parent / "docs" / "grafana" / "ramps-team.json").read_text())
    served = set()
    suffixes = {"counter": ("_total",), "histogram": ("_bucket", "_count", "_sum"), "gauge": ("",), "info": ("_info",)}
    for fam in NodeMetrics("r1", "t").registry.collect():  # labelled series have no samples yet: by type
        served |= {fam.name + suffix for suffix in suffixes[fam.type]}
    names = set()
    for panel in dash["panels"]:
        assert panel["targets"], panel["title"]
        for t in panel["targets"]:
            names |= set(re.findall(r"\bramps_[a-z0-9_]+", t["expr"]))
    names |= set(re.findall(r"\bramps_[a-z0-9_]+", json.dumps(dash["templating"])))
    assert names and names <= served, sorted(names - served)
    # every kind of metric the issue asks for is on the dashboard
    for wanted in ("ramps_programs_placed_total", "ramps_programs_run_total", "ramps_programs_delivered_total",
                   "ramps_program_attempts_failed_total", "ramps_programs_replaced_total",
                   "ramps_failure_detection_seconds_bucket", "ramps_dispatch_seconds_bucket", "ramps_cpu_busy_cores",
                   "ramps_run_queue", "ramps_messages_dropped_total", "ramps_teammates_seen"):
        assert wanted in names, wanted


def test_parse_metrics_address_defaults_and_errors():
    assert parse_metrics_address("9464") == ("127.0.0.1", 9464)
    assert parse_metrics_address(":9464") == ("127.0.0.1", 9464)
    assert parse_metrics_address("0.0.0.0:9100") == ("0.0.0.0", 9100)
    assert parse_metrics_address("[::1]:9100") == ("::1", 9100)
    for bad in ("localhost:http", "1.2.3.4:70000", ""):
        with pytest.raises(ValueError, match="metrics"):
            parse_metrics_address(bad)


def test_the_render_benchmark_renders_a_busy_nodes_series():
    """``ramps bench metrics`` times renders of ``busy_metrics()``: every host, program and outcome it
    fed is in the exposition, and the size it reports is that exposition's (the creation times in it
    vary in digits)."""
    from prometheus_client import generate_latest

    from ramps.bench.metrics_cost import busy_metrics, render_cost

    text = generate_latest(busy_metrics().registry)
    samples = [s for fam in text_string_to_metric_families(text.decode()) for s in fam.samples]

    def labels(metric: str, label: str) -> set[str]:
        return {s.labels[label] for s in samples if s.name == metric}

    assert labels("ramps_programs_placed_total", "host") == {f"r{i}" for i in range(1, 6)}
    assert labels("ramps_programs_run_total", "program") == {"prog0", "prog1", "prog2"}
    assert labels("ramps_programs_delivered_total", "outcome") == {"ok", "program"}
    assert labels("ramps_program_attempts_failed_total", "reason") >= {"host_lost"}
    assert render_cost(renders=2)["bytes"] == pytest.approx(len(text), rel=0.01)


@pytest.mark.slow
def test_metrics_scraped_while_programs_run(tmp_path):
    ports = {f"r{i}": free_port() for i in (1, 2, 3)}
    t = LocalTeam(3, tmp_path)
    try:
        for name, port in ports.items():
            t.start_node(name, wait=False, extra_args=["--metrics", f"127.0.0.1:{port}"]
                         + (["--trace", str(tmp_path / "r1.trace.jsonl")] if name == "r1" else []))
        t.wait_visible(list(ports))
        before = scrape(ports["r1"])
        assert total(before, "ramps_programs_delivered_total", robot="r1") == 0
        assert total(before, "ramps_cores", robot="r1") == 2
        team = t.client("r1")
        futs = [team.submit("spin", seconds=0.2) for _ in range(6)]
        bad = team.submit("fail")
        deadline = time.monotonic() + 30
        while total(scrape(ports["r1"]), "ramps_programs_placed_total", robot="r1") < 1:  # parses while they run
            assert time.monotonic() < deadline, "no placement counted"
            time.sleep(0.05)
        for f in futs:
            f.result(RESULT_TIMEOUT)
        with pytest.raises(Exception):
            bad.result(RESULT_TIMEOUT)
        after = scrape(ports["r1"])
        assert total(after, "ramps_programs_delivered_total", robot="r1", program="spin", outcome="ok") == 6
        assert total(after, "ramps_programs_delivered_total", robot="r1", program="fail", outcome="program") == 1
        assert total(after, "ramps_programs_placed_total", robot="r1") >= 7
        assert total(after, "ramps_dispatch_seconds_count", robot="r1") >= 7
        assert total(after, "ramps_program_duration_seconds_count", robot="r1", program="spin") == 6
        # the hosts' executors counted what they ran, by origin
        ran = sum(total(scrape(p), "ramps_programs_run_total", origin="r1") for p in ports.values())
        assert ran >= 7
        assert sum(total(scrape(p), "ramps_programs_finished_total", program="spin", outcome="ok")
                   for p in ports.values()) >= 6

        # a host crashes under a program: failure detected, program re-placed and delivered
        r3_before = total(after, "ramps_programs_placed_total", robot="r1", host="r3")
        rr = team.options(policy="round_robin")  # so that some surely land on r3
        slow = [rr.submit("sleepy", seconds=4.0, tag=f"m{i}") for i in range(6)]
        marks = t.marks
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if any((marks / f"m{i}").exists() and (marks / f"m{i}").read_text().startswith("r3")
                   for i in range(6)):
                break
            time.sleep(0.1)
        else:
            pytest.fail("no program reached r3\n" + t.logs())
        t.kill_node("r3")
        for f in slow:
            f.result(RESULT_TIMEOUT)
        # the gauges come with the next load report (once a second)
        deadline = time.monotonic() + 10
        while True:
            end = scrape(ports["r1"])
            if total(end, "ramps_teammates_seen", robot="r1") == 1 or time.monotonic() > deadline:
                break
            time.sleep(0.3)
        assert total(end, "ramps_programs_placed_total", robot="r1", host="r3") > r3_before
        assert total(end, "ramps_program_attempts_failed_total", robot="r1", host="r3") >= 1
        assert total(end, "ramps_failure_detection_seconds_count", robot="r1") >= 1
        assert total(end, "ramps_recovery_seconds_count", robot="r1") >= 1
        assert total(end, "ramps_programs_replaced_total", robot="r1", program="sleepy") >= 1
        assert total(end, "ramps_blacklistings_total", robot="r1", host="r3") >= 1
        assert total(end, "ramps_programs_delivered_total", robot="r1", program="sleepy", outcome="ok") == 6
        assert total(end, "ramps_teammates_seen", robot="r1") == 1
        assert total(end, "ramps_memory_free_bytes", robot="r1") > 0
        info = end["ramps_node_info"][0].labels
        assert info["team"] == t.team and info["robot"] == "r1"

        # and `ramps report` of r1's trace shows the crash as the origin saw it
        check_report_of_node_trace(tmp_path / "r1.trace.jsonl", tmp_path)
    finally:
        t.close()


@pytest.mark.slow
def test_metrics_port_taken_is_a_clear_error(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        t = LocalTeam(1, tmp_path)
        try:
            r = t.cli("node", "--robot", "rx", "--team", t.team, "--no-multicast", "--listen",
                      f"tcp/127.0.0.1:{free_port()}", "--speed", "1", "--metrics", f"127.0.0.1:{port}", timeout=60)
        finally:
            t.close()
    assert r.returncode == 2, r.stderr
    assert "cannot serve metrics" in r.stderr and str(port) in r.stderr
