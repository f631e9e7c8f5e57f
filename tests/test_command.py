"""Executables as programs, without a team: ``CommandProgram`` run directly, and their registration.

Each test writes a small shell or Python script into its temporary
directory and runs it the way a worker does (``CommandProgram.run``), so
the contract of ``ramps.runtime.command`` is checked in well under a second
a test: JSON in on stdin, JSON out on stdout, exit code and stderr tail on
failure, progress lines, the time limit, and the process group killed.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import psutil
import pytest

from ramps.errors import BadArguments, ConfigError
from ramps.runtime.command import (STDERR_TAIL, CommandFailed, CommandProgram, NotACheckpoint, parse_checkpoint,
                                   parse_progress)
from ramps.runtime.registry import Registry, encode_args, resolve
from ramps.runtime.settings import load_settings

pytestmark = pytest.mark.slow  # each test starts a process or two (sub-second)


def script(tmp_path: Path, text: str, name: str = "prog") -> str:
    p = tmp_path / name
    p.write_text(text)
    p.chmod(0o755)
    return str(p)


def run(path: str, args: dict | None = None, *, timeout: float = 30.0, progress=None):
    return CommandProgram(path, timeout=timeout, name="prog").run(
        args or {}, on_progress=progress or (lambda f, d: None))


def test_arguments_come_on_stdin_and_the_result_from_stdout(tmp_path):
    p = script(tmp_path, f"#!{sys.executable}\nimport json, sys\na = json.load(sys.stdin)\n"
                         "print('a log line', file=sys.stderr)\njson.dump({'sum': sum(a['xs']), 'n': a['n']}, sys.stdout)\n")
    assert run(p, {"xs": [1, 2, 3], "n": "x"}) == {"sum": 6, "n": "x"}


def test_empty_stdout_is_null_and_a_program_need_not_read_its_input(tmp_path):
    assert run(script(tmp_path, "#!/bin/sh\nexit 0\n"), {"big": "x" * 300_000}) is None


def test_failure_carries_exit_code_and_the_tail_of_stderr(tmp_path):
    p = script(tmp_path, "#!/bin/sh\ni=0\nwhile [ $i -lt 500 ]; do echo \"line $i of noise\" >&2; i=$((i+1)); done\n"
                         "echo 'fatal: map not found' >&2\nexit 7\n")
    with pytest.raises(CommandFailed) as err:
        run(p)
    text = str(err.value)
    assert text.startswith("prog exited with code 7")
    assert text.endswith("fatal: map not found\n")
    assert len(text) < STDERR_TAIL + 200 and "line 0 of noise" not in text


def test_death_by_signal_is_named(tmp_path):
    with pytest.raises(CommandFailed, match="killed by signal SIGSEGV"):
        run(script(tmp_path, "#!/bin/sh\nkill -SEGV $$\n"))


def test_stdout_that_is_not_json_is_a_clear_error(tmp_path):
    with pytest.raises(CommandFailed, match="stdout is not JSON.*'hello"):
        run(script(tmp_path, "#!/bin/sh\necho hello world\n"))


def test_progress_lines_are_reported_and_kept_out_of_the_stderr_tail(tmp_path):
    p = script(tmp_path, "#!/bin/sh\necho 'RAMPS_PROGRESS 0.25 loading' >&2\necho 'RAMPS_PROGRESS 2 bad' >&2\n"
                         "echo 'RAMPS_PROGRESS 1.0' >&2\necho boom >&2\nexit 1\n")
    seen = []
    with pytest.raises(CommandFailed) as err:
        run(p, progress=lambda f, d: seen.append((f, d)))
    assert seen == [(0.25, "loading"), (1.0, "")]
    assert "RAMPS_PROGRESS" not in str(err.value.args[0]).split("stderr", 1)[1].replace("RAMPS_PROGRESS 2 bad", "")
    assert "boom" in str(err.value)


def test_parse_progress() -> None:
    assert parse_progress(b"RAMPS_PROGRESS 0.5 half way") == (0.5, "half way")
    for bad in (b"RAMPS_PROGRESS", b"RAMPS_PROGRESS x", b"RAMPS_PROGRESS -0.1", b"RAMPS_PROGRESS nan", b"progress 0.5"):
        assert parse_progress(bad) is None, bad


CHECKPOINTING = f"""#!{sys.executable}
import json, os, sys
args = json.load(sys.stdin)
path = os.environ.get("RAMPS_RESUME")
start = json.load(open(path))["i"] if path else 0
for i in range(start, args["n"]):
    print(f"RAMPS_CHECKPOINT {{json.dumps({{'i': i + 1, 'note': 'x'}})}}", file=sys.stderr, flush=True)
