"""Clips: short pieces of a recorded trajectory that the cost rolls out and matches.

A clip ``c_k`` (paper eq. 1) is a recorded initial state ``x^r_{0,k}``, the
recorded controls ``u^r_{0..H-1,k}`` and the recorded states
``x^r_{1..H,k}`` to compare against. ``identify`` draws ``N_c`` clips with
horizons uniform in a range (SPI, paper §III-B); the MHE tiles its window with
consecutive clips (or one clip covering the whole window).

Where clips start matters more than how many there are: a resting box says
nothing about its mass or friction, so starts are drawn with probability
proportional to how much the box moves and is pushed around them (docs/reference.md#identification:
the mass shows only during robot–box bumps, free sliding pins down μ).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.io.quat import quat_relative_rotvec
from amhe_cli.io.smoothing import CLEAN_SIGMA, CLEAN_SIGMA_ROT, pose_noise
from amhe_cli.model.scene import Scene
from amhe_cli.io.trajectory import Trajectory

ROLES = ("base", "joint_states", "box")


@dataclass
class Clips:
    """A batch of ``N_c`` clips, padded to the longest horizon ``H_max``.

    Attributes:
        start: (N_c,) index of each clip's initial state in the trajectory.
        horizon: (N_c,) number of steps ``H_k`` rolled out.
        initial_state: (N_c, nstate) mjSTATE_FULLPHYSICS initial states.
        control: (N_c, H_max, nu) recorded controls ``u^r_t`` (step t uses row t).
        qpos: (N_c, H_max, nq) recorded states ``x^r_{t+1}`` (row t = after step t).
        qvel: (N_c, H_max, nv).
        observed: (N_c, H_max, 3) bool, per role in :data:`ROLES`, whether
            the recorded state at that step was measured (False in gaps and
            in padding beyond ``H_k``).
        dt: model timestep [s].
    """

    start: np.ndarray
    horizon: np.ndarray
    initial_state: np.ndarray
    control: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    observed: np.ndarray
    dt: float

    def __len__(self) -> int:
        return int(self.start.shape[0])

    def subset(self, index) -> "Clips":
        """The clips at ``index`` (an index array or boolean mask over the ``N_c`` clips), padding kept."""
        return Clips(self.start[index], self.horizon[index], self.initial_state[index], self.control[index],
                     self.qpos[index], self.qvel[index], self.observed[index], self.dt)

    @property
    def steps(self) -> int:
        """Total simulated steps for one candidate: sum of horizons."""
        return int(self.horizon.sum())


def make_clips(traj: Trajectory, scene: Scene, starts, horizons) -> Clips:
    """Cut clips at ``starts`` (N_c,) with ``horizons`` (N_c,) steps out of ``traj``.

    The trajectory grid must equal the model timestep.

    Raises:
        AmheError: a clip runs past the end of the trajectory, or the grid
            spacing differs from the model timestep.
    """
    starts = np.asarray(starts, dtype=int)
    horizons = np.asarray(horizons, dtype=int)
    if abs(traj.dt - scene.model.opt.timestep) > 1e-9:
        raise AmheError(f"trajectory grid {traj.dt} s differs from the model timestep {scene.model.opt.timestep} s")
    if starts.size == 0:
        raise AmheError("no clips: the trajectory has no usable window")
    if np.any(starts < 0) or np.any(starts + horizons >= len(traj)) or np.any(horizons < 1):
        raise AmheError(f"clip beyond the trajectory ({len(traj)} samples)")
    qpos_all, qvel_all = scene.qpos_qvel(traj)
    hmax = int(horizons.max())
    n = len(starts)
    nu = scene.model.nu
    control = np.zeros((n, hmax, nu))
    qpos = np.zeros((n, hmax, scene.model.nq))
    qvel = np.zeros((n, hmax, scene.model.nv))
    observed = np.zeros((n, hmax, len(ROLES)), dtype=bool)
    roles = [traj.observed.get(r, np.ones(len(traj), dtype=bool)) for r in ROLES]
    for k, (s, h) in enumerate(zip(starts, horizons)):
        control[k, :h] = traj.ctrl[s:s + h]
        control[k, h:] = traj.ctrl[s + h - 1]
        qpos[k, :h] = qpos_all[s + 1:s + h + 1]
        qvel[k, :h] = qvel_all[s + 1:s + h + 1]
        qpos[k, h:] = qpos_all[s + h]
        qvel[k, h:] = qvel_all[s + h]
        for j, mask in enumerate(roles):
            observed[k, :h, j] = mask[s + 1:s + h + 1]
    initial = scene.full_state(qpos_all[starts], qvel_all[starts], time=traj.t[starts])
    return Clips(starts, horizons, initial, control, qpos, qvel, observed, float(traj.dt))


def join_clips(traj: Trajectory, scene: Scene, *parts: Clips) -> tuple[Clips, list[np.ndarray]]:
    """The clips of ``parts`` (each cut from ``traj``) as one batch in time order, padded to the longest horizon:
    ``(clips, index)``, ``index[i]`` the positions (n_i,) of part ``i``'s clips in it."""
    starts = np.concatenate([p.start for p in parts])
    horizons = np.concatenate([p.horizon for p in parts])
    order = np.argsort(starts, kind="stable")
    position = np.empty_like(order)
    position[order] = np.arange(order.size)
    bounds = np.cumsum([0] + [len(p) for p in parts])
    return (make_clips(traj, scene, starts[order], horizons[order]),
            [position[a:b] for a, b in zip(bounds[:-1], bounds[1:])])


