"""Programs that are executables: a C++ planner, a detector, a script.

How this works: ``ramps node --command NAME=PATH`` (or a ``[commands.NAME]``
table in the config file) registers an executable installed on the robot as
the program NAME. As for Python programs, only the name and the arguments
travel (weak mobility): the same executable must be installed on every
robot that may run it, at the path its own node was given.

The contract with the executable (``docs/ros2.md`` repeats it):

- **arguments**: the call's keyword arguments, one JSON object on stdin
  (``{"seed": 3, "goal": [1, 2]}``), then end of input. Extra command-line
  arguments fixed at registration (``args``) come first on argv.
- **result**: stdout, one JSON value (whitespace around it is ignored; empty
  stdout is ``null``). Anything else on stdout is an error, so log to stderr.
- **failure**: a non-zero exit code (or death by a signal). The caller gets a
  ``ProgramFailed`` naming the exit code and the last ``STDERR_TAIL``
  characters of stderr.
- **progress**: a line ``RAMPS_PROGRESS <fraction> [text]`` on stderr, the
  fraction between 0 and 1; it reaches the caller's future (``fut.progress``)
  and ROS action feedback. Such lines are not part of the stderr tail.
- **checkpoint**: a line ``RAMPS_CHECKPOINT <one JSON value>`` on stderr
  saves the program's state (as ``ramps.checkpoint``: at most 256 KiB, at
  most five a second kept; report progress before it). A checkpoint that
  is not JSON or too big stops the program with a clear error, as an
  uncaught ``ramps.checkpoint`` error stops a Python program.
- **resume**: after a move or a failure, ``RAMPS_RESUME`` names a file
  holding the latest checkpoint (the same JSON value); on a fresh start it
  is not set.
- **time limit**: ``timeout`` seconds (default ``DEFAULT_TIMEOUT``); then the
  process group is killed and the caller gets a clear error.
- **environment**: the node's, plus ``RAMPS_PROGRAM`` (the program's name).
- **process group**: the executable runs in its own session and process
  group. The whole group is killed (SIGKILL) when the program ends (strays
  left behind), times out, is withdrawn, is moved elsewhere, or its node
  leaves or dies: a small guardian process, forked before the executable
  starts, holds the group's id and kills it as soon as the worker that ran
  it is gone, however it went (``WorkerPool.cancel`` kills that worker).

The executable runs inside an ordinary worker process
(``ramps.runtime.worker``), so placement, heartbeats, failure recovery and
cancellation are those of every other program.
"""

from __future__ import annotations

import json
import math
import os
import selectors
import signal
import struct
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Callable, cast

#: seconds an executable may run unless its registration says otherwise
DEFAULT_TIMEOUT = 600.0
#: characters of stderr returned with a failure (the wire limits errors to 4096)
STDERR_TAIL = 2000
#: the prefix of a progress line on stderr
PROGRESS_PREFIX = b"RAMPS_PROGRESS"
#: the prefix of a checkpoint line on stderr
CHECKPOINT_PREFIX = b"RAMPS_CHECKPOINT"
#: target strings of command programs in the registry start with this
TARGET_PREFIX = "exec:"


class CommandFailed(Exception):
    """The executable failed; ``str()`` is the whole message for the caller."""


def command_target(path: str, *, timeout: float = DEFAULT_TIMEOUT, args: list[str] | None = None,
                   name: str = "") -> str:
    """The registry target of an executable (``exec:{json}``): what a worker
    needs to run it. Checks now, so a typo fails when the node starts."""
    p = Path(path).expanduser()
    if not p.is_absolute():
        p = p.resolve()
    if not p.is_file():
        raise ValueError(f"command {path!r}: no such file")
    if not os.access(p, os.X_OK):
        raise ValueError(f"command {path!r} is not executable (chmod +x it)")
    if not (isinstance(timeout, (int, float)) and math.isfinite(timeout) and timeout > 0):
        raise ValueError(f"command {path!r}: timeout must be a positive number of seconds, got {timeout!r}")
    return TARGET_PREFIX + json.dumps({"path": str(p), "timeout": float(timeout), "args": list(args or []),
                                        "name": name or p.name})


def parse_target(target: str) -> "CommandProgram":
    try:
        d = json.loads(target[len(TARGET_PREFIX):])
        return CommandProgram(d["path"], timeout=float(d.get("timeout", DEFAULT_TIMEOUT)), args=d.get("args", []),
                              name=d.get("name", ""))
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"bad command target {target!r}: {exc}") from None


