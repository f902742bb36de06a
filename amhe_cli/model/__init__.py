"""The model: scene (MJCF + box + floor), physical parameters, and the rollout pool."""
