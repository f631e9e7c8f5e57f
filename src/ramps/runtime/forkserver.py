"""The executor's fork server: new worker processes in milliseconds.

How this works: the worker pool (``ramps.runtime.workers``) starts one
``python -m ramps.runtime.worker --fork-server`` per node. It imports the
registered programs' modules once, then waits on a Unix socket. For each new
worker the pool sends the worker's two pipe ends (``SCM_RIGHTS``); the
server forks, and the child becomes an ordinary worker
(``ramps.runtime.worker.run`` over those pipes, the same frames, nothing
pickled). The pool gets the child's pid back.

Why: booting ``python -m ramps.runtime.worker`` and importing the registry
costs about 0.2 s of CPU, which on a robot emulated at 0.08 of a host core per
core made programs beyond one per core start 2.5-4.5 s late. A fork of the
warmed server costs a few milliseconds. The server is single-threaded and
has no Zenoh session, so forking it is safe (the node, which has Zenoh's
threads, never forks a worker itself).

Death: the server and every worker ask the kernel (``PR_SET_PDEATHSIG``) for
SIGKILL when their parent dies, and check that it has not already. A node
killed alone (SIGKILL of its process only) takes its fork server with it,
and the server its workers, at once: work is never left running that nobody
will collect. Workers are reaped by the server (SIGCHLD ignored there, reset
to the default in each worker so programs can wait for their own children).

Protocol on the socket (SOCK_SEQPACKET, one message each way per fork):
pool -> server ``b"fork"`` with fds [job_read, result_write]; server -> pool
the child's pid as 8 ASCII digits. Anything else ends the server.
"""

from __future__ import annotations

import ctypes
import os
import signal
import socket
import sys

PR_SET_NAME = 15
PR_SET_PDEATHSIG = 1


def _prctl(option: int, arg) -> None:
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


def _preload(targets: dict[str, str]) -> None:
    """Import every program's module now, so a forked worker has it; a module
    that fails here fails again, with its error, when its program runs."""
    from ramps.runtime.registry import resolve

    for target in targets.values():
        try:
            resolve(target)
        except BaseException:  # noqa: BLE001 - reported when the program runs
            pass


def serve(sock: socket.socket, parent: int) -> None:
    from ramps.runtime import worker

    die_with_parent(parent)
    name_process(b"ramps-forksrv")
    init = sock.recv(1 << 20)
    if not init:
        return
    targets = worker._dec.decode(init)["targets"]
    _preload(targets)
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # the kernel reaps the workers
    me = os.getpid()
    while True:
        try:
            msg, fds, _, _ = socket.recv_fds(sock, 64, 2)
        except (OSError, KeyboardInterrupt):
            return
        if msg != b"fork" or len(fds) != 2:
            for fd in fds:
                os.close(fd)
            return
        job_r, res_w = fds
        pid = os.fork()
        if pid == 0:  # the new worker
            try:
                sock.close()
                signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                die_with_parent(me)
                name_process(b"ramps-worker")
                inp = os.fdopen(job_r, "rb", buffering=0)
                out = os.fdopen(res_w, "wb", buffering=0)
                worker.run(inp, out)
            except BaseException:  # noqa: BLE001 - a worker never returns into the server loop
                pass
            finally:
                os._exit(0)
        os.close(job_r)
        os.close(res_w)
        try:
            sock.send(b"%08d" % pid)
        except OSError:
            return


def main(parent: int, fd: int) -> None:
    """``python -m ramps.runtime.worker --fork-server PARENT_PID SOCKET_FD``."""
    os.dup2(2, 1)  # prints from programs go to stderr, as in any worker
    sys.stdout = sys.stderr
    sock = socket.socket(fileno=fd)
    try:
        serve(sock, parent)
    finally:
        sock.close()