#: Lever arm [m] that turns the box's yaw rate into a speed in :func:`excitation` and :func:`box_travel`
#: (half the edge of the default 0.38 m box: how fast its sides move when it turns).
LEVER = 0.19


def excitation(traj: Trajectory, window: int) -> np.ndarray:
    """(T,) how informative a clip starting at each sample is likely to be.

    Box speed [m/s] plus box speed change over ``window`` samples, maxed over
    the window that follows: high where the box is pushed or slides, zero where
    it rests.
    """
    speed = np.linalg.norm(traj.box_linvel[:, :2], axis=1) + LEVER * np.abs(traj.box_angvel[:, 2])
    change = np.abs(np.roll(speed, -window) - speed)
    change[-window:] = 0.0
    score = speed + change
    # max over the following window (sliding max via cumulative strides)
    pad = np.concatenate([score, np.zeros(window)])
    win = np.lib.stride_tricks.sliding_window_view(pad, window + 1)[: len(score)]
    return win.max(axis=1)


def moving_starts(traj: Trajectory, hi: int, t_range=None, min_speed: float = 0.02,
                  min_travel: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clip starts over ``hi`` samples, as :func:`sample_clips` takes them.

    Returns:
        (usable, active, score): (T,) bool starts whose whole clip is observed (and inside ``t_range``
        [s]); (T,) bool those of them whose :func:`excitation` is above ``min_speed`` [m/s] and over whose
        ``hi`` samples the box went further than ``min_travel`` [m]; (T,) the excitation.
    Raises:
        AmheError: no observed stretch is long enough for one clip.
    """
    usable = _usable_starts(traj, hi, t_range)
    score = excitation(traj, hi)
    active = usable & (score > min_speed)
    if min_travel > 0:
        idx = np.flatnonzero(active)
        active[idx[box_travel(traj, idx, np.full(idx.size, hi)) <= min_travel]] = False
    return usable, active, score


class ClipsHeld(AmheError):
    """:func:`sample_clips`' ``hold`` held the draw back."""


def sample_clips(traj: Trajectory, scene: Scene, n_clips: int, horizon_range=(0.1, 0.2),
                 rng: np.random.Generator | None = None, t_range=None, min_speed: float = 0.02,
                 min_travel: float = 0.0, candidates: int = 1, hold=None) -> Clips:
    """Draw ``n_clips`` clips for SPI-style identification (paper §III-B).

    Horizons are uniform in ``horizon_range`` [s] (rounded to model steps);
    starts are drawn without replacement with probability proportional to
    :func:`excitation`, among starts whose whole clip is observed and, if
    given, inside ``t_range = (t0, t1)`` [s]. Where the box moves faster than
    ``min_speed`` [m/s] somewhere in the clip only those starts are used.
    Where fewer than ``n_clips`` such starts exist, the clips are drawn from
    all observed starts and a warning says so: clips of a box at rest tell
    nothing of its mass or friction, so the estimate stays near the prior.
    Starts over whose longest horizon the box goes no further than
    ``min_travel`` [m] (:func:`rest_travel`: what pose noise alone moves a
    resting box) count as at rest (:func:`moving_starts`). ``candidates`` > 1 draws that many times
    ``n_clips`` (as many as there are) for :func:`choose_informative` to choose from. ``hold``, a callable
    ``(moving starts, longest horizon [samples]) -> bool`` (e.g. :func:`legs_hold`), holds the draw back where
    True, before anything is drawn.

    Raises:
        ClipsHeld: ``hold`` held it.
        AmheError: no observed stretch is long enough for one clip.
    """
    rng = rng or np.random.default_rng(0)
    lo, hi = _horizon_steps(traj, horizon_range)
    usable, active, score = moving_starts(traj, hi, t_range, min_speed, min_travel)
    if hold is not None and hold(np.flatnonzero(active), hi):
        raise ClipsHeld("the draw was held")
    if active.sum() < n_clips:
        where = "in the log" if t_range is None else f"in {t_range[0]:g}-{t_range[1]:g} s of the log"
        warnings.warn(f"the box moves faster than {min_speed:g} m/s {where} at only {int(active.sum())} clip "
                      f"starts, fewer than the {n_clips} clips asked for: clips of a box at rest tell nothing of "
                      "its mass or friction, so the estimate stays near the prior (give a log, or --t-range, "
                      "where the robot pushes the box)", stacklevel=2)
    pool = np.flatnonzero(active if active.sum() >= n_clips else usable)
    weight = score[pool] + 1e-3
    k = min(n_clips * max(int(candidates), 1), pool.size)
    starts = np.sort(rng.choice(pool, size=k, replace=False, p=weight / weight.sum()))
    horizons = rng.integers(lo, hi + 1, size=k)
    return make_clips(traj, scene, starts, horizons)


def sample_rest_clips(traj: Trajectory, scene: Scene, n_clips: int, horizon_range=(0.1, 0.2),
                      rng: np.random.Generator | None = None, t_range=None) -> Clips | None:
    """Draw up to ``n_clips`` clips in which the box rests: the robot's own motion, for robot-side parameters.

    A start counts when the box goes no further over the longest horizon than
    pose noise alone moves a resting box (:func:`rest_travel`, at least
    :data:`REST_FLOOR`) and the robot stays out of the box's reach
    (:func:`robot_box_clear`): a robot leaning on a box that does not move
    would otherwise be read with the prior's box, which may slide in the
    rollout (``mass_switch``, a robot that is its model, read a payload of
    0.41 ± 0.01 kg without this). Starts are drawn uniformly without
    replacement; horizons uniform in ``horizon_range`` [s].

    Returns:
        the clips, or None where no start qualifies.
    Raises:
        AmheError: no observed stretch is long enough for one clip.
    """
    rng = rng or np.random.default_rng(0)
    lo, hi = _horizon_steps(traj, horizon_range)
    pool = np.flatnonzero(_usable_starts(traj, hi, t_range))
    pool = pool[box_travel(traj, pool, np.full(pool.size, hi)) <= max(rest_travel(traj), REST_FLOOR)]
    pool = pool[robot_box_clear(traj, scene, pool, hi)]
    if pool.size == 0:
        return None
    k = min(n_clips, pool.size)
    starts = np.sort(rng.choice(pool, size=k, replace=False))
    return make_clips(traj, scene, starts, rng.integers(lo, hi + 1, size=k))


#: The farthest any part of the Go1 reaches from its trunk origin in the horizontal plane [m]: the head
#: plate at 0.28 m, a swinging front foot a little beyond, and a margin. Beyond it plus half the box's
#: horizontal diagonal the robot cannot touch the box, and no geometry is computed.
ROBOT_REACH = 0.4
#: Nearer, the robot's geoms must stay this far [m] from the box's (:meth:`Scene.robot_box_gap`) at every
#: sample checked (every 10th): a swinging foot moves 2–4 cm in 10 samples of 2 ms.
CLEAR_GAP = 0.05
#: The gap is computed on every this many samples (:func:`robot_box_clear`).
GAP_STRIDE = 5
#: A leg nearer the box than this [m] at a :data:`GAP_STRIDE`-th sample touches it (:func:`leg_only_touch`):
#: a foot swinging at 0.5 m/s covers it between two checked samples.
LEG_GAP = 0.005
#: The trunk nearer the box than this [m] pushes it: a pushing head plate sits within 3 mm of the box as
#: recorded (2.7 mm inside it at most on emulated T4 runs through 1 mm motion capture), and noise adds a few.
TRUNK_PUSH = 0.01
#: A change test or line decision waits where a leg alone touched the box in more than this many times as many of
#: its span's moving clip starts as it did not, however many clean ones it holds (:func:`legs_hold`). An emulated T3
#: run's late span, the robot stepping round the box, held 0.16 s of clean moving starts (past
#: :data:`~amhe_cli.estimation.attribution.MOVING_MIN`) against 1.03 s of a leg's alone (87 %), and read a change
#: that was not there, in the loop and replayed; the 2 s after T3's switch held 0–16 % on five recordings. Replayed
#: (``amhe mhe-replay``) on 19 emulated T3/T4 recordings, it dropped that change and decided nothing else otherwise
#: (docs/evaluation.md "A change its data do not show is closed…").
LEGS_OUTNUMBER = 2


def _gap_index(traj: Trajectory, starts: np.ndarray, hi: int, every: int) -> np.ndarray:
    """(N, K) the log samples a gap is read at for the clips from ``starts`` over ``hi`` samples: every
    ``every``-th sample of each (and its last), each on the nearest :data:`GAP_STRIDE`-th sample of the log (a
    foot moves under a centimetre in 4 ms: a fifth of the ``mj_geomDistance`` calls, and most of a check's
    time)."""
    offsets = np.unique(np.r_[np.arange(0, hi + 1, every), hi])
    return np.minimum(np.round((starts[:, None] + offsets[None]) / GAP_STRIDE).astype(int) * GAP_STRIDE,
                      (len(traj) - 1) // GAP_STRIDE * GAP_STRIDE)


def _gaps(traj: Trajectory, scene: Scene, samples: np.ndarray, part: str) -> np.ndarray:
    """(T,) robot–box gaps [m] of ``part`` (:meth:`~amhe_cli.model.scene.Scene.robot_box_gap`) at the log's
    ``samples``; ``inf`` elsewhere, and where the trunk origin is farther from the box's centre than
    :data:`ROBOT_REACH` plus half the box's horizontal diagonal."""
    reach = ROBOT_REACH + 0.5 * float(np.hypot(*scene.config.box_size[:2]))
    need = np.unique(samples)
    near = need[np.linalg.norm(traj.base_pos[need, :2] - traj.box_pos[need, :2], axis=1) <= reach]
    dist = np.full(len(traj), np.inf)
    if near.size:
        dist[near] = scene.robot_box_gap(scene.qpos_qvel(traj, near)[0], part=part)
    return dist


def robot_box_clear(traj: Trajectory, scene: Scene, starts: np.ndarray, hi: int) -> np.ndarray:
    """(N,) bool: the robot cannot touch the box anywhere in the clips from ``starts`` over ``hi`` samples.

    At every 10th sample (and the last) either the trunk origin is farther than :data:`ROBOT_REACH`
    plus half the box's horizontal diagonal from the box's centre, or the robot's geoms, posed as
    recorded, are at least :data:`CLEAR_GAP` from the box (:meth:`~amhe_cli.model.scene.Scene.robot_box_gap`).
    The radius alone takes a robot walking up to the box, or round it, as touching it: on an emulated
    run's recording (T1, a Go1 1.5 kg heavier than its model) it left fewer clips than a fit needs, and
    the robot was read as its model.
    """
    starts = np.asarray(starts, dtype=int)
    if starts.size == 0:
        return np.zeros(0, dtype=bool)
    index = _gap_index(traj, starts, hi, 10)
    return (_gaps(traj, scene, index, "robot")[index] > CLEAR_GAP).all(axis=1)


def leg_only_touch(traj: Trajectory, scene: Scene, starts: np.ndarray, hi: int) -> np.ndarray:
    """(N,) bool: in the clip from each of ``starts`` over ``hi`` samples a leg touches the box (nearer than
    :data:`LEG_GAP`) at a checked sample (every :data:`GAP_STRIDE`-th) where the trunk does not push it (no
    nearer than :data:`TRUNK_PUSH`): a kick, or a foot standing against the box.

    Such a contact is the model's least trustworthy (its soft foot spheres sit up to 12 mm inside the box on a
    clean lock-step recording, 20 mm on an emulated run's, where a pushing trunk sits within 3 mm) and, a kick
    being over before friction matters, it reads as inertia alone. A foot touching the box beside a pushing
    trunk (a front foot striking the box's face each stride of a push) does not count: the push carries the
    box; as a leg's alone, with the trunk a centimetre off the box, count up to two thirds of a window's clips at
    T3's switch on emulated runs, which is why they gate a decision rather than leave it
    (:func:`~amhe_cli.estimation.mhe.decision_clips`).
    """
    starts = np.asarray(starts, dtype=int)
    if starts.size == 0:
        return np.zeros(0, dtype=bool)
    index = _gap_index(traj, starts, hi, GAP_STRIDE)
    touch = _gaps(traj, scene, index, "legs")[index] <= LEG_GAP
    if not touch.any():
        return touch.any(axis=1)
    # the trunk's gap only where a leg touches
    return (touch & (_gaps(traj, scene, index[touch], "trunk")[index] > TRUNK_PUSH)).any(axis=1)


def legs_hold(traj: Trajectory, scene: Scene, moving: np.ndarray, hi: int, need: float) -> bool:
    """Whether a leg alone touched the box (:func:`leg_only_touch`) in some of the clips from the ``moving`` starts
    (sample indices, clips of ``hi`` samples) while the others number fewer than ``need``, or fewer than
    1/:data:`LEGS_OUTNUMBER` of the leg's. The newest starts are read first, a chunk at a time, until ``need`` of
    them are clean and the rest could not outnumber them so: a push's span is read in a third of its chunks."""
    moving = np.asarray(moving, dtype=int)
    clean, alone, read = 0, 0, 0
    for chunk in np.array_split(moving[::-1], max(1, int(np.ceil(moving.size / (2 * need))))):
        legs = leg_only_touch(traj, scene, chunk, hi)
        clean, alone, read = clean + int((~legs).sum()), alone + int(legs.sum()), read + chunk.size
        if clean >= need and LEGS_OUTNUMBER * clean >= alone + (moving.size - read):
            return False
    return alone > 0 and (clean < need or alone > LEGS_OUTNUMBER * clean)


def _horizon_steps(traj: Trajectory, horizon_range) -> tuple[int, int]:
    """(lo, hi) clip horizon [model steps] of a ``(min, max)`` range [s]."""
    lo, hi = (int(round(h / traj.dt)) for h in horizon_range)
    lo = max(lo, 1)
    return lo, max(hi, lo)


def _usable_starts(traj: Trajectory, hi: int, t_range=None) -> np.ndarray:
    """(T,) bool: starts ``s`` whose samples ``s..s+hi`` are all observed (and inside ``t_range`` [s]).

    Raises:
        AmheError: there is none.
    """
    bad = np.concatenate([[0], np.cumsum(~traj.valid())])
    usable = np.zeros(len(traj), dtype=bool)
    last = len(traj) - hi - 1
    if last > 0:
        s = np.arange(last)
        usable[:last] = (bad[s + hi + 1] - bad[s]) == 0
    if t_range is not None:
        usable &= (traj.t >= t_range[0]) & (traj.t + hi * traj.dt <= t_range[1])
    if not usable.any():
        raise AmheError(f"no stretch of the log is {hi * traj.dt:.2f} s long without gaps: "
                        "expected at least one clip's worth of continuous data")
    return usable


def choose_informative(info: np.ndarray, n_clips: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``n_clips`` clips drawn, without replacement, by how much they inform.

    Args:
        info: (N, n_params) each candidate clip's information about each free
            parameter (:func:`~amhe_cli.estimation.uncertainty.clip_information`).
        n_clips: how many to keep (all N if fewer).
        rng: the draw's generator.

    Each clip's weight is its share of every parameter's total information,
    summed over the parameters, so a parameter that few clips inform (the mass:
    only the robot–box bumps) keeps those clips next to the many that inform
    another (the friction: every slide). *Why*: a handful of clips carries most
    of the information (on ``noisy_b`` the top 10 % of 160 clips held 70 % of
    the mass curvature), so 32 clips drawn by box motion alone differ from seed
    to seed in which bumps they hold, and the estimate with them: mass ± 5–6 %
    over seeds on the shared noisy and mismatched logs, where CMA-ES's own path
    on one fixed clip set moved it by ± 0.9–1.9 %.

    Returns:
        (min(n_clips, N),) sorted indices.
    """
    info = np.nan_to_num(np.asarray(info, dtype=float), nan=0.0, posinf=0.0)
    n = info.shape[0]
    if n <= n_clips:
        return np.arange(n)
    total = info.sum(axis=0)
    share = np.where(total > 0, info / np.where(total > 0, total, 1.0), 0.0).sum(axis=1)
    weight = share + 1e-3 * max(share.mean(), 1e-12)  # every clip keeps a chance
    return np.sort(rng.choice(n, size=n_clips, replace=False, p=weight / weight.sum()))


def box_travel(traj: Trajectory, starts: np.ndarray, horizons: np.ndarray) -> np.ndarray:
    """(N,) how far the box went over each clip [m]: its centre's net horizontal displacement plus
    :data:`LEVER` × the angle it turned, from sample ``starts`` to ``starts + horizons``."""
    a, b = np.asarray(starts), np.asarray(starts) + np.asarray(horizons)
    shift = np.linalg.norm(traj.box_pos[b, :2] - traj.box_pos[a, :2], axis=1)
    return shift + LEVER * np.linalg.norm(quat_relative_rotvec(traj.box_quat[a], traj.box_quat[b]), axis=1)


#: A box that goes no further than this over a clip counts as at rest on a clean log [m] (2 mm in 0.2 s:
#: 1 cm/s, below the 2 cm/s that counts as moving).
REST_FLOOR = 0.002

#: A clip counts as the box at rest unless the box went this many standard deviations of the pose noise
#: further than a resting box appears to (:func:`rest_travel`).
REST_SIGMAS = 4.0


def rest_travel(traj: Trajectory) -> float:
    """How far [m] a box at rest appears to go over a clip, by the log's measured pose noise (0 if clean).

    :data:`REST_SIGMAS` × √2 × the pose noise as read
    (:func:`~amhe_cli.io.smoothing.pose_noise`; position and :data:`LEVER` ×
    orientation): the difference of two noisy poses. On ``noisy_b`` (1 mm /
    0.2° at 120 Hz, smoothed over 58 ms) it is 4.3 mm, and without it windows
    of the box at rest from 1 s on counted as informative: the MHE fitted the
    noise, and its friction fell to 0.36 where the truth is 0.55 before the
    robot had touched the box.
    """
    pos, rot = pose_noise(traj.meta, "box", traj.dt)
    if pos <= CLEAN_SIGMA and rot <= CLEAN_SIGMA_ROT:  # what the reader takes for no noise
        return 0.0
    return float(REST_SIGMAS * np.sqrt(2.0) * np.hypot(pos, LEVER * rot))


def window_clips(traj: Trajectory, scene: Scene, start: int, stop: int, clip_steps: int | None,
                 max_steps: int | None = None, min_speed: float = 0.0, min_travel: float = 0.0) -> Clips | None:
    """The clips of an estimation window, samples ``start`` to ``stop`` (exclusive).

    The window is tiled with consecutive clips of ``clip_steps`` steps, each
    reset to the recorded state (multiple shooting), or rolled out in one piece
    with ``clip_steps=None`` (the paper's eq. 4). Clips that cross a gap, whose
    :func:`excitation` is not above ``min_speed`` [m/s], or over which the box
    went no further than ``min_travel`` [m] (:func:`box_travel`: a box at rest
    under motion-capture noise reads a speed but goes nowhere) are dropped; of
    the rest, the most excited are kept up to ``max_steps`` simulated steps, and
    where what is left of the budget is at least half a clip, the next most
    excited clip cut to it (motion capture's 95-step clips left 55 of the MHE's
    150 unspent: *measured*, ``benchmarks/mhe_accuracy.py``, docs/evaluation.md).

    Returns:
        the :class:`Clips`, or None when the window holds nothing informative.
    """
    if stop - start < 2:
        return None
    length = stop - 1 - start
    step = length if clip_steps is None else max(1, min(clip_steps, length))
    starts = np.arange(start, stop - 1, step)
    horizons = np.minimum(step, stop - 1 - starts)
    valid = traj.valid()
    keep = np.array([valid[a:a + h + 1].all() for a, h in zip(starts, horizons)], dtype=bool)
    score = excitation(traj.slice(start, stop), max(1, step))[starts - start]
    keep &= score > min_speed
    if min_travel > 0:
        keep &= box_travel(traj, starts, horizons) > min_travel
    if not keep.any():
        return None
    starts, horizons, score = starts[keep], horizons[keep], score[keep]
    order = np.argsort(-score)
    budget = np.inf if max_steps is None else max(max_steps, horizons[order][0])
    fits = np.cumsum(horizons[order]) <= budget
    chosen = order[fits]
    rest = 0 if fits.all() else int(budget - horizons[chosen].sum())  # a clip left out: the budget is finite
    if rest >= max(1, step // 2):  # the budget's remainder: the next clip, cut to it (horizons: a copy already)
        nxt = order[np.argmin(fits)]
        horizons[nxt] = rest
        chosen = np.append(chosen, nxt)
    chosen = np.sort(chosen)
    return make_clips(traj, scene, starts[chosen], horizons[chosen])
