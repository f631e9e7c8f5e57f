"""The program executor's worker processes.

How this works: ``size`` worker processes (the robot's cores) are kept
ready, so a program starts in well under a millisecond. Workers are forked
by the node's fork server (``python -m ramps.runtime.worker --fork-server``,
see ``ramps.runtime.forkserver``), which has imported the programs already:
a new worker costs milliseconds of CPU, not the 0.2 s of a fresh
interpreter, a node's Zenoh threads are never forked and the caller's
``__main__`` is never re-imported. Each worker runs one program at a time;
jobs and results travel as length-prefixed msgpack frames over the worker's
own pipes (see ``ramps.runtime.worker``); nothing is pickled. The fork server
and its workers die with the node (``PR_SET_PDEATHSIG``), so a node killed
alone leaves no work running that nobody will collect.

Every program runs at once, as one process each, and the operating system
shares the cores among them: processor sharing, which is what the cost model
(``ramps.core.cost``), the simulator and the paper's prototype (one process
per program) assume. When every worker is busy and none has finished a
program (nor started) for ``GROW_AFTER``, every program that has waited that
long gets a new worker at once, up to ``max_size`` (default 8 per core, so
a flood of programs cannot exhaust memory); beyond that programs wait in a
FIFO queue. A burst of tiny programs, which keeps the workers finishing, is
served by the workers there are. Nor does the pool grow while the programs
it runs are starved: every busy worker runnable (Linux's ``/proc``) yet
none given ``STARVED_CPU`` of CPU since the pool first looked at it while
programs waited. Those are short programs on a host busy with other work
(the robot's own software), not long ones: a new worker would only split
the same CPU among more programs, which then all end late together, and
take more of it from the robot's software; the queue waits for them, as it
does for tiny ones. The CPU is counted in the robot's cores
(``core_share``: the host cores one of them is, under a CPU quota), so a
program on a robot whose cores are slices of a host's (a container, an
emulated robot) that gets its share is not starved. A long program (one that gets its CPU), one that sleeps
(I/O, an executable's child) or one this system cannot see lets the pool
grow as above. A worker beyond ``size`` exits after ``RETIRE_AFTER`` idle.

One monitor thread watches every worker's output. A result is handed to
``on_finished``; a worker that dies under a program (killed, out of memory,
``os._exit``, a crash) is reported as a *retryable* failure so the origin
places the program again, and a fresh worker takes its place. Where the fork
server said how the worker ended (its exit code or signal and the last lines
it wrote to stderr, see ``ramps.runtime.forkserver``) the report says so and
is marked ``died``: the worker died by itself while this executor lived, which
the origin counts towards calling the program a poison pill
(``ramps.core.origin``); a worker killed with its fork server is not.
``cancel`` kills the worker running a program (or drops it from the queue)
and reports nothing: the core already knows.
"""

from __future__ import annotations

import os
import select
import selectors
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from typing import Any, Callable, NamedTuple

import msgspec

from ramps.runtime.forkserver import Forked
from ramps.runtime.frames import frame
from ramps.runtime.measure import stat_cpu

Key = tuple[str, int]
#: on_finished(key, ok, value_bytes, error_text, retryable, cpu_seconds or None,
#: died: the worker died by itself, as the fork server saw it)
Finished = Callable[[Key, bool, bytes, str, bool, "float | None", bool], None]
#: on_progress(key, fraction, detail): a running program reported progress
Progress = Callable[[Key, float, str], None]
#: on_checkpoint(key, state_bytes, fraction): a running program saved its state
Checkpoint = Callable[[Key, bytes, "float | None"], None]