def parse_progress(line: bytes) -> tuple[float, str] | None:
    """``RAMPS_PROGRESS 0.42 text`` -> (0.42, "text"); None if not such a line
    or the fraction is not a number in [0, 1]."""
    if not line.startswith(PROGRESS_PREFIX):
        return None
    parts = line[len(PROGRESS_PREFIX):].decode("utf-8", "replace").strip().split(None, 1)
    if not parts:
        return None
    try:
        fraction = float(parts[0])
    except ValueError:
        return None
    if not 0.0 <= fraction <= 1.0:
        return None
    return fraction, (parts[1] if len(parts) > 1 else "")


class CommandProgram:
    """A registered executable; calling it runs it once (in a worker)."""

    def __init__(self, path: str, *, timeout: float = DEFAULT_TIMEOUT, args: list[str] | None = None,
                 name: str = "") -> None:
        self.path = path
        self.timeout = timeout
        self.args = list(args or [])
        self.name = name or Path(path).name

    def __repr__(self) -> str:
        return f"CommandProgram({self.path!r}, timeout={self.timeout:g})"

    def __call__(self, **kwargs: Any) -> Any:
        return self.run(kwargs)

    def check_args(self, kwargs: dict[str, Any]) -> None:
        """Arguments must be JSON (no bytes, no non-string keys)."""
        try:
            json.dumps(kwargs, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"arguments of an executable travel as JSON: {exc}") from None

    def run(self, kwargs: dict[str, Any], *, on_progress: Callable[[float, str], object] | None = None,
            on_checkpoint: Callable[[Any], Any] | None = None, resume: Any = None) -> Any:
        """Run it once. In a worker, progress and checkpoints go to the
        program's origin and ``resume`` is the state saved in an earlier
        attempt (``ramps.runtime.running``); outside one, pass them."""
        try:
            stdin = json.dumps(kwargs, allow_nan=False).encode()
        except (TypeError, ValueError) as exc:
            raise CommandFailed(f"arguments of {self.name} cannot be passed as JSON: {exc}") from None
        from ramps.runtime import running

        if on_progress is None:
            on_progress = running.report_progress
        if on_checkpoint is None:
            on_checkpoint = running.save_checkpoint
            resume = running.resume_state() if resume is None else resume

        env = dict(os.environ)
        env["RAMPS_PROGRAM"] = self.name
        env.pop("RAMPS_RESUME", None)
        resume_file = None
        if resume is not None:
            try:
                text = json.dumps(resume, allow_nan=False)
            except (TypeError, ValueError) as exc:
                raise CommandFailed(f"{self.name}: its saved state cannot be passed back as JSON: {exc}") from None
            fd, resume_file = tempfile.mkstemp(prefix=f"ramps-resume-{os.getpid()}-", suffix=".json")
            with os.fdopen(fd, "w") as f:
                f.write(text)
            env["RAMPS_RESUME"] = resume_file
        try:
            return self._run(stdin, env, on_progress, on_checkpoint, running.MAX_RESULT_BYTES)
        finally:
            if resume_file:
                try:
                    os.unlink(resume_file)
                except OSError:
                    pass

    def _run(self, stdin: bytes, env: dict[str, str], on_progress: Callable[[float, str], object],
             on_checkpoint: Callable[[Any], Any], max_result: int) -> Any:
        guard_r, guard_w = os.pipe()
        # The guardian is forked first: a worker killed while the executable
        # starts must not leave it behind. It learns the group's id (the
        # executable's pid, as it leads its own session) before the
        # executable is given its input.
        guardian = _start_guardian(guard_r)
        os.close(guard_r)
        try:
            proc = subprocess.Popen([self.path, *self.args], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, env=env, start_new_session=True, close_fds=True)
        except OSError as exc:
            os.close(guard_w)  # end of input before a group id: the guardian leaves
            if guardian:
                os.waitpid(guardian, 0)
            raise CommandFailed(f"{self.name}: cannot start {self.path}: {exc.strerror or exc}") from None
        try:
            os.write(guard_w, _GROUP.pack(proc.pid))
        except OSError:
            pass
        deadline = time.monotonic() + self.timeout
        try:
            got = _communicate(proc, stdin, deadline, max_result, on_progress, on_checkpoint)
            if not got.stopped:
                try:  # it may close its output and go on running
                    proc.wait(timeout=max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    got.timed_out = True
        finally:
            _kill_group(proc.pid)  # strays the executable left behind, before its group id can be reused
            proc.wait()
            try:
                os.write(guard_w, b"d")  # done: the guardian leaves without killing
            except OSError:
                pass
            os.close(guard_w)
            if guardian:
                try:
                    os.waitpid(guardian, 0)
                except ChildProcessError:
                    pass
        tail = got.err_tail.decode("utf-8", "replace")[-STDERR_TAIL:]
        if got.bad_checkpoint:
            raise CommandFailed(f"{self.name} wrote a checkpoint ramps cannot keep ({got.bad_checkpoint}) and was "
                                "stopped" + _stderr(tail))
        if got.timed_out:
            raise CommandFailed(f"{self.name} did not finish within its time limit of {self.timeout:g} s and was "
                                f"killed" + _stderr(tail))
        if got.too_big:
            raise CommandFailed(f"{self.name} wrote more than {max_result} bytes on stdout (results must fit "
                                "one message: write a file and return its path)")
        code = proc.returncode
        if code != 0:
            if code < 0:
                try:
                    how = f"was killed by signal {signal.Signals(-code).name}"
                except ValueError:
                    how = f"was killed by signal {-code}"
            else:
                how = f"exited with code {code}"
            raise CommandFailed(f"{self.name} {how}" + _stderr(tail))
        text = bytes(got.out).strip()
        if not text:
            return None
        try:
            return json.loads(text)
        except (ValueError, UnicodeDecodeError) as exc:
            head = text[:200].decode("utf-8", "replace")
            raise CommandFailed(f"{self.name} exited 0 but its stdout is not JSON ({exc}); it began with {head!r}"
                                + _stderr(tail)) from None


def _stderr(tail: str) -> str:
    return f"; stderr (last {STDERR_TAIL} characters):\n{tail}" if tail.strip() else "; stderr was empty"


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


#: how the worker tells its guardian the executable's process group
_GROUP = struct.Struct("!q")


def _start_guardian(read_fd: int) -> int:
    """Fork a process that kills the executable's group when the worker dies.

    It leaves the worker's process group (a crash that kills the node's
    whole group must not take the guardian along) and reads ``read_fd``:
    first the group's id (``_GROUP``), then one byte if the worker finished
    the program itself. End of input after the id and before the byte
    means the worker is gone: kill the group. End of input before the id
    means the executable never started."""
    try:
        pid = os.fork()
    except OSError:
        return 0  # no guardian: the program still runs and is killed when it ends normally
    if pid:
        return pid
    try:  # the child: only os-level calls, then _exit
        os.closerange(0, read_fd)  # the worker's pipes too: the pool must see the worker's end at once
        os.closerange(read_fd + 1, os.sysconf("SC_OPEN_MAX") if hasattr(os, "sysconf") else 1024)
        os.setsid()
        head = b""
        try:
            while len(head) < _GROUP.size:
                got = os.read(read_fd, _GROUP.size - len(head))
                if not got:
                    break
                head += got
            gone = len(head) == _GROUP.size and not os.read(read_fd, 1)
        except OSError:
            gone = len(head) == _GROUP.size
        if gone:
            _kill_group(_GROUP.unpack(head)[0])
    finally:
        os._exit(0)


def parse_checkpoint(line: bytes) -> Any:
    """``RAMPS_CHECKPOINT {"i": 3}`` -> {"i": 3}; ``NotACheckpoint`` if the
    line is no checkpoint; ValueError if it is one that is not JSON."""
    if not line.startswith(CHECKPOINT_PREFIX + b" "):
        return NotACheckpoint
    try:
        return json.loads(line[len(CHECKPOINT_PREFIX) + 1:])
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"not one JSON value: {exc}") from None


