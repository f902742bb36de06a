"""amhe: sampling-based system identification and adaptive MPC for legged loco-manipulation."""

__version__ = "0.1.0"