#: seconds a program waits, with no worker finishing or starting meanwhile, before the pool starts another
GROW_AFTER = 0.1
#: CPU seconds a busy worker uses, once the pool has looked at it while programs waited, for it to
#: count as running a long program rather than a starved short one (the pool grows only then): a
#: program that ends within GROW_AFTER of CPU is a tiny one, however long a busy host makes it take
STARVED_CPU = GROW_AFTER
#: seconds an extra worker (beyond one per core) stays idle before it exits
RETIRE_AFTER = 2.0
#: seconds the fork server may take to fork a worker (it imports the programs first)
FORK_TIMEOUT = 60.0
#: lines of a dead worker's stderr quoted in its program's error (ramps's own
#: frames in a crash's traceback left out)
STDERR_LINES = 10
_OWN_FRAMES = ("/ramps/runtime/worker.py\"", "/ramps/runtime/forkserver.py\"", "<frozen runpy>")

_enc = msgspec.msgpack.Encoder()
_dec = msgspec.msgpack.Decoder()


class _Job(NamedTuple):
    """A program waiting for a worker."""

    key: Key
    program: str
    args: bytes
    queued_at: float
    #: the checkpoint it resumes from, if any
    resume: bytes | None
    #: the accelerator it runs on (``Grant.as_wire``), None on a CPU
    accelerator: dict[str, Any] | None = None


class _Worker:
    __slots__ = ("proc", "fd", "buf", "job", "cancelled", "retiring", "idle_since", "ended", "cpu_mark", "stat_fd")

    def __init__(self, proc: Forked) -> None:
        self.proc = proc
        self.fd = proc.stdout.fileno()
        self.buf = bytearray()
        self.job: Key | None = None
        self.cancelled = False
        self.retiring = False
        self.idle_since = time.monotonic()
        #: how it ended, from the fork server: {"died": "exit code 3", "stderr": "..."}
        self.ended: dict[str, object] | None = None
        #: its CPU seconds when the pool first looked at it running its program while others waited
        self.cpu_mark: float | None = None
        #: its ``/proc/<pid>/stat``, opened the first time the pool looks (``cpu``)
        self.stat_fd: int | None = None

    def cpu(self) -> tuple[float, str] | None:
        """Its CPU seconds and state (``ramps.runtime.measure.proc_cpu``), None if unreadable."""
        if self.stat_fd is None:
            try:
                self.stat_fd = os.open(f"/proc/{self.proc.pid}/stat", os.O_RDONLY)
            except OSError:
                return None
        return stat_cpu(self.stat_fd)

    def close_stat(self) -> None:
        if self.stat_fd is not None:
            os.close(self.stat_fd)
            self.stat_fd = None


def death_text(ended: dict[str, object] | None) -> str:
    """A dead worker's program error: how it ended and, if it wrote any,
    the last ``STDERR_LINES`` lines of its stderr."""
    if ended is None:
        return "worker process died under the program (killed or crashed)"
    how = str(ended.get("died", "?"))
    lines = [ln for ln in str(ended.get("stderr", "")).splitlines()
             if ln.strip() and not any(own in ln for own in _OWN_FRAMES)][-STDERR_LINES:]
    text = f"worker process died under the program: {how}"
    if lines:
        text += "; its last stderr:\n" + "\n".join("    " + ln[:300] for ln in lines)
    return text


