"""A persistent pool of batched MuJoCo rollouts with per-candidate models.

Thin layer over ``mujoco.rollout.Rollout``: it keeps the thread pool, one
``MjData`` per thread and a set of ``MjModel`` copies alive between calls, so a
batch of ``B`` parameter candidates costs ``B`` parameter writes and one call
into MuJoCo's C++ thread pool (no GIL). Used by the cost module and the planner.
"""

from __future__ import annotations

import copy
import os

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout


def default_threads() -> int:
    """Threads for rollouts: the CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


class RolloutPool:
    """Batched open-loop rollouts of one model template under many parameter sets.

    Args:
        model: template ``MjModel``; never modified.
        nthread: worker threads (default: all CPUs available).

    Use as a context manager or call :meth:`close`.
    """

    def __init__(self, model: mujoco.MjModel, nthread: int | None = None):
        self.template = model
        self.nthread = nthread or default_threads()
        self._pool = mj_rollout.Rollout(nthread=self.nthread)
        self._datas = [mujoco.MjData(model) for _ in range(self.nthread)]
        self._models: list[mujoco.MjModel] = []
        self.nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)

    def __enter__(self) -> "RolloutPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Shut the thread pool down."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def models(self, n: int) -> list[mujoco.MjModel]:
        """``n`` private model copies (created once, reused; write parameters into them)."""
        while len(self._models) < n:
            self._models.append(copy.copy(self.template))
        return self._models[:n]

    def rollout(self, models: list[mujoco.MjModel], initial_state: np.ndarray, control: np.ndarray,
                nstep: int | None = None) -> np.ndarray:
        """Roll out ``nbatch`` trajectories.

        Args:
            models: length-nbatch list of models (same sizes).
            initial_state: (nbatch, nstate) mjSTATE_FULLPHYSICS states.
            control: (nbatch, nstep, nu) controls; row t drives step t.
            nstep: steps (default: ``control.shape[1]``).

        Returns:
            (nbatch, nstep, nstate) states; row t is the state *after* step t.
            A diverged rollout repeats its last state (MuJoCo's behaviour);
            NaNs are possible and left to the caller.
        """
        if self._pool is None:
            raise RuntimeError("rollout pool is closed")
        nbatch = len(models)
        nstep = control.shape[1] if nstep is None else nstep
        state = np.empty((nbatch, nstep, self.nstate))
        chunk = max(1, nbatch // (self.nthread * 4))
        self._pool.rollout(models, self._datas, np.ascontiguousarray(initial_state),
                           np.ascontiguousarray(control), nstep=nstep, state=state, chunk_size=chunk)
        return state
