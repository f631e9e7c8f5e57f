"""The executor's fork server: new worker processes in milliseconds.

How this works: the worker pool (``ramps.runtime.workers``) starts one
``python -m ramps.runtime.worker --fork-server`` per node. It imports the
registered programs' modules once, and the modules each program names in
``preload`` (those it imports only when it runs, such as ``route_plan``'s
OR-Tools, see ``ramps.runtime.registry.program``), then waits on a Unix
socket: no worker pays an import, so a fresh team's first calls of a heavy
program run as fast as its later ones (``ramps bench first-calls``). For each new
worker the pool sends the worker's two pipe ends (``SCM_RIGHTS``); the
server forks, and the child becomes an ordinary worker
(``ramps.runtime.worker.run`` over those pipes, the same frames, nothing
pickled). The pool gets the child's pid back.

Why: booting ``python -m ramps.runtime.worker`` and importing the registry
costs about 0.2 s of CPU, which on a robot emulated at 0.08 of a host core per
core made programs beyond one per core start 2.5-4.5 s late. A fork of the
warmed server costs a few milliseconds. The server starts no thread of its
own (a library a program imports may: numpy's OpenBLAS pool, which stops
itself around a fork) and has no Zenoh session, so forking it is safe (the
node, which has Zenoh's threads, never forks a worker itself). What the
preload costs: the imports' CPU once, at the node's start, which waits for
its first workers (OR-Tools: about 0.4 CPU-seconds), and memory: the fork
server holds the imported modules (OR-Tools: about 70 MB resident), which its
workers share until they write to them. A module that is not installed (a
base install has no OR-Tools, ``ramps.extras``) is skipped. The bundled
programs' modules are imported only when the node says so
(``NodeSettings.preload_bundled``): a robot that never runs ``route_plan``
keeps its fork server at about 17 MiB instead of 90.

Death: the server and every worker ask the kernel (``PR_SET_PDEATHSIG``) for
SIGKILL when their parent dies, and check that it has not already. A node
killed alone (SIGKILL of its process only) takes its fork server with it,
and the server its workers, at once: work is never left running that nobody
will collect. Workers are reaped by the server (SIGCHLD is reset to the
default in each worker so programs can wait for their own children).

How a worker ended: the server keeps its own copy of each worker's result
pipe, a pidfd of the worker, and the read end of the worker's stderr (fds 1
and 2 of the worker), which it copies to its own stderr keeping the last
``STDERR_TAIL`` bytes. When the worker exits the server reaps it and writes
one last frame into its result pipe, ``{"died": "exit code 3" | "killed by
signal 11 (SIGSEGV)", "stderr": its last lines}``, then closes its copy: the pool sees
that frame, then end of file. A worker whose server died first (killed with
it, ``PR_SET_PDEATHSIG``) sends no such frame. Where pidfds are missing (Linux
before 5.3) the kernel reaps the workers and nothing is said.

Ctrl-C (SIGINT to the terminal's process group) is the node's: the server
and its workers ignore it, and the node, which hands its programs back
first, stops them.

Protocol on the socket (SOCK_SEQPACKET, one message each way per fork):
pool -> server ``b"fork"`` with fds [job_read, result_write]; server -> pool
the child's pid as 8 ASCII digits. Anything else ends the server. ``Forked``
is the pool's handle of one worker forked so.
"""

from __future__ import annotations

import ctypes
import importlib
import io
import os
import select
import selectors
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from typing import BinaryIO

import msgspec

from ramps.runtime.frames import frame

PR_SET_NAME = 15
PR_SET_PDEATHSIG = 1
#: what the fork server and its workers call themselves (``comm``: ``ps``, ``top``, and the
#: node's load sampler, which counts them as the node's own: ``ramps.runtime.runqueue``)
FORK_SERVER_NAME, WORKER_NAME = b"ramps-forksrv", b"ramps-worker"
#: bytes of a worker's stderr kept to say how it ended, and of that the last
#: lines sent (a crash's "Extension modules: ..." list left out), each cut
#: short: the frame stays within one atomic pipe write (PIPE_BUF, 4096)
STDERR_TAIL = 8192
TAIL_LINES = 20
TAIL_LINE_CHARS = 150