class WorkerPool:
    def __init__(self, size: int, targets: dict[str, str], on_finished: Finished, *,
                 env: dict[str, str] | None = None, nice: int = 0, max_size: int | None = None,
                 on_progress: Progress | None = None, on_checkpoint: Checkpoint | None = None,
                 core_share: float = 1.0, bundled: bool = True) -> None:
        if size < 1:
            raise ValueError("a worker pool needs at least one worker")
        self.size = size
        self.max_size = max(size, max_size if max_size is not None else 8 * size)
        self.targets, self.bundled = dict(targets), bundled  # bundled: the fork server preloads theirs too
        self.on_finished = on_finished
        self.on_progress, self.on_checkpoint = on_progress, on_checkpoint
        self.env, self.nice = env, nice
        #: host cores one of the robot's cores is (under a CPU quota: its share; else 1)
        self.core_share = min(1.0, max(core_share, 1e-3))
        self._lock = threading.Lock()
        self._sel = selectors.DefaultSelector()
        self._workers: list[_Worker] = []
        self._queue: deque[_Job] = deque()
        self._wake_r, self._wake_w = os.pipe()
        self._sel.register(self._wake_r, selectors.EVENT_READ, None)
        self._stopping = False
        self._thread = threading.Thread(target=self._monitor, name="ramps-workers", daemon=True)
        self.started = self.died = 0
        #: workers forked by the fork server (all of them, unless it failed)
        self.forked = 0
        self._server: subprocess.Popen[bytes] | None = None
        self._server_sock: socket.socket | None = None
        #: when a worker last finished a program or was started (growth waits GROW_AFTER after it)
        self._last_progress = 0.0

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        with self._lock:
            for _ in range(self.size):
                self._add_worker()
        self._thread.start()

    def _start_server(self) -> socket.socket:
        """The fork server (``ramps.runtime.forkserver``), with the programs'
        modules imported; returns the socket that asks it for workers."""
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            self._server = subprocess.Popen(
                [sys.executable, "-m", "ramps.runtime.worker", "--fork-server", str(os.getpid()),
                 str(theirs.fileno())],
                stdin=subprocess.DEVNULL, env=self.env, close_fds=True, pass_fds=(theirs.fileno(),))
        finally:
            theirs.close()
        ours.settimeout(FORK_TIMEOUT)
        ours.send(_enc.encode({"targets": self.targets, "bundled": self.bundled}))
        self._server_sock = ours
        return ours

    def _stop_server(self) -> None:
        if self._server_sock is not None:
            self._server_sock.close()
            self._server_sock = None
        if self._server is not None:
            if self._server.poll() is None:
                self._server.kill()
            try:
                self._server.wait(timeout=2)
            except subprocess.TimeoutExpired:
                pass
            self._server = None

    def _fork(self) -> Forked:
        """A new worker from the fork server (restarted once if it is gone)."""
        for attempt in (1, 2):
            sock = self._server_sock
            if sock is None or self._server is None or self._server.poll() is not None:
                self._stop_server()
                sock = self._start_server()
            job_r, job_w = os.pipe()
            res_r, res_w = os.pipe()
            try:
                socket.send_fds(sock, [b"fork"], [job_r, res_w])
                reply = sock.recv(16)
                if len(reply) != 8:
                    raise OSError("the fork server closed")
            except OSError:
                for fd in (job_w, res_r):
                    os.close(fd)
                self._stop_server()
                if attempt == 2:
                    raise
                continue
            finally:
                os.close(job_r)
                os.close(res_w)
            self.forked += 1
            return Forked(int(reply), os.fdopen(job_w, "wb", buffering=0), os.fdopen(res_r, "rb", buffering=0))
        raise AssertionError("unreachable")

    def _add_worker(self) -> None:
        proc = self._fork()
        proc.stdin.write(frame(_enc.encode({"targets": self.targets, "nice": self.nice})))
        w = _Worker(proc)
        self._workers.append(w)
        self._sel.register(w.fd, selectors.EVENT_READ, w)
        self.started += 1

    def stop(self) -> None:
        with self._lock:
            self._stopping = True
            workers = list(self._workers)
            self._queue.clear()
        self._poke()
        for w in workers:
            try:
                w.proc.stdin.close()
            except OSError:
                pass
            if w.proc.poll() is None:
                w.proc.kill()
        for w in workers:
            try:
                w.proc.wait(timeout=2)
            except subprocess.TimeoutExpired:
                pass
            try:
                w.proc.stdout.close()
            except OSError:
                pass
        self._stop_server()
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        for w in workers:
            w.close_stat()
        self._sel.close()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def _poke(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass

    # ------------------------------------------------------------ jobs
    def run(self, key: Key, program: str, args: bytes, resume: bytes | None = None,
            accelerator: dict[str, Any] | None = None) -> None:
        """Run ``program`` (resuming from the checkpoint ``resume``, if any;
        on the ``accelerator`` granted, if any)."""
        with self._lock:
            if self._stopping:
                return
            before = len(self._queue)
            self._queue.append(_Job(key, program, args, time.monotonic(), resume, accelerator))
            self._dispatch_locked()
            # the monitor (a worker for a program that waits GROW_AFTER, from its busy workers' CPU) wakes when
            # programs start to wait or a worker took one; not for each behind them (it wakes every GROW_AFTER / 2)
            wake = bool(self._queue) and (before == 0 or len(self._queue) <= before)
        if wake:
            self._poke()

    def cancel(self, key: Key) -> None:
        with self._lock:
            for i, queued in enumerate(self._queue):
                if queued.key == key:
                    del self._queue[i]
                    return
            for w in self._workers:
                if w.job == key:
                    w.cancelled = True
                    w.proc.kill()
                    break

    def busy(self) -> int:
        with self._lock:
            return sum(1 for w in self._workers if w.job is not None)

    def queued(self) -> int:
        with self._lock:
            return len(self._queue)

    def pids(self) -> dict[Key, int]:
        """Which worker process runs which program (for tests and tools)."""
        with self._lock:
            return {w.job: w.proc.pid for w in self._workers if w.job is not None}

    def _dispatch_locked(self) -> None:
        """Queued programs to idle workers, in order, each worker looked at
        only when one needs it (whether it lives is a system call)."""
        if not self._queue:
            return
        idle = (w for w in self._workers if w.job is None and not w.retiring and w.proc.poll() is None)
        now = time.monotonic()
        while self._queue:
            w = next(idle, None)
            if w is None:
                if (len(self._workers) >= self.max_size or now - self._queue[0].queued_at < GROW_AFTER
                        or now - self._last_progress < GROW_AFTER or self._starved_locked()):
                    return
                try:
                    self._add_worker()
                except OSError:  # out of processes or memory: the queue waits for a worker
                    return
                w = self._workers[-1]
            job = self._queue.popleft()
            w.job, w.cancelled, w.cpu_mark = job.key, False, None
            message: list[Any] = [job.program, job.args]
            if job.resume is not None or job.accelerator is not None:
                message.append(job.resume)
            if job.accelerator is not None:
                message.append(job.accelerator)
            try:
                w.proc.stdin.write(frame(_enc.encode(message)))
            except (BrokenPipeError, OSError):
                pass  # the monitor sees the dead worker and reports the job

    def _starved_locked(self) -> bool:
        """Whether every busy worker is runnable yet none has had
        ``STARVED_CPU`` since the pool first looked at it (marking those it
        looks at for the first time): short programs held back by a busy
        host, which a new worker would not speed up (the module's docstring)."""
        starved = True
        for w in self._workers:
            if w.job is None or select.select([w.fd], [], [], 0)[0]:
                continue  # idle, or its reply (or progress) not read yet: it waits for this pool, not for CPU
            seen = w.cpu()
            if seen is None:
                return False  # cannot tell: grow as on any system
            cpu, state = seen
            if w.cpu_mark is None:
                w.cpu_mark = cpu
            if state != "R" or cpu - w.cpu_mark >= STARVED_CPU * self.core_share:
                starved = False
        return starved

    def _mark_busy_locked(self) -> None:
        """Note the CPU of the busy workers not looked at yet, while programs
        wait: the mark ``_starved_locked`` counts from."""
        for w in self._workers:
            if w.job is not None and w.cpu_mark is None:
                seen = w.cpu()
                if seen is not None:
                    w.cpu_mark = seen[0]

    def _retire_idle_locked(self) -> float | None:
        """Workers beyond ``size`` idle for RETIRE_AFTER exit (end of input).
        Returns the seconds until the next one would, if any."""
        spare = len(self._workers) - self.size
        now = time.monotonic()
        nxt = None
        for w in self._workers:
            if spare <= 0 or self._queue:
                return None
            if w.job is None and not w.retiring and now - w.idle_since < RETIRE_AFTER:
                left = RETIRE_AFTER - (now - w.idle_since)
                nxt = left if nxt is None else min(nxt, left)
            elif w.job is None and not w.retiring:
                w.retiring = True
                spare -= 1
                try:
                    w.proc.stdin.close()
                except OSError:
                    pass
        return nxt

    # ------------------------------------------------------------ monitor thread
    def _monitor(self) -> None:
        while True:
            with self._lock:  # a waiting program may need a new worker, an idle extra one may go
                wait = GROW_AFTER / 2 if self._queue and len(self._workers) < self.max_size else None
                if wait is not None:
                    self._mark_busy_locked()
                retire = self._retire_idle_locked()
                if retire is not None:
                    wait = retire + 0.01 if wait is None else min(wait, retire + 0.01)
            events = self._sel.select(wait)
            finished: list[tuple[Key, bool, bytes, str, bool, float | None, bool]] = []
            progress: list[tuple[Key, float, str]] = []
            checkpoints: list[tuple[Key, bytes, float | None]] = []
            with self._lock:
                if self._stopping:
                    return
                for skey, _ in events:
                    w: _Worker | None = skey.data  # None: the wake-up pipe
                    if w is None:
                        os.read(self._wake_r, 4096)
                        continue
                    try:
                        chunk = os.read(w.fd, 65536)
                    except OSError:
                        chunk = b""
                    if chunk:
                        w.buf += chunk
                        while len(w.buf) >= 4:
                            n = int.from_bytes(w.buf[:4], "big")
                            if len(w.buf) < 4 + n:
                                break
                            body, w.buf = bytes(w.buf[4:4 + n]), w.buf[4 + n:]
                            try:
                                reply = _dec.decode(body)
                            except msgspec.DecodeError:  # cut short by its death: the end of file follows
                                continue
                            if isinstance(reply, dict) and "died" in reply:  # the fork server: how it ended
                                w.ended = reply
                                continue
                            if isinstance(reply, dict) and "checkpoint" in reply:  # its saved state
                                if w.job is not None and not w.cancelled and isinstance(reply["checkpoint"], bytes):
                                    checkpoints.append((w.job, reply["checkpoint"], reply.get("fraction")))
                                continue
                            if isinstance(reply, dict):  # progress of the running program, not its end
                                if w.job is not None and not w.cancelled:
                                    progress.append((w.job, reply.get("progress", 0.0), reply.get("detail", "")))
                                continue
                            ok, value, error = reply[:3]
                            cpu = reply[3] if len(reply) > 3 and isinstance(reply[3], (int, float)) else None
                            if w.job is not None and not w.cancelled:
                                finished.append((w.job, ok, value, error, False, cpu, False))
                            w.job = None
                            w.idle_since = self._last_progress = time.monotonic()
                        continue
                    # end of file: the worker is gone
                    self._sel.unregister(w.fd)
                    self._workers.remove(w)
                    w.close_stat()
                    w.proc.wait()
                    for f in (w.proc.stdin, w.proc.stdout):
                        try:
                            f.close()
                        except OSError:
                            pass
                    if w.job is not None and not w.cancelled:
                        self.died += 1
                        finished.append((w.job, False, b"", death_text(w.ended), True, None, w.ended is not None))
                    if len(self._workers) < self.size:
                        self._add_worker()
                self._dispatch_locked()  # idle extra workers retire at the top of the loop
            if self.on_progress is not None:
                for p in progress:
                    self.on_progress(*p)
            if self.on_checkpoint is not None:
                for c in checkpoints:
                    self.on_checkpoint(*c)
            for item in finished:
                self.on_finished(*item)
