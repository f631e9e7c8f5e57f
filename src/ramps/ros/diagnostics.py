"""A robot's load report as a ROS 2 ``diagnostic_msgs/DiagnosticStatus``:
what ``ramps ros`` publishes on ``/diagnostics`` for each robot of the team
(``ramps.ros.face``), with a level that says whether the robot is well
(OK), left or looks stale or cut off (WARN), or is gone (ERROR)."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

__all__ = ["robot_status"]


def robot_status(r, team_size: int, *, stale_after: float) -> DiagnosticStatus:
    """One robot's load report as a DiagnosticStatus (OK / WARN / ERROR)."""
    s = DiagnosticStatus(name=f"ramps: {r.robot}", hardware_id=r.robot)
    if not r.alive and r.leaving:  # stopped, its programs handed back: not a fault
        s.level, s.message = DiagnosticStatus.WARN, "left the team: its node stopped"
    elif not r.alive:
        s.level, s.message = DiagnosticStatus.ERROR, "gone: not in the team"
    elif r.report_age is None:
        s.level, s.message = DiagnosticStatus.WARN, "alive, no load report yet"
    elif r.report_age > stale_after:
        s.level, s.message = DiagnosticStatus.WARN, f"load report {r.report_age:.1f} s old"
    elif r.blacklisted or (r.sees is not None and r.sees < team_size - 1):
        s.level = DiagnosticStatus.WARN
        s.message = (f"sees {r.sees} of {team_size - 1} teammates" if r.sees is not None and r.sees < team_size - 1
                     else f"wrote off {', '.join(r.blacklisted)}")
    else:
        s.level = DiagnosticStatus.OK
        s.message = f"{r.cpu_busy:.1f}/{r.cores} cores busy, {r.ramps_running} program(s)"
    vals = {"cores": r.cores, "speed": f"{r.speed:g}", "cpu busy": f"{r.cpu_busy:.2f}", "run queue": f"{r.runnable:.2f}",
            "load avg": f"{r.load_avg:.2f}", "programs running": r.ramps_running, "programs done": r.finished_total,
            "programs moved": r.moves, "node cores": f"{r.node_cpu:.2f}", "mem free MiB": r.mem_free // 2**20, "sees": "-" if r.sees is None else r.sees,
            "blacklisted": ",".join(r.blacklisted), "dropped messages": r.bad_messages,
            "report age s": "-" if r.report_age is None else f"{r.report_age:.1f}"}
    s.values = [KeyValue(key=k, value=str(v)) for k, v in vals.items()]
    for i, p in enumerate(r.running):  # what runs there, and how far it is
        s.values.append(KeyValue(key=f"program {i + 1}", value=f"{p.program} from {p.origin}"
                                 + ("" if p.progress is None else f", {100 * p.progress:.0f}%")))
    return s
