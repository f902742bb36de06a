"""Ground truth that logs amhe simulates carry inside them (an MCAP metadata record)."""

from __future__ import annotations

import json

from amhe_cli.io.trajectory import Trajectory

#: Metadata record holding the ground truth of logs amhe simulates.
TRUTH_RECORD = "amhe_truth"


def metadata_truth(traj: Trajectory) -> dict | None:
    """Ground truth a log amhe simulated carries (record :data:`TRUTH_RECORD`): name -> value, else None."""
    rec = traj.meta.get("metadata", {}).get(TRUTH_RECORD)
    if not rec:
        return None
    out = {}
    for k, v in rec.items():
        try:
            out[k] = json.loads(v) if isinstance(v, str) else v
        except json.JSONDecodeError:
            continue
    return out