class NotACheckpoint:
    """What ``parse_checkpoint`` returns for any other line."""


#: the longest checkpoint line read (JSON of MAX_CHECKPOINT_BYTES of state, escaped)
_MAX_CHECKPOINT_LINE = 6 * 256 * 1024


@dataclass(slots=True)
class _Exchange:
    """What ``_communicate`` read from an executable, and why it stopped reading early if it did."""

    out: bytearray = field(default_factory=bytearray)
    #: stderr without its progress and checkpoint lines, its last ``2 * STDERR_TAIL`` bytes or more
    err_tail: bytearray = field(default_factory=bytearray)
    #: stderr's last line, not ended yet
    line: bytearray = field(default_factory=bytearray)
    timed_out: bool = False
    #: stdout grew over the largest result
    too_big: bool = False
    #: why a checkpoint cannot be kept; empty when none was refused
    bad_checkpoint: str = ""

    @property
    def stopped(self) -> bool:
        """Reading stopped before the executable closed its output."""
        return self.timed_out or self.too_big or bool(self.bad_checkpoint)


def _communicate(proc: subprocess.Popen, stdin: bytes, deadline: float, max_out: int,
                 on_progress: Callable[[float, str], object],
                 on_checkpoint: Callable[[Any], Any]) -> _Exchange:
    """Feed stdin, collect stdout and stderr (progress and checkpoint lines
    parsed out, stderr kept as a bounded tail) until both close, the time is
    up, stdout grows over ``max_out`` bytes or a checkpoint cannot be kept."""
    got = _Exchange()
    sel = selectors.DefaultSelector()
    pos = 0
    assert proc.stdin and proc.stdout and proc.stderr
    for f in (proc.stdin, proc.stdout, proc.stderr):
        os.set_blocking(f.fileno(), False)
    if stdin:
        sel.register(proc.stdin, selectors.EVENT_WRITE)
    else:
        proc.stdin.close()
    sel.register(proc.stdout, selectors.EVENT_READ)
    sel.register(proc.stderr, selectors.EVENT_READ)
    try:
        while sel.get_map() and not got.stopped:
            left = deadline - time.monotonic()
            if left <= 0:
                got.timed_out = True
                break
            for key, _ in sel.select(min(left, 1.0)):
                f = cast(IO[bytes], key.fileobj)  # only the process's pipes are registered
                if f is proc.stdin:
                    pos = _feed(sel, f, stdin, pos)
                    continue
                try:
                    chunk = os.read(f.fileno(), 65536)
                except BlockingIOError:
                    continue
                if not chunk:
                    sel.unregister(f)
                elif f is proc.stdout:
                    got.out += chunk
                    got.too_big = len(got.out) > max_out
                else:
                    _take_stderr(got, chunk, on_progress, on_checkpoint)
                if got.stopped:
                    break
    finally:
        sel.close()
        for f in (proc.stdin, proc.stdout, proc.stderr):
            try:
                f.close()
            except OSError:
                pass
    if not (got.too_big or got.bad_checkpoint):
        got.err_tail += got.line
    return got