def _prctl(option: int, arg: int | ctypes.c_char_p) -> None:
    try:
        ctypes.CDLL(None, use_errno=True).prctl(option, arg, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux
        pass


def name_process(name: bytes) -> None:
    """What ``ps -o comm``/``top`` show for this process (Linux, 15 bytes)."""
    _prctl(PR_SET_NAME, ctypes.c_char_p(name[:15]))


def die_with_parent(parent: int) -> None:
    """SIGKILL this process when its parent dies (Linux); if the parent is
    already gone (reparented meanwhile), exit now."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: workers still end when their input closes
        return
    if os.getppid() != parent:
        os._exit(1)


def preload(targets: dict[str, str], *, bundled: bool = True) -> list[str]:
    """Import every program's module now, and the modules its spec names in
    ``preload`` (those it imports only when it runs, such as ``route_plan``'s
    OR-Tools), so a forked worker has them all and no run pays an import;
    ``bundled`` False: not those of the bundled programs (``BUILTINS``).
    Returns the ``preload`` modules imported. A module that fails here (any
    exception, ``SystemExit`` too) is skipped: the server goes on, and the
    program's runs fail with the import's own error."""
    from ramps.runtime.registry import BUILTINS, default_registry, resolve

    wanted = set(targets.values())
    extra: list[str] = []
    for target in sorted(wanted):
        try:
            fn = resolve(target)
        except BaseException:  # noqa: BLE001 - reported when the program runs
            continue
        extra.extend(getattr(getattr(fn, "__ramps_program__", None), "preload", ()))  # a decorated program's
    for spec in default_registry.specs():  # the built-ins, and the programs registered by those imports
        if spec.target in wanted and (bundled or BUILTINS.get(spec.name) is not spec):
            extra.extend(spec.preload)
    imported = []
    for module in dict.fromkeys(extra):
        try:
            importlib.import_module(module)
        except BaseException:  # noqa: BLE001 - reported when the program runs
            continue
        imported.append(module)
    return imported


def describe_status(status: int) -> str:
    """A ``waitpid`` status in words: "exit code 3", "killed by signal 11 (SIGSEGV)"."""
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        try:
            name = signal.Signals(sig).name
        except ValueError:
            return f"killed by signal {sig}"
        return f"killed by signal {sig} ({name})"
    if os.WIFEXITED(status):
        return f"exit code {os.WEXITSTATUS(status)}"
    return f"status {status}"


class _Watched:
    """What the server holds of one live worker (see the module's docstring)."""

    __slots__ = ("pid", "pidfd", "res_w", "err_r", "tail")

    def __init__(self, pid: int, pidfd: int, res_w: int, err_r: int) -> None:
        self.pid, self.pidfd, self.res_w, self.err_r = pid, pidfd, res_w, err_r
        self.tail = bytearray()


class _Workers:
    """The server's live workers: their stderr copied and tailed, their end
    reaped and reported into their result pipe."""

    def __init__(self, sock: socket.socket) -> None:
        self.sel = selectors.DefaultSelector()
        self.sel.register(sock, selectors.EVENT_READ, None)
        self.live: dict[int, _Watched] = {}

    def fds(self) -> list[int]:
        return [fd for w in self.live.values() for fd in (w.pidfd, w.res_w, w.err_r)]

    def add(self, pid: int, res_w: int, err_r: int) -> None:
        try:
            pidfd = os.pidfd_open(pid)
        except OSError:  # cannot watch it: the pool sees its end of file only
            os.close(res_w)
            os.close(err_r)
            return
        w = _Watched(pid, pidfd, res_w, err_r)
        self.live[pid] = w
        os.set_blocking(err_r, False)
        self.sel.register(pidfd, selectors.EVENT_READ, ("end", w))
        self.sel.register(err_r, selectors.EVENT_READ, ("err", w))

    def wait_for_request(self) -> None:
        """Copy stderr and report ends until the pool sends something."""
        while True:
            for key, _ in self.sel.select():
                if key.data is None:
                    return
                what, w = key.data
                if what == "err":
                    self._copy(w)
                else:
                    self._ended(w)

    def _copy(self, w: _Watched) -> bool:
        """Copy what the worker wrote to stderr; False at its end."""
        try:
            data = os.read(w.err_r, 65536)
        except BlockingIOError:
            return True
        except OSError:
            data = b""
        if not data:
            self.sel.unregister(w.err_r)
            os.close(w.err_r)
            w.err_r = -1
            return False
        try:
            os.write(2, data)
        except OSError:
            pass
        w.tail += data
        del w.tail[:-STDERR_TAIL]
        return True

    def _ended(self, w: _Watched) -> None:
        try:
            _, status = os.waitpid(w.pid, 0)
            how = describe_status(status)
        except ChildProcessError:
            how = "ended (status unknown)"
        # what it wrote last (a child of the program may still hold the pipe: no end of file)
        while w.err_r >= 0 and _readable(w.err_r) and self._copy(w):
            pass
        os.set_blocking(w.res_w, False)  # the worker is gone: nobody else writes; never block the server
        try:
            os.write(w.res_w, frame(msgspec.msgpack.encode({"died": how, "stderr": _last_lines(bytes(w.tail))})))
        except OSError:
            pass
        self.sel.unregister(w.pidfd)
        for fd in (w.pidfd, w.res_w):
            os.close(fd)
        if w.err_r >= 0:
            self.sel.unregister(w.err_r)
            os.close(w.err_r)
        del self.live[w.pid]


def _last_lines(tail: bytes) -> str:
    """The last TAIL_LINES lines worth quoting of a worker's stderr tail."""
    lines = tail.decode("utf-8", "replace").splitlines()
    if len(tail) >= STDERR_TAIL:
        lines = lines[1:]  # cut mid-line
    keep = [ln[:TAIL_LINE_CHARS] for ln in lines if ln.strip() and not ln.startswith("Extension modules:")]
    return "\n".join(keep[-TAIL_LINES:])


def _readable(fd: int) -> bool:
    return bool(select.select([fd], [], [], 0)[0])


def _pidfds() -> bool:
    try:
        os.close(os.pidfd_open(os.getpid()))
        return True
    except (AttributeError, OSError):
        return False


class Forked:
    """The pool's handle of a worker this server forked: not the pool's
    child, so it is watched and signalled through a pidfd (no pid reuse
    race). ``stdin`` carries its jobs, ``stdout`` its replies."""

    def __init__(self, pid: int, stdin: io.FileIO, stdout: io.FileIO) -> None:
        self.pid = pid
        self.stdin = stdin
        self.stdout = stdout
        self.returncode: int | None = None
        try:
            self._pidfd: int | None = os.pidfd_open(pid)
        except (AttributeError, OSError):  # gone already, or no pidfds (old kernel)
            self._pidfd = None

    def poll(self) -> int | None:
        if self.returncode is None:
            if self._pidfd is not None:
                if select.select([self._pidfd], [], [], 0)[0]:
                    self._ended()
            else:
                try:
                    os.kill(self.pid, 0)
                except ProcessLookupError:
                    self._ended()
        return self.returncode

    def _ended(self) -> None:
        self.returncode = -signal.SIGKILL if self._killed else 1  # the server reaps it: the status is not ours
        if self._pidfd is not None:
            os.close(self._pidfd)
            self._pidfd = None

    _killed = False

    def kill(self) -> None:
        if self.poll() is not None:
            return
        self._killed = True
        try:
            if self._pidfd is not None:
                signal.pidfd_send_signal(self._pidfd, signal.SIGKILL)
            else:
                os.kill(self.pid, signal.SIGKILL)
        except (ProcessLookupError, OSError):
            pass

    def wait(self, timeout: float | None = None) -> int:
        started = time.monotonic()
        while (code := self.poll()) is None:
            left: float | None = None
            if timeout is not None:
                left = timeout - (time.monotonic() - started)
                if left <= 0:
                    raise subprocess.TimeoutExpired(f"worker {self.pid}", timeout)
            if self._pidfd is not None:
                select.select([self._pidfd], [], [], left)
            else:
                time.sleep(0.01 if left is None else min(0.01, left))
        return code


def serve(sock: socket.socket, parent: int, run: Callable[[BinaryIO, BinaryIO], None]) -> None:
    """Fork a worker for each request on ``sock`` until it closes; each runs
    ``run`` over its two pipes (``ramps.runtime.worker.run``)."""
    die_with_parent(parent)
    name_process(FORK_SERVER_NAME)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the node's (see the module's docstring)
    init = sock.recv(1 << 20)
    if not init:
        return
    init = msgspec.msgpack.decode(init)
    preload(init["targets"], bundled=init.get("bundled", True))
    workers = _Workers(sock) if _pidfds() else None
    if workers is None:
        signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # the kernel reaps the workers
    me = os.getpid()
    while True:
        try:
            if workers is not None:
                workers.wait_for_request()
            msg, fds, _, _ = socket.recv_fds(sock, 64, 2)
        except (OSError, KeyboardInterrupt):
            return
        if msg != b"fork" or len(fds) != 2:
            for fd in fds:
                os.close(fd)
            return
        job_r, res_w = fds
        err_r, err_w = os.pipe() if workers is not None else (-1, -1)
        pid = os.fork()
        if pid == 0:  # the new worker
            try:
                sock.close()
                if workers is not None:  # other workers' pipes are not this one's to hold
                    workers.sel.close()
                    for fd in workers.fds() + [err_r]:
                        os.close(fd)
                    os.dup2(err_w, 2)
                    os.dup2(err_w, 1)
                    os.close(err_w)
                signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                die_with_parent(me)
                name_process(WORKER_NAME)
                inp = os.fdopen(job_r, "rb", buffering=0)
                out = os.fdopen(res_w, "wb", buffering=0)
                run(inp, out)
            except BaseException:  # noqa: BLE001 - a worker never returns into the server loop
                pass
            finally:
                os._exit(0)
        os.close(job_r)
        if workers is not None:
            os.close(err_w)
            workers.add(pid, res_w, err_r)
        else:
            os.close(res_w)
        try:
            sock.send(b"%08d" % pid)
        except OSError:
            return


def main(parent: int, fd: int, run: Callable[[BinaryIO, BinaryIO], None]) -> None:
    """``python -m ramps.runtime.worker --fork-server PARENT_PID SOCKET_FD``:
    ``run`` is what each forked worker runs (``ramps.runtime.worker.run``)."""
    os.dup2(2, 1)  # prints from programs go to stderr, as in any worker
    sys.stdout = sys.stderr
    sock = socket.socket(fileno=fd)
    try:
        serve(sock, parent, run)
    finally:
        sock.close()
