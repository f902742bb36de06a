"""Change attribution: the box's mass and friction held apart through noisy motion capture
(``MHESettings.attribute``; issue #24).

Through motion capture with millimetre noise a 1 s MHE window pins the friction force a push shows,
``m·μ`` (times g), but not its split into mass and friction: the split shows only where the box
accelerates, and the noise blurs it (*measured*: ``benchmarks/window_information.py``, docs/reference.md).
Worse, successive windows chain their estimates (``p̂⁻``), so a window's product can sit 20–30 % off for
seconds. What the data *can* tell, over a couple of seconds, is which of the two moved: scored along two
lines, one moving the mass with the friction held at its value before, one moving the friction with the
mass held, the changed parameter's line had the lower cost in 16 of 16 draws on noisy T3/T4 recordings
(``benchmarks/change_attribution.py``). This module makes that an estimator beside the windows:

* **the reference** ``(m_ref, μ_ref)`` is what is reported. It starts at the prior (a belief from
  ``probe``/``identify``, whose manoeuvre excites what the windows cannot) and moves only by a *line
  decision*, over :data:`SPAN` seconds of informative data with clips drawn as ``identify`` draws them:
  :data:`FACTORS` × the reference's value on each of the two lines are scored (the shared cost, data term
  only), then :data:`FINE` points around each line's best; a line's minimum lies where the parabola through
  its best point and neighbours puts it, and costs what its best evaluated point does;

  - where the better line reads the same friction force as the reference (within :data:`CHANGE` in log),
    nothing changed, whichever line was lower: the reading is averaged into the reference (its ``ln m·μ``,
    the last :data:`AVERAGE` at most), along the last attributed parameter's line, or before any
    attribution along the prior's own metric (``ln m`` and ``ln μ`` move in the ratio of the prior's
    relative variances: the split nearest the prior with that product). One span's reading scatters by
    ~10 %;
  - where the force moved and one line's cost is lower by :data:`DECISIVE_GAP` of the higher, that
    parameter moved: it takes its line's minimum, the other is held (an *attribution*); a periodic span's
    attribution also opens the change from the span's middle, since its data may straddle it (an emulated
    T3 run's span over its switch read a friction change), so the change's final decision, on the data
    after it, confirms or corrects it;
  - where the force moved and neither line is decisive, nothing moves yet: a periodic span straddles the
    change (it is then placed at the span's middle and decided on the data after it), a provisional one
    holds too little after it (tried again every :data:`RETRY` seconds of new data);
  - the final decision of a change, its lines' costs summed over a whole span, gives the change to the
    lower line whatever the gap past :data:`TIE`: that line's sign was right in 16 of 16 draws, and 12 of 12
    on two fresh T3 recordings, where its size was not (``benchmarks/change_attribution.py``: gaps of
    15 ± 5 % and 24 ± 7 %), and the force split as above left T3's mass 12–15 % and μ 0.06–0.07 off. Only
    lines that tie, within :data:`TIE` of the higher, move the force alone;

* **the windows** still solve eq. (4), but their product ``m·μ`` only *detects* a change (a
  one-coordinate :class:`~amhe_cli.estimation.fusion.WindowFusion`: gate confirmed by a window sharing no
  data, or CUSUM), and it follows a change over seconds (each window starts from the last, ``p̂⁻``). So
  each window's data is also *tested* (:meth:`SplitTracker.test`): :data:`TEST_CLIPS` clips of it scored at
  the reference and at the friction force moved by ``exp(±CHANGE)`` along either line; two successive tests
  that read it moved the same way open the change, or one that reads it moved by :data:`OPEN`. A change is
  decided provisionally as soon as it opens, with the lines held at the reference before it, and finally at
  the window whose data after it come nearest :data:`FINAL` seconds; its attributions of one parameter are
  averaged, weighted by the data each saw. The windows show it a second or two late, so each of its decisions
  for :data:`RELOCATE` seconds seeks it in the data from :data:`BACK` seconds before (:func:`locate`, over the
  clips' own costs) and scores clips drawn afresh from where it lies; a change's decisions add their lines'
  costs up (each scores its own clips of the data since it), so a longer span does not flip a decisive shorter
  one on one draw of clips. For :data:`QUIET` seconds after a change moved the reference the windows open no
  new one (they are still following it). A change that :data:`DROP` provisional decisions in a row read as
  no change of the force is closed (the tests look again), and one that opens less than :data:`MERGE` seconds
  after a change moved the reference is decided from the split before that change.
  With no change detected the lines are scored every :data:`PERIOD` seconds of data.

*Measured* (``benchmarks/mhe_accuracy.py`` without the clock, 1 mm / 0.2° motion capture, docs/evaluation.md
"Change attribution, decided on the data after the change" and "Line decisions on the GPU beside CPU
windows"): from 3 s after the change, mass within 10 % and μ within 0.05 on 12 of 16 noisy T3/T4
recordings on one seed, against 8 of 16 for the rules before (lines over ½–2×, a straddling or undecided
span's reading averaged or split at once, the last decision alone); over four seeds on 12 of them, 31 of
48 replays (4 to 10 of 12 per seed); with the lines compared at evaluated points (:data:`FINE`) 32 of
48, with a change's final decision by the lower line 37 of 48 (T4 16 of 16, T3 21 of 32), and with the
change located 43 of 48 (T4 16 of 16, T3 27 of 32). On one core a decision takes seconds: on the live
clock it held 0 of 8; with the decisions on a GPU (``MHESettings.attribute_device``) 21 of 48 (the rules
before :data:`FINE`). In the emulated closed loop (``amhe run --target go1``, decisions on an H200, T3 and
T4, docs/evaluation.md "The attribution on the wall clock, traced") the change went to the parameter that
moved in 14 of 14 runs once a periodic reading kept the windows' held evidence (0 of 11 reached the bound
before), and both bounds held from 4.3–4.5 s after the change (median), not from the issue's 3 s. With each
decision locating its change again (:data:`RELOCATE`; "Each decision of a change locates it again"): 43 of
48 offline (T4 15 of 16, T3 28 of 32), and in the emulated loop 29 of 29 changes to the parameter that
moved, both bounds from 3.6–3.7 s after it (median), 27 of 29 in the end, 4 of 29 from 3 s. With the decisions
on a thread of their own on the wall clock (``MovingHorizonEstimator.concurrent``: the windows keep their
cadence) and a belief to start from, 60 emulated runs: from 3.9 s (T3) and 3.2 s (T4) after the change
(median), 2 and 5 of 22 from 3 s ("Line decisions on a thread of their own"). With the change test and a
change's readings averaged, 48 emulated runs on an H200 against the code before, paired seeds 0–11: the
parameter that moved first attributed on 2.0 s (T3) and 1.6 s (T4) of data after the change, against 3.3 s and
2.0 s; both bounds from 3.8 s and 3.4 s (median), against 6.2 s and 3.7 s; from 3 s in 3 of 12 and 3 of 12,
against 1 of 12 and 0 of 11 ("A change test on each window's data"). With a change's final decision at the window
nearest :data:`SPAN` (:meth:`SplitTracker.due`), 32 emulated runs on an H200: both bounds from 3 s in 16 of 16 (T3) and
14 of 16 (T4; its two misses read a change of their own later), against 6 of 8 for the code before on T3 in the same
session ("The final decision at the span's window"). Those two late changes came from spans whose box moved only where
a leg alone touched it (:func:`~amhe_cli.estimation.clips.leg_only_touch`): a test or decision over such a span waits
(:data:`MOVING_MIN`); leaving a leg's clips out of every decision instead cost T3's switch its clips (11 of 16 from
3 s on an H200; "A leg on the box is not a push"). With the final decision on :data:`FINAL` (1.5 s) of data and no
provisional one whose measured run would hold it up (:attr:`SplitTracker.lead`), 48 emulated runs on an H200: both
bounds from 3 s in 27 of 32 (T3; 25 of 32 on the same seeds before) and 14 of 16 (T4; 15 of 16), in them from 2.1 s
after T3's switch (median) against 2.6 s; finals that waited for another decision 3 of 38 against 14 of 35 ("The
final decision on 1.5 s of data, and no provisional one it would wait for").

A change of both at once is attributed to the one whose line explains it better. The reference cannot
learn a split the prior got wrong unless a change is attributed: ``attribute`` is for a run that starts
from a belief (``run``'s Adaptive mode), not for a log with a nominal prior.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.estimation.fusion import WindowFusion
from amhe_cli.estimation.surrogate import parabola_vertex

#: Seconds of informative data (windows where the box moved) a line decision scores.
SPAN = 2.0
#: Seconds of informative data after a change on which its final decision is made (:meth:`SplitTracker.due`): the
#: change's decisions' summed lines, and its readings averaged by their data, over that much. *Measured* offline with
#: no clock (``benchmarks/mhe_accuracy.py``, ``mhe-replay``'s defaults, four fresh noisy T3 recordings and two T4, four
#: seeds): both bounds from 3 s after the change in 13 of 16 (T3) and 8 of 8 (T4) replays on 1.5 s against 14 of 16
#: and 8 of 8 on :data:`SPAN`, T4 in them from 1.43 s against 1.62 s (median). In the emulated loop the final decision
#: on :data:`SPAN` reached the planner 3.1–4.2 s after T3's switch in 9 of 64 runs on an H200 with its reading within
#: 10 %; on 1.5 s (and :attr:`SplitTracker.lead`) T3 held the bounds from 2.1 s (median) against 2.6 s, its final
#: mass readings +1.2 ± 4.4 % (docs/evaluation.md "The final decision on 1.5 s of data, and no provisional one it
#: would wait for").
FINAL = 1.5
#: Seconds of data before an update the estimator needs with ``attribute`` (the span, and rests between).
LOOKBACK = 4 * SPAN
#: Multiples of the reference's value scored on each line: evenly in log from a third to three times it.
#: A friction that doubles (T4's 0.4 -> 0.8) lay at the end of the earlier ½–2× line whenever the windows'
#: product had not yet moved, and a minimum at a periodic line's end moves nothing.
FACTORS = np.exp(np.linspace(np.log(1 / 3), np.log(3.0), 11))
#: Points a decision adds on each line around its best grid point, as powers of the grid's step (×1.25):
#: the lines are compared at evaluated points, the nearest a sixth of a step from each minimum. Compared at
#: the vertex of the parabola through three grid points, as before, the friction line's minimum lay up to
#: 20 % of the cost below any point of it on noisy T3 data (its cost rises steeper than a parabola past the
#: minimum): on ``t3_s5_n3``, 32 clips over the 2.5 s after the switch, the lines' minima on a fine grid
#: 1396 / 1723 (mass / friction), the parabolas' 1351 / 1404, a gap under :data:`DECISIVE_GAP`. *Measured*
#: over 12 noisy recordings × 4 seeds (docs/evaluation.md "Lines compared at evaluated points"): T4 16 of
#: 16 against 12, T3 16 of 32 against 19 (21 with the final decision by the lower line).
FINE = np.array([-2.0, -1.0, 1.0, 2.0]) / 3.0
#: Ratio of two neighbouring :data:`FACTORS`.
GRID_STEP = FACTORS[1] / FACTORS[0]
#: Clips a line decision draws, as ``identify`` draws them for the log's noise (its 32, of 0.1–0.2 s on a
#: noisy log). Half as many, on a replay of the live clock, lost the mass switch more often.
CLIPS = 32
#: Seconds of clip starts at which the box moves with no leg alone on it (:func:`~amhe_cli.estimation.clips.leg_only_touch`)
#: that a change test or line decision asks of a span where a leg alone touched it; with fewer it waits
#: (:func:`~amhe_cli.estimation.mhe.decision_clips`).
#: A leg's contact with the box is the model's least trustworthy (its soft foot spheres sit up to 12 mm inside the box on
#: a clean lock-step recording, 20 mm on an emulated run's) and, a kick being over before friction matters, it reads as
#: inertia: two emulated T4 runs read mass changes of −35 % and +34 % that were not there from spans whose box moved
#: only where a front foot struck it or stood against it (not one moving clip start clean of a leg in either; 7 and 18
#: of 121 and 367 in two T3 runs' late misreads of the friction). A push holds 97–356 clean ones a second.
MOVING_MIN = 0.1
#: Seconds of informative data between line decisions where no change is detected.
PERIOD = SPAN
#: Periodic decisions averaged (in log product) since the last change, at most: noise of one is ~10 %.
AVERAGE = 4
#: Cost gap, as a share of the higher line's lowest cost, that decides which parameter moved before a change's
#: final decision (which goes by the gap's sign). 0.05 throughout lost a T4 friction step to the mass.
DECISIVE_GAP = 0.15
#: Share of the higher line's cost, summed over a whole span, under which a change's final decision calls its lines a
#: tie: the friction force moves, split as before (along the last attributed parameter's line, or in the prior's
#: metric), and neither parameter is attributed. The final gaps of the T3/T4 changes were 15 ± 5 % and 24 ± 7 %
#: (``benchmarks/change_attribution.py``), 16–83 % on six noisy T3/T4 replays; a box 37 % heavier than its belief
#: from the start, through motion capture 20 ms late at 2 mm / 0.4°, gave its first change a gap of 1.2 %, and its
#: sign put the mass's change on the friction (4.05 kg, μ 0.535 for 5.5 kg, μ 0.4): every later decision read from
#: that split, and the floor's step then went to the mass (12.6 kg; docs/evaluation.md "Several at once").
TIE = 0.03
#: Change of the friction force a decision must read, ``|ln(f / f_ref)|``, to count as a change: twice the
#: ~10 % scatter of one span's reading. Below it the reading is averaged, whichever line was lower.
CHANGE = 0.2
#: Seconds of new informative data before an undecided provisional decision is tried again.
RETRY = 0.5
#: Seconds after a change moved the reference during which the windows' product opens no new change: the
#: windows chain their estimates (``p̂⁻``) and follow a change for seconds, so their product restarted at
#: the new reference still moves (traced on a noisy T4 recording: a change "detected" 1.5 s after the
#: friction was attributed, decided on 0.5 s of data, moved the held mass +22 %). Periodic decisions still
#: read the force meanwhile.
QUIET = SPAN
#: Seconds of data before a detected change (the end of the first window that showed it) searched for the
#: change itself (:func:`locate`): the windows chain their estimates, so the first that shows a change ends a
#: second or two after it, and the data between were lost to the decision (traced on a noisy T3 recording:
#: the switch at 10.0 s decided on data from 12.0 s, half of it the box at rest; located, at 10.0 s).
BACK = SPAN
#: Clips a decision that locates its change draws (over :data:`BACK` seconds more data than :data:`CLIPS`).
LOCATE_CLIPS = 48
#: A decision that seeks its change, in rollouts, as a multiple of one that does not: it scores its lines' candidates
#: on :data:`LOCATE_CLIPS` clips more than their :data:`CLIPS` (:attr:`SplitTracker.seek_lead` before one ran). On an
#: H200 such decisions took 0.41–0.84 s in one batch (median 0.54), periodic ones 0.23–0.55 s (0.27): 2.0 measured.
SEEK_WORK = 1 + LOCATE_CLIPS / CLIPS
#: Seconds after a change showed during which each of its decisions locates it again, over the data from
#: :data:`BACK` seconds before it showed, earlier or later than it was placed. Located once, at the update
#: that opened it, a change sat 1.4 s before a noisy T3 recording's switch (with 0.5 s of data after the
#: switch in), so its final decision came at the next update, over data mostly before the switch, and read
#: no change; and a window held 1.7 s before a T4 step, confirmed by the step, placed the change there and
#: gave the step to the mass (+114 %, docs/evaluation.md "Each decision of a change locates it again").
RELOCATE = 2 * SPAN
#: Seconds later a change may be placed again and keep its earlier decisions' summed costs: about a clip's
#: length (0.1–0.2 s on a noisy log), the jitter of :func:`locate` between decisions (0.02–0.05 s traced).
SHIFT = 0.25
#: Share of a seeking decision's lines' clips (drawn where its change sat, scored in the search's batch) that must
#: start after the place the search gives it (less :data:`SHIFT`) for the decision to keep their costs rather than
#: draw them again from there, a second batch on a GPU (``MovingHorizonEstimator._decide``). In stop 80's emulated
#: T3 grid (an H200, 40 runs) six final decisions drew again, 0.7–1.2 s a job against 0.4–0.7 s, and three of them
#: reached the planner 0.3–1.4 s past the bound from 3 s; offline (stop 72's noisy T3 recordings) the search placed
#: the change 0.3–1.2 s past their first clip in 6 of 19 seeking decisions: a quarter of the clips left out (a
#: reading's ~10 % scatter about 15 % wider) is the price of keeping to one batch. A change placed *earlier* than
#: where they were drawn from takes the search's own clips that start between (:func:`kept_clips`): the lines' clips
#: alone left those data out, and a false change placed 2 s early was read from half its span (one of 16 noisy T3
#: replays 20 % off after the switch, against 7 %).
KEEP = 0.75
#: Clips at least that a located change keeps after it.
LOCATE_MIN = 8
#: Clips a change test draws from the last window's data (:meth:`SplitTracker.test_candidates`): the windows'
#: own clips are one or two (their step budget), too few to tell a moved force from noise.
TEST_CLIPS = 16
#: Share of the held split's cost by which a candidate with the friction force moved by ``exp(±CHANGE)`` must
#: beat it, in two successive tests and the same direction, to open a change (:meth:`SplitTracker.test`).
DETECT = 0.15
#: Share of the held split's cost by which one change test alone opens a change (:meth:`SplitTracker.test`): the
#: first window ending 0.5–1.3 s after a T3/T4 change beat the held split by 0.31–0.58 on most fresh noisy
#: recordings; 3 of 218 windows before a change did (``benchmarks/change_test.py``).
OPEN = 0.3
#: Provisional decisions of a pending change in a row that read the friction force unchanged after which it is
#: closed: the data after it show no change. Held open for its final decision instead, a change the tests opened
#: 3.2 s before an emulated T4 run's friction step (its three provisional decisions read the force unchanged) kept
#: the tests off, and its final decision, over 1.6 s of data before the step and 0.3 s after, gave the step to the
#: mass (+25 %; docs/evaluation.md "A change its data do not show is closed").
DROP = 2
#: Seconds after the decision that last moved the reference within which a change that opens is decided from the
#: split before that one (:meth:`SplitTracker.open`): a decision whose data straddled a change misreads it, and the
#: next change, read from the misread split, keeps the error (the same T4 run: the step given to the mass, then the
#: friction attributed with the mass held at +25 %).
MERGE = SPAN
#: Names of the two parameters whose split is attributed.
NAMES = ("box_mass", "box_friction")


@dataclass
class Decision:
    """One line decision.

    Attributes:
        t: time [s] of the update that made it.
        since: start [s] of the data it scored.
        reason: ``change`` (a change is pending: the windows detected it, or a periodic span read a moved
            force with no decisive line; the final decision, :data:`FINAL` seconds of data after it),
            ``provisional`` (the same, before: as soon as it is pending, and again every :data:`RETRY`
            seconds of data until decisive) or ``period`` (:data:`PERIOD` seconds without a pending change).
        changed: ``box_mass`` or ``box_friction`` where the force moved and the gap (summed over a change's
            decisions) was decisive, else None (the force averaged or split, or nothing moved yet).
        mass, friction: the new reference [kg], [-].
        cost: the two lines' lowest costs, name -> J (data term only).
    """

    t: float
    since: float
    reason: str
    changed: str | None
    mass: float
    friction: float
    cost: dict

    def describe(self) -> str:
        """One line for a log: what the decision found."""
        if self.changed is None:
            return (f"t={self.t:.2f} s: MHE line decision ({self.reason}, data from {self.since:.1f} s): which "
                    f"parameter moved is undecided; friction force m·μ {self.mass * self.friction:.2f} kg")
        new = f"{self.mass:.2f} kg" if self.changed == "box_mass" else f"{self.friction:.3f}"
        held = (f"friction held at {self.friction:.3f}" if self.changed == "box_mass"
                else f"mass held at {self.mass:.2f} kg")
        return (f"t={self.t:.2f} s: MHE attributes the change ({self.reason}, data from {self.since:.1f} s) to "
                f"{self.changed}: {new}; {held}")


def line_minimum(factors: np.ndarray, J: np.ndarray) -> tuple[float, float]:
    """(factor, cost) of a line's minimum over points ``factors`` (ascending, duplicates allowed) with costs
    ``J``: where it lies, the best point refined by the parabola through it and its two neighbours (in log
    factor), kept inside them, or the best point itself at an end of the line; its cost, the best point's own
    (evaluated, not the parabola's: :data:`FINE`)."""
    factors, J = np.asarray(factors, dtype=float), np.asarray(J, dtype=float)
    order = np.lexsort((J, factors))  # by factor, the lowest cost first among equal ones
    factors, J = factors[order], J[order]
    keep = np.r_[True, np.diff(factors) > 0]
    factors, J = factors[keep], J[keep]
    k = int(np.argmin(J))
    if k in (0, len(J) - 1) or not np.all(np.isfinite(J[k - 1:k + 2])):
        return float(factors[k]), float(J[k])
    xm, _ = parabola_vertex(np.log(factors[k - 1:k + 2]), J[k - 1:k + 2])
    return float(np.exp(xm)), float(J[k])


def change_gains(per_clip: np.ndarray, held: np.ndarray, keep_min: int = LOCATE_MIN) -> np.ndarray:
    """(N_c − keep_min + 1,) the gain of a change placed at each clip ``j`` that keeps ``keep_min`` clips after
    it: ``max_k Σ_{i ≥ j} (held_i − per_clip[k, i])`` (a likelihood-ratio change point, the best candidate each).

    ``per_clip`` (B, N_c) is the data cost of each line candidate on each clip, ``held`` (N_c,) that of the
    split before the change, the clips in time order. Diverged rollouts count as the largest finite gain seen."""
    d = np.asarray(held, dtype=float)[None, :] - np.asarray(per_clip, dtype=float)
    finite = np.isfinite(d)
    bound = float(np.abs(d[finite]).max()) if finite.any() else 0.0
    d = np.clip(np.where(finite, d, bound), -bound, bound)
    gain = np.cumsum(d[:, ::-1], axis=1)[:, ::-1].max(axis=0)
    return gain[:max(gain.size - max(int(keep_min), 1), 0) + 1]


def locate(per_clip: np.ndarray, held: np.ndarray, keep_min: int = LOCATE_MIN) -> int:
    """First clip after a change: the single change point the clips' costs explain best, the clip ``j`` in
    ``[0, N_c − keep_min]`` of the largest :func:`change_gains` (arguments as there)."""
    return int(np.argmax(change_gains(per_clip, held, keep_min)))


def kept_clips(sought: np.ndarray, ahead: np.ndarray, own: np.ndarray, after: np.ndarray, placed: float,
               since: float) -> np.ndarray | None:
    """Positions, ascending, in a seeking decision's one batch of the clips its lines are decided on, or None where
    too few are there and the lines' clips are drawn again from the place (a second batch; :data:`KEEP`).

    ``sought`` (N_s,) and ``ahead`` (N_a,) are the start times [s] of the search's clips (drawn from before the
    change showed) and of the lines' (drawn from ``since``, where the change sat), ``own`` and ``after`` their
    positions in the batch (:func:`~amhe_cli.estimation.clips.join_clips`); ``placed`` [s] is where the search put
    the change. Kept: the lines' clips that start after it, less :data:`SHIFT` (its jitter), and where it sits more
    than ``SHIFT`` before ``since``, the search's own clips that start between (``[placed − SHIFT, since)``), the
    data the lines' clips were not drawn from; where these are ``KEEP`` × N_a or more. Before stop 85 a change
    placed earlier drew the lines' clips again: 3 of the 4 second batches of 18 seeking decisions in eight offline
    T3 replays of this path; in the emulated loop finals of two batches were every late miss of stop 84's T3 grid
    (0.09–0.11 s past the bound from 3 s), and none of 32 T3 finals took two with this (docs/evaluation.md, stop 85)."""
    sought, ahead = np.asarray(sought, dtype=float), np.asarray(ahead, dtype=float)
    gap = (sought >= placed - SHIFT) & (sought < since) if placed < since - SHIFT else np.zeros(sought.size, bool)
    keep = ahead >= placed - SHIFT
    if keep.sum() + gap.sum() < KEEP * ahead.size:
        return None
    return np.sort(np.r_[np.asarray(own)[gap], np.asarray(after)[keep]])


def test_reading(J: np.ndarray) -> tuple[float, int] | None:
    """What a change test's data costs ``J`` (5,), in :meth:`SplitTracker.test_candidates`' order, read: ``(gain,
    direction)``, the best moved candidate's cost below the held split's as a share of it, and +1 where it moved
    the friction force up, −1 down; None where the held split's cost is not finite and positive."""
    J = np.where(np.isfinite(J), np.asarray(J, dtype=float), np.inf)
    if not np.isfinite(J[0]) or J[0] <= 0:
        return None
    gain = (J[0] - J[1:]) / J[0]
    up, down = max(gain[0], gain[2]), max(gain[1], gain[3])
    return (float(up), 1) if up >= down else (float(down), -1)


class SplitTracker:
    """The reported mass and friction: a reference moved by line decisions, changes detected by the
    windows' product (module doc).

    Args:
        index: flat indices ``(i_m, i_μ)`` of the box's mass and friction in the estimator's vector.
        mean0: (d,) the prior mean; ``std0``: (d,) its σ (the reference to start from, and its metric).
        noise0: (d,) σ of one window's estimate assumed before the fusion can read it.
        floor: σ floor of the product's window noise, as a share of the prior product.
        window: ``H`` [s] of the windows.
        every: [s] between the windows' updates (``MHESettings.every``): a change's final decision is due at
            the window whose data after it come nearest :data:`FINAL` (:meth:`due`).

    Attributes:
        ref: (mass [kg], friction) reported.
        active: the parameter last attributed a change (None before any).
        pending: ``(since, split before)`` of a detected change not yet finally decided, or None.
        decisions: the :class:`Decision` list so far.
        lead: [s] a line decision takes on the wall clock, where decisions run beside the windows (set by
            ``MovingHorizonEstimator``; 0 without a clock): no provisional decision is made whose run would
            still hold the final one up (:meth:`due`).
        seek_lead: [s] the same for a decision that seeks its change (:meth:`search_from`), which scores
            :data:`LOCATE_CLIPS` clips more: measured from such decisions, before any ran :attr:`lead` ×
            :data:`SEEK_WORK`.

    Raises:
        AmheError: a non-positive prior mass or friction (the metric is taken in logs).
    """

    def __init__(self, index: tuple[int, int], mean0: np.ndarray, std0: np.ndarray, noise0: np.ndarray,
                 floor: float, window: float, every: float = 0.5):
        self.im, self.iu = index
        if not every > 0:
            raise AmheError(f"change attribution needs a positive update period, got {every} s")
        self.every = float(every)
        m, mu = float(mean0[self.im]), float(mean0[self.iu])
        if not (m > 0 and mu > 0):
            raise AmheError(f"change attribution needs a positive prior mass and friction, got {m} kg and {mu}")
        rel = lambda v: (float(v[self.im]) / m, float(v[self.iu]) / mu)  # noqa: E731
        rm, ru = rel(std0)
        self.share = rm ** 2 / (rm ** 2 + ru ** 2)
        self.rel_std = (rm, ru)
        self.ref = (m, mu)
        self.active: str | None = None
        f0 = m * mu
        self.product = WindowFusion(np.array([f0]), np.array([f0 * np.hypot(rm, ru)]),
                                    np.array([f0 * np.hypot(*rel(noise0))]), np.array([f0]), floor, window)
        self.pending: tuple[float, tuple[float, float]] | None = None
        self.shown = 0.0  # time [s] the pending change showed (opened): its search reaches :data:`BACK` before
        self.floor = -np.inf  # start [s] of the data of the reference's last change: no search before it
        # ``seen`` [s] from which the pending change's next provisional decision is due: inf once one attributed it
        self.retry_at = 0.0
        self.evidence = np.zeros(2)  # the pending change's lines' lowest costs, summed over its decisions
        self.readings: list[tuple[str, float, float]] = []  # the pending change's attributions (:meth:`open`)
        self.quiet_until = -np.inf  # data time [s] before which the windows open no change (:data:`QUIET`)
        self.since: float | None = None  # start [s] of the data the next periodic decision scores
        self.seen = 0.0  # seconds of informative windows since then (or since the pending change showed)
        self.last: float | None = None  # end [s] of the last informative window
        self.spans: list[tuple[float, float]] = []  # (start, end) [s] of the data counted, the last LOOKBACK s
        self.decisions: list[Decision] = []
        self.center: float | None = None  # product [kg] the next lines are centred on, after an edge
        self.averaged = 1  # readings averaged into the reference since the last change (the prior: one)
        self.tested: tuple[float, int] | None = None  # (time [s], direction ±1) of the last test past DETECT
        self.unchanged = 0  # the pending change's provisional decisions in a row that read the force unchanged
        # (time [s], split before) of the decision that last moved the reference by a change (:data:`MERGE`)
        self.moved: tuple[float, tuple[float, float]] | None = None
        self.lead = 0.0
        self.seek_lead = 0.0

    def fuse(self, t: float, window_mean: np.ndarray) -> None:
        """Take the informative window (d,) ending at ``t`` [s]: its product feeds the change detection. A
        detected change with none pending opens one, from the end of the first window that showed it."""
        held = self.product.held[0]
        first = held[0][0] if held else float(t)
        restarts = self.product.restarts
        self.product.update(t, np.array([float(window_mean[self.im] * window_mean[self.iu])]))
        self.advance(t)
        w = self.product.window
        if self.product.restarts > restarts and self.pending is None and t >= self.quiet_until:
            self.open(first, min(t - first, w))

    def advance(self, t: float) -> None:
        """Count the new data of the informative window ending at ``t`` [s] as seen (since the last informative
        one, at most a window's length), once: :meth:`fuse` calls it too, and a window's data are in before its
        solve (the decision it makes due may start with it)."""
        if self.last is not None and float(t) <= self.last:
            return
        w = self.product.window
        if self.since is None:
            self.since = float(t) - w
        new = w if self.last is None else min(float(t) - self.last, w)
        self.seen += new
        self.last = float(t)
        self.spans = [s for s in self.spans if s[1] > self.last - LOOKBACK] + [(self.last - new, self.last)]

    def informative(self, since: float) -> float:
        """Seconds of informative data (the windows :meth:`advance` counted) after ``since`` [s], within the last
        :data:`LOOKBACK` seconds: a box at rest between them adds none."""
        return float(sum(max(0.0, b - max(a, float(since))) for a, b in self.spans))

    def testing(self, t: float) -> bool:
        """Whether a change test (:meth:`test`) at the window ending at ``t`` [s] may open a change: none pending,
        and past :data:`QUIET`."""
        return self.pending is None and t >= self.quiet_until

    def test_candidates(self, base: np.ndarray) -> np.ndarray:
        """(5, d) candidates of a change test: ``base`` with the split held (the reference), then with the mass
        times ``exp(+CHANGE)``, ``exp(−CHANGE)`` (friction held), then the friction so (mass held)."""
        m, mu = self.ref
        r = float(np.exp(CHANGE))
        P = np.repeat(np.asarray(base, dtype=float)[None], 5, axis=0)
        P[:, self.im] = [m, m * r, m / r, m, m]
        P[:, self.iu] = [mu, mu, mu, mu * r, mu / r]
        return P

    def test_search_from(self) -> float | None:
        """Start [s] of the data in which the next change test also seeks the change it may open (:func:`locate`,
        its ``located``): where the last test passed :data:`DETECT`, :data:`BACK` seconds before that test's window,
        where the change's first decision would seek it (:meth:`search_from`), not before the reference's last
        change; else None."""
        if self.tested is None or self.pending is not None:
            return None
        return self._search_start(self.tested[0] - self.product.window)

    def test(self, t: float, J: np.ndarray, located: float | None = None) -> bool:
        """Take a change test of the window ending at ``t`` [s]: ``J`` (5,) the data costs of
        :meth:`test_candidates` on :data:`TEST_CLIPS` clips drawn from the window's data. The friction force
        moved where a candidate that moves it beats the held split by :data:`DETECT` of its cost; two
        successive tests so, in the same direction, open a change from the start of the first one's window,
        its data counted as seen (decided then on the data after it, located first), or from ``located`` [s]
        where given (the change sought with this test, in :meth:`test_search_from`'s data: its first decision
        need not seek it). One test alone opens it where it beats the held split by :data:`OPEN`, from the
        start of its window. Returns whether it opened one.

        The windows chain their estimates (``p̂⁻``, eq. 4), so their product follows a change over seconds
        (:meth:`fuse`); this test starts from the split held each time. *Measured* on four fresh noisy T3/T4
        recordings (``benchmarks/change_test.py``: 16 clips of the last second, the truth before the change
        held): the best moved candidate beat the held split by +0.19 to +0.58 of its cost in every window from
        the first ending 0.7–1.3 s after the change until the box next rested, by at most +0.35 in a window
        before it, and by more than 0.15 in two successive ones the same way twice in 56 windows before it. A
        change opened so where the force did not move is read unchanged by its decision, and averaged in
        (:meth:`decide`) (docs/evaluation.md "A change test on each window's data").

        On eight more fresh recordings (two draws each), one test past :data:`OPEN` came 0.5 s before two
        past :data:`DETECT` in 9 of 16 changes, and 3 of 218 windows before a change passed it (two in a row
        past DETECT: 1). Replayed without a clock (``benchmarks/mhe_accuracy.py``), T3's switch held both
        bounds from 3 s in 13 of 16 (seeds 0–3) against 8 of 16 for two tests alone, T4's step 7 of 8 either way
        (docs/evaluation.md "The final code in the emulated loop, and one test that opens a change")."""
        reading = test_reading(J)
        if reading is None or reading[0] < DETECT or not self.testing(t):
            self.tested = None
            return False
        last, self.tested = self.tested, (float(t), reading[1])
        w = self.product.window
        if last is not None and last[1] == reading[1]:
            self.open(last[0] - w, w + min(float(t) - last[0], w))
        elif reading[0] >= OPEN:
            self.open(float(t) - w, w)
        else:
            return False
        if located is not None:
            self.relocate(min(float(located), float(t)))
        return True

    @property
    def final_at(self) -> float:
        """Seconds of data after a change from which its final decision is due (:meth:`due`)."""
        return FINAL - 0.5 * self.every

    def due(self) -> tuple[float, str] | None:
        """``(since, reason)`` of the line decision due now (:class:`Decision`), else None.

        A pending change's final decision is due at the window whose data after it come nearest :data:`FINAL`
        (from ``FINAL − every/2``: :attr:`final_at`), and no provisional one is made whose run would still hold
        it up: where the next window would make it due, or where :attr:`lead` (a decision's measured time on the
        wall clock; :attr:`seek_lead` for one that would seek its change) reaches past it. Due at the first window
        past :data:`SPAN`, the final decision came on 2.0–2.5 s of data, and on the wall clock it waited for a
        provisional decision still running (0.18–0.41 s in four of 16 emulated T3 runs on an H200). Due at the
        window nearest :data:`SPAN`, with no provisional decision the window before, it still waited 0.27–0.69 s
        for one in 7 of 64 emulated T3 runs (provisional decisions that seek their change take 0.76–1.14 s there),
        and those reached the planner 3.1–4.2 s after the switch with a reading within 10 % (docs/evaluation.md
        "The sidestep in the emulated loop")."""
        if self.pending is not None:
            if self.seen >= self.final_at - 1e-9:
                return self.pending[0], "change"
            lead = self.seek_lead if self.search_from("provisional") is not None else self.lead
            if self.seen < self.retry_at - 1e-9 or self.seen + max(self.every, lead) >= self.final_at - 1e-9:
                return None
            return self.pending[0], "provisional"
        if self.since is not None and self.seen >= PERIOD - 1e-9:
            return self.since, "period"
        return None

    def search_from(self, reason: str) -> float | None:
        """Start [s] of the data in which a decision due for ``reason`` seeks its change (:func:`locate`):
        :data:`BACK` seconds before the pending change showed, not before the reference's last change, for
        :data:`RELOCATE` seconds after it showed; else None (nothing to seek)."""
        if reason == "period" or self.pending is None or self.last is None or self.last - self.shown >= RELOCATE:
            return None
        return self._search_start(self.shown)

    def _search_start(self, shown: float) -> float:
        """Where the search for a change that showed at ``shown`` [s] starts: :data:`BACK` seconds before, not
        before the reference's last change."""
        return max(shown - BACK, self.floor, 0.0)

    def relocate(self, t: float) -> str:
        """Place the pending change at ``t`` [s], earlier or later than before; the informative data since count
        as seen (:meth:`informative`). Moved later by more than :data:`SHIFT`, its earlier decisions scored data
        from before it: their summed costs are dropped. Returns the reason of its decision now: ``change`` where
        its final decision is due (:meth:`due`), else ``provisional``.

        Counted by the clock instead, a change moved back into a rest took the rest as data after it: traced on a
        noisy T4 recording (the box at rest 15.5–23.5 s, a change opened when the pushes resumed and placed at
        19.8 s), its first decision was already the final one, decided by the lines' sign on 1 s of pushes: μ 0.48
        against 0.8 for two seconds (docs/evaluation.md "A decision started with its window")."""
        since, held = self.pending
        self.seen = self.informative(t)
        if t > since + SHIFT:
            self.evidence, self.readings = np.zeros(2), []
        self.pending = (float(t), held)
        return "change" if self.seen >= self.final_at - 1e-9 else "provisional"

    def held(self, base: np.ndarray) -> np.ndarray:
        """(1, d) ``base`` with the split before the pending change (or the reference)."""
        P = np.asarray(base, dtype=float)[None].copy()
        P[0, self.im], P[0, self.iu] = self.pending[1] if self.pending is not None else self.ref
        return P

    def candidates(self, base: np.ndarray) -> np.ndarray:
        """(2·len(FACTORS), d) candidates: ``base`` with the mass line's points, then the friction line's.

        Each line holds the other parameter at the split before the pending change (or the reference)
        and is centred where it meets the friction force the windows now show (:attr:`center`, the
        product's fusion: right after a change, the window that confirmed it)."""
        m, mu = self.pending[1] if self.pending is not None else self.ref
        f = self.center if self.center is not None else float(self.product.x[0])
        P = np.repeat(np.asarray(base, dtype=float)[None], 2 * FACTORS.size, axis=0)
        n = FACTORS.size
        P[:n, self.im], P[:n, self.iu] = f / mu * FACTORS, mu
        P[n:, self.im], P[n:, self.iu] = m, f / m * FACTORS
        return P

    def refinements(self, P: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points around each line's best of :meth:`candidates` ``P`` (costs ``J``): ``(R, g_mass, g_friction)``,
        ``R`` (2·len(FINE), d) the mass line's then the friction line's, ``g_*`` (len(FINE),) their factors
        (:data:`FINE` steps from the best grid point, kept on the line)."""
        n = FACTORS.size
        J = np.where(np.isfinite(J), np.asarray(J, dtype=float), np.inf)
        g = [np.clip(FACTORS[int(np.argmin(J[i * n:(i + 1) * n]))] * GRID_STEP ** FINE, FACTORS[0], FACTORS[-1])
             for i in (0, 1)]
        return self._on_lines(P, *g), g[0], g[1]

    def between(self, P: np.ndarray) -> np.ndarray:
        """(2·2·(len(FACTORS) − 1), d) the points :data:`FINE` steps from every grid point of :meth:`candidates`
        ``P`` that lie between two of them, the mass line's then the friction line's: every point of
        :meth:`refinements`, whichever grid point is best, is one of these or a grid point. Scored in the lines'
        own batch (on a GPU, where width is cheap and each dependent batch costs its latency), a decision needs no
        second batch for its refinements."""
        g = (FACTORS[:-1, None] * GRID_STEP ** FINE[FINE > 0]).ravel()
        return self._on_lines(P, g, g)

    def _on_lines(self, P: np.ndarray, g_mass: np.ndarray, g_friction: np.ndarray) -> np.ndarray:
        """(len(g_mass) + len(g_friction), d): the points at factors ``g_*`` of :data:`FACTORS`' scale on the mass
        line of :meth:`candidates` ``P``, then on its friction line (the other parameter held as there)."""
        n = FACTORS.size
        R = np.repeat(np.asarray(P[[0, n]], dtype=float), [g_mass.size, g_friction.size], axis=0)
        R[:g_mass.size, self.im] = P[0, self.im] / FACTORS[0] * g_mass
        R[g_mass.size:, self.iu] = P[n, self.iu] / FACTORS[0] * g_friction
        return R

    def decide(self, t: float, reason: str, P: np.ndarray, J: np.ndarray, retry: bool = True,
               score=None) -> Decision | None:
        """Move the reference by the costs ``J`` (2·len(FACTORS),) of :meth:`candidates` ``P`` (module doc).

        Where the better line's minimum lies at its end and ``retry`` is set, nothing is decided: the lines
        are re-centred there (:attr:`center`) for the caller to score once more, and None is returned; at
        its end without ``retry``, the reference stays (a decision with ``changed`` None). ``score`` (the
        same cost: (B, d) candidates -> (B,) costs), where given, scores :meth:`refinements` first, so each
        line's minimum is compared at an evaluated point near it (:data:`FINE`)."""
        n = FACTORS.size
        J = np.where(np.isfinite(J), np.asarray(J, dtype=float), np.inf)
        k = int(np.argmin(J))
        if retry and k % n in (0, n - 1):
            self.center = float(P[k, self.im] * P[k, self.iu])
            return None
        self.center = None
        lines = [(FACTORS, J[:n]), (FACTORS, J[n:])]
        if score is not None:
            R, g_m, g_u = self.refinements(P, J)
            JR = np.asarray(score(R), dtype=float)
            JR = np.where(np.isfinite(JR), JR, np.inf)
            lines = [(np.r_[FACTORS, g_m], np.r_[J[:n], JR[:FINE.size]]),
                     (np.r_[FACTORS, g_u], np.r_[J[n:], JR[FINE.size:]])]
        (gm, jm), (gu, ju) = (line_minimum(*line) for line in lines)
        m0, mu0 = self.pending[1] if self.pending is not None else self.ref
        f_c = float(P[0, self.im] * P[0, self.iu]) / FACTORS[0]  # the product the lines are centred on
        fm, fu = gm * f_c / (m0 * mu0), gu * f_c / (m0 * mu0)  # as factors of the split held
        since = self.pending[0] if self.pending is not None else self.since
        changed, wait = None, False  # wait: nothing decided yet, the pending change tried again on more data
        settle = None  # how the decision settles (_settle), where not as its reason: a periodic attribution
        cost = {"box_mass": float(jm), "box_friction": float(ju)}
        if not FACTORS[0] < (gu if ju < jm else gm) < FACTORS[-1]:
            # the better line's minimum at its end, re-centred or not: the data do not place it (a span that
            # straddles a change, a push too slow to tell): nothing moves
            return self._record(Decision(t, since, reason, None, *self.ref, cost), False)
        if self.pending is not None:
            # a pending change's decisions add up: each scores its own clips of the data since the change
            self.evidence += (jm, ju)
            jm, ju = self.evidence
        if abs(jm - ju) >= DECISIVE_GAP * max(jm, ju) or (reason == "change" and abs(jm - ju) >= TIE * max(jm, ju)):
            # decisive; or the change's final decision, a whole span summed, where the lower line's sign
            # holds though its margin may not (not within TIE: a coin's toss)
            changed = "box_mass" if jm < ju else "box_friction"
        better = fm if jm <= ju else fu  # the friction force the better line reads, as a factor of the held one
        unchanged = abs(np.log(better)) < CHANGE
        self.unchanged = self.unchanged + 1 if unchanged and reason == "provisional" else 0
        if unchanged:
            # no change of the friction force (whichever line was lower: with the force unchanged a line's
            # preference is the span's noise): one more reading of it, averaged along the usual line; a
            # provisional decision looks again with more data (the windows' change is not in it yet), until
            # :data:`DROP` in a row read it so: the change is closed, and the tests look for one again
            changed, wait = None, 0 < self.unchanged < DROP
            settle = "change" if self.unchanged >= DROP else None
            self.averaged = min(self.averaged + 1, AVERAGE)
            self.ref = self.split(m0 * mu0 * float(np.exp(np.log(better) / self.averaged)), (m0, mu0))
        elif changed is not None:
            factor = fm if changed == "box_mass" else fu
            if self.pending is not None:
                # a change's readings of the parameter it moved, averaged in log weighted by the data each saw:
                # one draw of clips scatters ~10 % (traced on a fresh noisy T3 recording: 5.82 kg at the
                # provisional decision, 5.22 kg at the final one, over nearly the same data; the truth 6 kg)
                self.readings.append((changed, float(np.log(factor)), max(self.seen, RETRY)))
                same = [(g, w) for c, g, w in self.readings if c == changed]
                factor = float(np.exp(sum(g * w for g, w in same) / sum(w for _, w in same)))
            if reason == "period":
                # a periodic span over a moved force may straddle the change, and its lines then misread it (an
                # emulated T3 run's recording: the span over its switch gave it to the friction): attributed now,
                # and opened from the span's middle, so the change's final decision, on the data after it (located
                # first), confirms or corrects this one against the split held before
                self._open_straddled(since)
                settle = "provisional"
            self.ref = (m0 * factor, mu0) if changed == "box_mass" else (m0, mu0 * factor)
            self.active, self.averaged, self.quiet_until, self.floor = changed, 1, float(t) + QUIET, since
            self.moved = (float(t), (m0, mu0))
        elif reason == "change":
            # the lines tie (within TIE) after a whole span; the friction force does not: the better line's,
            # split as before
            self.ref = self.split(m0 * mu0 * better, (m0, mu0))
            self.averaged, self.quiet_until, self.floor = 1, float(t) + QUIET, since
            self.moved = (float(t), (m0, mu0))
        else:
            # the force moved and the span cannot tell which: a periodic span straddles the change, a
            # provisional one holds too little after it. Nothing moves; the change is decided on the data
            # after it, tried again as it comes in (a periodic span's change is placed at its middle)
            wait = True
            if reason == "period":
                self._open_straddled(since)
        return self._record(Decision(t, since, reason, changed, *self.ref, cost), wait, settle)

    def _record(self, d: Decision, wait: bool, settle: str | None = None) -> Decision:
        """Keep the decision ``d``; then, with ``wait``, try the pending change again after :data:`RETRY` s
        of data, else settle (:meth:`_settle`) as ``settle`` says (default: as ``d.reason``; a periodic
        attribution settles as a provisional one). The product's fusion restarts at the reference either way;
        where the decision moved nothing but a reading averaged in and no change is pending, the windows held
        beyond its gate stay, the evidence of a change in progress. Traced on an emulated T3 run (wall clock,
        decisions on an H200): a periodic decision due at the first window that showed the switch (10.5 s)
        dropped it, so the window at 12.0 s, sharing no data with it, did not confirm the change, and it was
        opened only by the next periodic decision, at 13.0 s. (Not restarting at all there, CUSUM sums
        included, opened spurious changes offline: T4 5 of 8 replays against 8.)"""
        keep = d.changed is None and self.pending is None
        self.decisions.append(d)
        self.tested = None  # a test is of the split held then
        if wait:
            self.retry_at = self.seen + RETRY
        else:
            self._settle(settle or d.reason)
        self.product.restart(0, self.ref[0] * self.ref[1], keep_held=keep)
        return d

    def _open_straddled(self, since: float) -> None:
        """A periodic span from ``since`` to the last window that may straddle a change: opened at its middle,
        the informative data of the span's second half counted as seen after it."""
        start = 0.5 * (since + self.last)
        self.open(start, self.informative(start))

    def open(self, since: float, seen: float) -> None:
        """A change is pending from ``since`` [s], with ``seen`` seconds of data after it in: decided on the
        data after it, the lines holding the split before it: the reference, or where the decision that last
        moved it came less than :data:`MERGE` seconds before ``since``, the split before that one (its data may
        have straddled this change and misread it; decided again from before both, on the data after this one)."""
        held = self.ref
        if self.moved is not None and float(since) - self.moved[0] < MERGE:
            held = self.moved[1]
        self.pending, self.retry_at, self.seen, self.shown = (since, held), 0.0, seen, float(since)
        self.tested = None
        self.unchanged = 0
        self.evidence = np.zeros(2)  # the lines' lowest costs summed over the change's decisions
        self.readings = []  # its attributions: (parameter, ln factor, weight [s] of data)

    def _settle(self, reason: str) -> None:
        """After a decision: the pending change stays for its final one, or the next span starts."""
        if reason == "provisional":
            self.retry_at = np.inf  # attributed: the final decision comes after the span
        else:
            self.pending, self.since, self.seen = None, self.last, 0.0

    def split(self, f: float, ref: tuple[float, float]) -> tuple[float, float]:
        """(mass [kg], friction) with the product ``f`` nearest ``ref``: along the last attributed
        parameter's line, or before any attribution in the prior's metric (module doc)."""
        m, mu = ref
        if self.active == "box_mass":
            return f / mu, mu
        if self.active == "box_friction":
            return m, f / m
        g = np.log(max(f, 1e-12) / (m * mu))
        return m * float(np.exp(self.share * g)), mu * float(np.exp((1.0 - self.share) * g))

    def std(self) -> tuple[float, float]:
        """σ (kg, 1) of the reference: the prior's relative σ, the windows' relative product σ added on the
        parameter(s) that take a change of the product."""
        m, mu = self.ref
        f = m * mu
        r = float(self.product.std[0]) / max(f, 1e-12)
        wm = {"box_mass": 1.0, "box_friction": 0.0}.get(self.active, self.share)
        return m * float(np.hypot(self.rel_std[0], r * wm)), mu * float(np.hypot(self.rel_std[1], r * (1 - wm)))