def _feed(sel: selectors.BaseSelector, f: IO[bytes], data: bytes, pos: int) -> int:
    """Write the next piece of ``data`` from ``pos`` to the executable's stdin; close it
    when all is written or it does not read. Returns the new position."""
    try:
        pos += os.write(f.fileno(), data[pos:pos + 65536])
    except (BrokenPipeError, OSError):
        pos = len(data)  # it does not read its input: fine
    if pos >= len(data):
        sel.unregister(f)
        f.close()
    return pos


def _take_stderr(got: _Exchange, chunk: bytes, on_progress: Callable[[float, str], object],
                 on_checkpoint: Callable[[Any], Any]) -> None:
    """Add a piece of stderr: each whole progress or checkpoint line goes to its callback,
    any other line to the tail; a checkpoint that cannot be kept sets ``bad_checkpoint``."""
    got.line += chunk
    while (nl := got.line.find(b"\n")) >= 0:
        one = bytes(got.line[:nl + 1])
        del got.line[:nl + 1]
        stripped = one.strip()
        prog = parse_progress(stripped)
        if prog is not None:
            on_progress(*prog)
            continue
        try:
            state = parse_checkpoint(stripped)
            if state is not NotACheckpoint:
                on_checkpoint(state)
                continue
        except (ValueError, TypeError) as exc:
            got.bad_checkpoint = str(exc)[:500]
            return
        got.err_tail += one
    # a very long line without a newline: no progress in it (a checkpoint may be long, up to its own limit)
    limit = _MAX_CHECKPOINT_LINE if got.line.startswith(CHECKPOINT_PREFIX) else 4096
    if len(got.line) > limit:
        if limit == _MAX_CHECKPOINT_LINE:
            got.bad_checkpoint = "a line over 1.5 MiB"
            return
        got.err_tail += got.line
        got.line.clear()
    if len(got.err_tail) > 4 * STDERR_TAIL:
        del got.err_tail[:-STDERR_TAIL * 2]
