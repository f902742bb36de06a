"""A persistent pool of batched MuJoCo rollouts with per-candidate models.

Thin layer over ``mujoco.rollout.Rollout``: it keeps the thread pool, one
``MjData`` per thread and a set of ``MjModel`` copies alive between calls, so a
batch of ``B`` parameter candidates costs ``B`` parameter writes and one call
into MuJoCo's C++ thread pool (no GIL). Used by the cost module (the ``cpu``
rollout backend, :mod:`~amhe_cli.model.device`) and the planner.
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


def edit_each(edit, *models) -> None:
    """``edit(model)`` once on each distinct model of ``models`` (None skipped): a rollout backend's template,
    its copies, and the model its parameter space writes from, which may be one and the same."""
    for m in {id(m): m for m in models if m is not None}.values():
        edit(m)


class RolloutPool:
    """Batched open-loop rollouts of one model template under many parameter sets.

    Args:
        model: template ``MjModel``; never modified but by :meth:`edit_models`.
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

    def edit_models(self, edit, base: mujoco.MjModel | None = None) -> None:
        """Apply ``edit(model)`` (in place) to the template and every model copy, so copies made later carry it
        too: what is not a parameter the candidates write (a robot's servo read mid-run,
        :mod:`~amhe_cli.control.robot_side`). ``base``: the model a
        :class:`~amhe_cli.model.params.ParameterSpace` rewrites its fields from at every write (its scene's),
        edited too where it is not the template."""
        edit_each(edit, base, self.template, *self._models)

    def describe(self) -> str:
        """One line for the device announcement."""
        return f"mujoco.rollout, {self.nthread} threads"

    def rollout_candidates(self, space, P: np.ndarray, initial_state: np.ndarray, control: np.ndarray,
                           horizon: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """Roll every candidate out over every clip: the rollout-backend interface of the cost module.

        Clips of one horizon run as one batch, so no step is simulated twice.

        Args:
            space: the :class:`~amhe_cli.model.params.ParameterSpace` whose
                ``model_fields`` and ``write_fields`` put a candidate into a model.
            P: (B, d) feasible candidates.
            initial_state: (N_c, nstate) mjSTATE_FULLPHYSICS clip starts.
            control: (N_c, H_max, nu) controls; row t drives step t.
            horizon: (N_c,) steps per clip.
        Returns:
            qpos (B, N_c, H_max, nq), qvel (B, N_c, H_max, nv) — row t is the
            state after step t, rows past a clip's horizon repeat its last
            state — and the number of steps simulated.
        """
        P = np.atleast_2d(P)
        B, n = P.shape[0], len(horizon)
        models = self.models(B)
        fields = space.model_fields(P)  # all candidates at once; mj_setConst per model
        for b in range(B):
            space.write_fields(models[b], fields, b)
        m = self.template
        hmax = control.shape[1]
        qpos = np.empty((B, n, hmax, m.nq))
        qvel = np.empty((B, n, hmax, m.nv))
        steps = 0
        for h in np.unique(horizon):
            idx = np.flatnonzero(horizon == h)
            h = int(h)
            batch_models = [models[b] for b in range(B) for _ in idx]
            init = np.tile(initial_state[idx], (B, 1))
            ctrl = np.tile(control[idx, :h], (B, 1, 1))
            state = self.rollout(batch_models, init, ctrl, nstep=h)
            steps += state.shape[0] * h
            state = state.reshape(B, idx.size, h, -1)
            qpos[:, idx, :h] = state[..., 1:1 + m.nq]
            qvel[:, idx, :h] = state[..., 1 + m.nq:1 + m.nq + m.nv]
            qpos[:, idx, h:] = qpos[:, idx, h - 1:h]
            qvel[:, idx, h:] = qvel[:, idx, h - 1:h]
        return qpos, qvel, steps

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
