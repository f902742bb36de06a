"""Plants the closed loop drives: the MuJoCo sim plant (and, behind the same interface, a real Go1)."""
