"""Estimation: clips, the one rollout-matching cost module, identify (CMA-ES), MHE, uncertainty, belief, probe."""
