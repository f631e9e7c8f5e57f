"""Many robots lost at once, on the testbed: how long the survivors stop hearing one another.

How this works: ``hearing_after_mass_loss`` makes a testbed of ``robots``
robots (1 core each) whose nodes trace every message they receive
(``RAMPS_TRACE_WIRE``), cuts off or crashes the last ``lose`` of them at
once, and reads from the survivors' traces, per pair of survivors, the
longest gap in hearing one another within ``window`` seconds, and whom
survivors wrongly wrote off.

    sudo .venv/bin/python -m ramps.lab.mass_loss 8 5 cut mass-cut.json   # ROBOTS LOSE cut|crash [OUT.json]
"""

from __future__ import annotations

import os
import time

from ramps.testbed import Testbed


def hearing_after_mass_loss(robots: int = 8, lose: int = 5, window: float = 9.0, how: str = "cut",
                            settle: float = 4.0, log=print) -> dict:
    """A testbed of ``robots`` (1 core each); ``lose`` of them (the last ones)
    are cut off (``how="cut"``: link down) or crashed at once. For ``window``
    seconds after, every survivor's trace of received messages (the nodes run
    with RAMPS_TRACE_WIRE) gives, per pair of survivors, the longest gap in
    hearing one another (Zenoh closing many links at once, SO_LINGER on a
    receive thread, can make survivors deaf for up to 10 s). Returns the
    gaps and the survivors' peer_lost events."""
    import json as _json

    os.environ["RAMPS_TRACE_WIRE"] = "1"
    names = [f"r{i}" for i in range(1, robots + 1)]
    survivors, lost = names[:robots - lose], names[robots - lose:]

    def trace(tb, robot: str) -> list[dict]:
        try:
            return [_json.loads(x) for x in (tb.log_dir / f"{robot}.trace.jsonl").read_text().splitlines() if x]
        except OSError:
            return []

    with Testbed(names, cores=1) as tb:
        time.sleep(settle)
        t_cut = time.monotonic()
        for r in lost:
            (tb.cut if how == "cut" else tb.crash)(r)
        took = time.monotonic() - t_cut
        time.sleep(window)
        gaps: dict[str, float] = {}
        for rcv in survivors:
            tr = trace(tb, rcv)
            for snd in survivors:
                if snd == rcv:
                    continue
                heard = sorted(e["t"] for e in tr if e["what"] == "rx" and e["other"] == snd
                               and t_cut <= e["t"] <= t_cut + window)
                edges = [t_cut, *heard, t_cut + window]
                gaps[f"{snd}->{rcv}"] = round(max(b - a for a, b in zip(edges, edges[1:])), 3)
        wrongly_lost = sorted({f"{rcv} lost {e['other']}" for rcv in survivors for e in trace(tb, rcv)
                               if e["what"] == "peer_lost" and e["other"] in survivors})
    out = {"robots": robots, "lost": lose, "how": how, "window_s": window, "inject_s": round(took, 3),
           "max_gap_s": max(gaps.values()) if gaps else None, "gaps_s": gaps, "survivors_lost": wrongly_lost}
    log(f"{lose} of {robots} robots {how} at once (in {took:.2f} s): longest silence between survivors "
        f"{out['max_gap_s']} s; survivors written off by survivors: {wrongly_lost or 'none'}")
    return out


if __name__ == "__main__":  # python -m ramps.lab.mass_loss [ROBOTS LOSE cut|crash [OUT.json]]
    import json
    import sys

    a = sys.argv[1:]
    res = hearing_after_mass_loss(int(a[0]) if a else 8, int(a[1]) if len(a) > 1 else 5,
                                  how=a[2] if len(a) > 2 else "cut")
    if len(a) > 3:
        with open(a[3], "w") as f:
            json.dump(res, f, indent=1)
