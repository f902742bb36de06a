"""Where the box moved under a leg alone: what the MHE's line decisions wait out, per recording.

For each recording (an ``amhe run`` MCAP, or any log ``load_problem`` reads) it prints the seconds of clip starts
at which the box moved (0.2 s clips, beyond the log's pose noise: ``estimation.clips.moving_starts``), how many of
them a leg alone touched the box in (``estimation.clips.leg_only_touch``: the trunk off it), and the stretches
of those, merged where less than 0.5 s apart, each with the run's messages inside it ("lost the box, walking back
behind it", "too near the box to turn on the spot, …", a reflex's recovery): which manoeuvre kicks the box. A
gait that keeps its feet off the box there would give the MHE data where it now waits
(``estimation.mhe.held_by_legs``; docs/evaluation.md "A leg on the box is not a push").

    python benchmarks/leg_contacts.py REC.mcap [REC.mcap ...] [--json]
"""

from __future__ import annotations

import argparse
import json
import re
import warnings

import numpy as np

#: a run-log message with its run time (closed_loop.run_task's warnings)
STAMPED = re.compile(r"^t=([0-9.]+) s: (.*)$")
#: leg-alone starts this close [s] belong to one stretch
MERGE = 0.5


def stretches(t: np.ndarray) -> list[tuple[float, float]]:
    """Sorted times ``t`` [s] merged into (start, end) stretches where consecutive ones are under :data:`MERGE`
    apart."""
    if not t.size:
        return []
    cut = np.flatnonzero(np.diff(t) >= MERGE)
    first = np.r_[0, cut + 1]
    last = np.r_[cut, t.size - 1]
    return [(float(t[a]), float(t[b])) for a, b in zip(first, last)]


def run_messages(path: str) -> list[tuple[float, str]]:
    """The recording's run-log messages that carry a run time (``amhe_run_log`` metadata), as (t [s], text)."""
    from mcap.reader import make_reader
    out = []
    try:
        with open(path, "rb") as fh:
            for m in make_reader(fh).iter_metadata():
                if m.name == "amhe_run_log":
                    for text in m.metadata.values():
                        hit = STAMPED.match(text)
                        if hit:
                            out.append((float(hit.group(1)), hit.group(2)))
    except Exception:  # not an MCAP, or no run log: the stretches alone
        return []
    return sorted(out)


def measure(path: str) -> dict:
    """The recording's moving and leg-alone clip starts [s] and its leg-alone stretches with their messages."""
    from amhe_cli.estimation.clips import leg_only_touch, moving_starts, rest_travel
    from amhe_cli.estimation.identify import clip_plan
    from amhe_cli.estimation.problem import load_problem
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pr = load_problem(path)
    traj, scene = pr.traj, pr.scene
    _, horizon, _ = clip_plan(traj)
    hi = int(round(horizon[1] / traj.dt))
    _, active, _ = moving_starts(traj, hi, None, 0.02, rest_travel(traj))
    moving = np.flatnonzero(active)
    alone = moving[leg_only_touch(traj, scene, moving, hi)] if moving.size else moving
    msgs = run_messages(path)
    spans = [{"from": round(a, 2), "to": round(b + hi * traj.dt, 2),
              "messages": [m for tm, m in msgs if a - 1.0 <= tm <= b + hi * traj.dt]}
             for a, b in stretches(traj.t[alone])]
    return {"log": path, "duration_s": round(float(traj.t[-1] - traj.t[0]), 2),
            "moving_s": round(moving.size * traj.dt, 2), "leg_alone_s": round(alone.size * traj.dt, 2),
            "stretches": spans}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--json", action="store_true", help="one JSON line per recording instead of the text")
    a = ap.parse_args()
    for path in a.logs:
        r = measure(path)
        if a.json:
            print(json.dumps(r), flush=True)
            continue
        share = r["leg_alone_s"] / r["moving_s"] if r["moving_s"] else float("nan")
        print(f"{path}: {r['duration_s']:.1f} s, the box moving at {r['moving_s']:.1f} s of clip starts, "
              f"a leg alone on it at {r['leg_alone_s']:.1f} s ({100 * share:.0f} %), {len(r['stretches'])} stretches")
        for s in r["stretches"]:
            said = "; ".join(dict.fromkeys(s["messages"])) or "-"
            print(f"  {s['from']:6.2f}-{s['to']:6.2f} s  {said[:160]}")


if __name__ == "__main__":
    main()