print("a log line", file=sys.stderr)
json.dump({{"start": start, "resume_file": path}}, sys.stdout)
"""


def test_checkpoint_lines_are_saved_and_a_resumed_run_reads_its_state_from_ramps_resume(tmp_path):
    p = script(tmp_path, CHECKPOINTING)
    saved: list = []
    fresh = CommandProgram(p, name="prog").run({"n": 3}, on_progress=lambda f, d: None, on_checkpoint=saved.append)
    assert fresh == {"start": 0, "resume_file": None}  # no RAMPS_RESUME on a fresh start
    assert saved == [{"i": 1, "note": "x"}, {"i": 2, "note": "x"}, {"i": 3, "note": "x"}]
    again = CommandProgram(p, name="prog").run({"n": 5}, on_progress=lambda f, d: None, on_checkpoint=saved.append,
                                                resume={"i": 3})
    assert again["start"] == 3 and saved[-1] == {"i": 5, "note": "x"}
    assert not Path(again["resume_file"]).exists()  # removed once the program ended


@pytest.mark.parametrize("line, why", [("RAMPS_CHECKPOINT {not json", "not one JSON value"),
                                       ("RAMPS_CHECKPOINT \"" + "x" * 300_000 + "\"", "exceeds the limit")])
def test_a_checkpoint_ramps_cannot_keep_stops_the_program_with_a_clear_error(tmp_path, line, why):
    from ramps.runtime.running import save_checkpoint  # what a worker saves with: it checks the size

    p = script(tmp_path, f"#!{sys.executable}\nimport sys, time\nprint({line!r}, file=sys.stderr, flush=True)\n"
                         "time.sleep(30)\n")
    t0 = time.monotonic()
    with pytest.raises(CommandFailed, match=f"prog wrote a checkpoint ramps cannot keep \\(.*{why}.*\\) and was stopped"):
        CommandProgram(p, name="prog").run({}, on_progress=lambda f, d: None, on_checkpoint=save_checkpoint)
    assert time.monotonic() - t0 < 25  # stopped, not left to its sleep


def test_parse_checkpoint() -> None:
    assert parse_checkpoint(b'RAMPS_CHECKPOINT {"i": 2}') == {"i": 2}
    assert parse_checkpoint(b"RAMPS_CHECKPOINT null") is None
    assert parse_checkpoint(b"RAMPS_PROGRESS 0.5") is NotACheckpoint
    assert parse_checkpoint(b"RAMPS_CHECKPOINTS 1") is NotACheckpoint
    with pytest.raises(ValueError, match="not one JSON value"):
        parse_checkpoint(b"RAMPS_CHECKPOINT {")


def test_time_limit_kills_the_whole_process_group(tmp_path):
    marks = tmp_path / "pids"
    p = script(tmp_path, f"#!/bin/sh\nsleep 300 &\necho $$ $! > {marks}\nwait\n")
    t0 = time.monotonic()
    with pytest.raises(CommandFailed, match="time limit of 0.5 s"):
        run(p, timeout=0.5)
    assert time.monotonic() - t0 < 20
    for pid in map(int, marks.read_text().split()):
        try:  # gone, or a zombie; it may exit between two looks at it
            assert psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
        except psutil.NoSuchProcess:
            pass


def test_strays_left_behind_by_a_finished_program_are_killed(tmp_path):
    marks = tmp_path / "pid"
    p = script(tmp_path, f"#!/bin/sh\n(sleep 300 >/dev/null 2>&1 &\necho $! > {marks})\necho 42\n")
    assert run(p) == 42
    pid = int(marks.read_text())
    deadline = time.monotonic() + 10
    while psutil.pid_exists(pid) and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
        assert time.monotonic() < deadline, "a stray of the finished program survived"
        time.sleep(0.05)


def test_a_killed_worker_takes_its_executable_group_along(tmp_path):
    """The guardian: the worker (here a child python) is SIGKILLed mid-program.

    The script reads its input first: the worker tells the guardian the
    group's id before it writes the input, so the guardian is armed when
    the marks appear."""
    marks = tmp_path / "pids"
    p = script(tmp_path, f"#!/bin/sh\ncat >/dev/null\nsleep 300 &\necho $$ $! > {marks}\nwait\n")
    import subprocess

    worker = subprocess.Popen([sys.executable, "-c", "import sys; from ramps.runtime.command import CommandProgram; "
                               f"CommandProgram({p!r}).run({{}}, on_progress=lambda f, d: None)"])
    deadline = time.monotonic() + 20
    while not marks.exists() or len(marks.read_text().split()) < 2:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    pids = list(map(int, marks.read_text().split()))
    os.kill(worker.pid, signal.SIGKILL)
    worker.wait()
    deadline = time.monotonic() + 10
    while any(psutil.pid_exists(x) and psutil.Process(x).status() != psutil.STATUS_ZOMBIE for x in pids):
        assert time.monotonic() < deadline, "the executable outlived its worker"
        time.sleep(0.05)


def test_arguments_must_be_json(tmp_path):
    reg = Registry()
    spec = reg.add_command("cat", "/bin/cat")
    assert encode_args(spec, {"a": [1, "x", None]})
    with pytest.raises(BadArguments, match="JSON"):
        encode_args(spec, {"blob": b"\x00\x01"})
    with pytest.raises(CommandFailed, match="JSON"):
        spec.function().run({"x": float("nan")}, on_progress=lambda f, d: None)


def test_registration_checks_the_file_now(tmp_path):
    reg = Registry()
    with pytest.raises(ConfigError, match="no such file"):
        reg.add_command("x", str(tmp_path / "missing"))
    plain = tmp_path / "plain"
    plain.write_text("#!/bin/sh\n")
    with pytest.raises(ConfigError, match="not executable"):
        reg.add_command("x", str(plain))
    with pytest.raises(ConfigError, match="command name"):
        reg.add_command("bad name", "/bin/cat")
    spec = reg.add_command("cat", "/bin/cat", timeout=5, args=["-u"])
    again = resolve(spec.target)  # what a worker process rebuilds from the target alone
    assert (again.path, again.timeout, again.args, again.name) == ("/bin/cat", 5.0, ["-u"], "cat")
    assert again.run({"k": 1}, on_progress=lambda f, d: None) == {"k": 1}


def test_commands_from_flags_environment_and_config_file(tmp_path):
    cfg = tmp_path / "node.toml"
    cfg.write_text('[commands.detect]\npath = "/bin/cat"\ntimeout = 12.5\nwork = 3.0\n')
    s = load_settings(config_file=cfg, environ={}, flags={"robot": "r1"})
    assert s.commands["detect"].timeout == 12.5 and s.commands["detect"].work == 3.0
    s = load_settings(config_file=cfg, environ={}, flags={"robot": "r1", "commands": {"plan": {"path": "/bin/true"}}})
    assert set(s.commands) == {"detect", "plan"}  # --command adds to the file's commands
    s = load_settings(environ={"RAMPS_COMMANDS": "a=/bin/cat, b=/bin/true"}, flags={"robot": "r1"})
    assert {k: v.path for k, v in s.commands.items()} == {"a": "/bin/cat", "b": "/bin/true"}
    with pytest.raises(ConfigError, match="NAME=PATH"):
        load_settings(environ={"RAMPS_COMMANDS": "nopath"}, flags={"robot": "r1"})
    cfg.write_text('[commands.detect]\npath = "/bin/cat"\ntimeout = -1\n')
    with pytest.raises(ConfigError, match="timeout"):
        load_settings(config_file=cfg, environ={}, flags={"robot": "r1"})
