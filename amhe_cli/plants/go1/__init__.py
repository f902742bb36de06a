"""The real Go1 plant: low-level UDP link, relay and safety layer, state estimation, motion capture, emulator."""
