"""Plain Python values (dicts, lists, floats) from numpy ones, for YAML, JSON and MCAP metadata."""

from __future__ import annotations

import numpy as np


def to_plain(v):
    """numpy scalars and arrays (also inside dicts and lists) -> plain Python, for YAML/JSON."""
    if isinstance(v, dict):
        return {k: to_plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return to_plain(v.tolist())
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return v.item()
    return v
