"""How late motion capture arrives, read against the IMU from the trunk's attitude.

The Go1's IMU and the motion-capture system both measure the trunk's attitude.
The IMU's reaches the client with its LowState (the link's own millisecond or
so); the motion capture's after its cameras' exposure, its processing and the
network: a few to about twenty milliseconds on common systems, of which a
vendor's SDK reports some part and a UDP pose stream nothing. A pose stamped
when it *arrives* is that much late against the joints, the IMU and the joint
targets — in the planner's state (positions carried forward over the wrong age)
and in the MHE's window, where a 0.2 m/s push 20 ms late puts the box 4 mm off
the robot's head, four times the motion capture's noise, in the contact the
mass is read from.

:class:`MocapLatency` reads the lateness from the two streams themselves: over
the last ``span`` seconds, the lag ``L`` in ``[0, max_lag]`` at which the IMU's
attitude, taken ``L`` before each pose arrived, best matches the pose's (least
mean squared difference, each stream's mean over the span removed: markers
tilted on the trunk are a constant; a parabola through the best lag and its
neighbours refines it). Attitude is compared as the world's up direction in the
trunk frame (:func:`up_in_body`), which does not depend on where either stream
puts its yaw zero. A trotting trunk rocks by a degree or more at 1.3 Hz and its
feet's impacts; a trunk that does not move (standing, lying) has no timing to
read, so a span whose IMU attitude varies by less than ``min_motion`` gives no
estimate, nor does a span whose best lag is at either end of the range (no
minimum inside it). The lateness reported is the median of the last
:data:`MEDIAN_OF` estimates, once enough of them agree with it (:data:`AGREE`);
it covers the whole pipeline but the IMU's own link delay.
*Measured*: a synthetic trot through 0.2° noise, markers tilted 2° and a yaw
zero 1 rad off, 3 / 17 / 45 ms late, read within 0.5 ms; ``amhe emulate go1
--pose-latency`` 0.003 / 0.025 read 4.3 / 26.6 ms 2 s into a T1 run (the link
and the relay's 2 ms tick add the rest); with :data:`AGREE` the first report
comes 4–5 s in (5.0 ms at 3 ms late).

The run's MHE window and its recording date each pose at its arrival less that
lateness (:meth:`~amhe_cli.plants.go1.plant.Go1Plant.trajectory`); ``mocap_latency:
S`` in a run config fixes it instead (``auto``: measured, the default). The
planner's state does not: carrying its poses forward over the lateness too
slowed T3 on the emulated Go1 with poses 20 ms late (docs/evaluation.md#late-motion-capture).
"""

from __future__ import annotations

import threading

import numpy as np

from amhe_cli.errors import AmheError

#: Successive span estimates whose median is reported ...
MEDIAN_OF = 5
#: ... once at least ``AGREE[0]`` of them lie within ``AGREE[1]`` [s] of it. The first span of a run (the
#: slow ramp to the stand) times the streams loosely: on the emulated Go1, 3 ms late, two runs' first
#: estimates read 31.1 and 80.0 ms and every later one 3.6–5.6; a median of the first two or three dated the
#: MHE's poses 20–40 ms wrong for seconds.
AGREE = (3, 0.003)
#: Largest fixed lateness a run config may give [s].
MAX_FIXED = 0.5


def parse_mocap_latency(value) -> float | None:
    """A run config's ``mocap_latency``: ``"auto"`` (or None) -> None (measured); seconds -> float.

    Raises:
        AmheError: anything else, or seconds outside [0, :data:`MAX_FIXED`].
    """
    if value is None or value == "auto":
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= MAX_FIXED:
        raise AmheError(f"mocap_latency {value!r}: expected auto (measured against the IMU) or how late motion "
                        f"capture arrives in seconds, 0 to {MAX_FIXED:g}")
    return float(value)


def up_in_body(quat) -> tuple[float, float] | None:
    """x and y of the world's up direction in the body frame of attitude ``quat`` (4,) (w, x, y, z), or None
    for a zero quaternion.

    About (−pitch, roll) [rad] for small angles; unchanged by any turn about the world's z, so two
    sensors whose yaw zeros differ (an IMU and motion capture) give the same values. Plain floats: the
    relay thread calls it every 2 ms, where numpy's per-call overhead would be most of the cost.
    """
    w, x, y, z = (float(v) for v in quat)
    n2 = w * w + x * x + y * y + z * z
    if not n2 > 0:
        return None
    # third row of the rotation matrix (body -> world), i.e. the world z axis in body coordinates
    return 2 * (x * z - w * y) / n2, 2 * (y * z + w * x) / n2


class MocapLatency:
    """Estimates how late motion-capture poses arrive against the IMU (see the module docstring).

    :meth:`add_imu` and :meth:`add_mocap` are cheap (a row into a ring buffer under a lock of its own:
    the relay thread calls them every 2 ms); :meth:`update` copies the buffers and estimates outside
    that lock, in the caller's thread.

    Args:
        span: seconds of both streams each estimate reads.
        every: seconds between estimates.
        max_lag: largest lateness considered [s].
        step: lag grid [s] (refined by a parabola).
        min_motion: least standard deviation of the IMU's attitude over a span [rad] for an estimate.

    Attributes:
        latency: the reported lateness [s] (median of the last :data:`MEDIAN_OF` estimates, taken once
            :data:`AGREE` holds and kept until it holds again), or None before.
        estimates: (time [s], span estimate [s]) of every estimate made.

    Raises:
        ValueError: a setting out of range.
    """

    #: Ring-buffer rows: enough for the span at 1 kHz (IMU) and 250 Hz (poses).
    IMU_RATE, MOCAP_RATE = 1000, 250

    def __init__(self, span: float = 4.0, every: float = 1.0, max_lag: float = 0.08, step: float = 0.001,
                 min_motion: float = 0.003):
        if not (span > 0 and every > 0 and 0 < step <= max_lag < span and min_motion >= 0):
            raise ValueError("mocap latency: expected span > max_lag >= step > 0, every > 0, min_motion >= 0")
        self.span, self.every, self.max_lag, self.step, self.min_motion = span, every, max_lag, step, min_motion
        self._lock = threading.Lock()
        self._imu = np.zeros((int(self.IMU_RATE * (span + max_lag)) + 1, 3))
        self._mocap = np.zeros((int(self.MOCAP_RATE * span) + 1, 3))
        self._n = [0, 0]  # rows written to each
        self._next: float | None = None
        self.latency: float | None = None
        self.estimates: list[tuple[float, float]] = []

    def add_imu(self, t: float, quat) -> None:
        """An IMU attitude (4,) (w, x, y, z) received at ``t`` [s] (any clock, the same as :meth:`add_mocap`'s)."""
        self._add(0, self._imu, t, quat)

    def add_mocap(self, t: float, quat) -> None:
        """A motion-capture attitude (4,) (w, x, y, z) of the trunk that arrived at ``t`` [s]."""
        self._add(1, self._mocap, t, quat)

    def _add(self, which: int, buf: np.ndarray, t: float, quat) -> None:
        up = up_in_body(quat)
        if up is None:
            return
        with self._lock:
            buf[self._n[which] % len(buf)] = (t, *up)
            self._n[which] += 1

    def _rows(self, which: int, buf: np.ndarray) -> np.ndarray:
        n = self._n[which]
        return buf[:n].copy() if n <= len(buf) else np.roll(buf, -(n % len(buf)), axis=0)

    def update(self, now: float) -> float | None:
        """Estimate once ``every`` seconds have passed since the last; returns :attr:`latency`."""
        if self._next is not None and now < self._next:
            return self.latency
        self._next = now + self.every
        with self._lock:
            imu, moc = self._rows(0, self._imu), self._rows(1, self._mocap)
        lag = self.measure(imu, moc)
        if lag is not None:
            self.estimates.append((now, lag))
            last = np.array([e for _, e in self.estimates[-MEDIAN_OF:]])
            mid = float(np.median(last))
            if np.count_nonzero(np.abs(last - mid) <= AGREE[1]) >= AGREE[0]:
                self.latency = mid
        return self.latency

    def measure(self, imu: np.ndarray, moc: np.ndarray) -> float | None:
        """The lag [s] of poses ``moc`` against IMU samples ``imu``, or None (too little motion or data, or
        the best lag at an end of ``[0, max_lag]``).

        Args:
            imu, moc: (N, 3) rows of (time [s], :func:`up_in_body` x, y), oldest first.
        """
        if len(imu) < 10 or len(moc) < 10:
            return None
        imu = imu[imu[:, 0] >= imu[-1, 0] - self.span - self.max_lag]
        if imu[-1, 0] - imu[0, 0] < self.span / 2:
            return None  # too short a record yet to time against
        moc = moc[(moc[:, 0] - self.max_lag >= imu[0, 0]) & (moc[:, 0] <= imu[-1, 0])]
        if len(moc) < 10 or np.sqrt(imu[:, 1:].var(axis=0).sum()) < self.min_motion:
            return None
        lags = np.arange(0.0, self.max_lag + 1e-12, self.step)
        at = (moc[:, 0][None, :] - lags[:, None]).ravel()
        cost = np.zeros(len(lags))
        for k in (1, 2):
            ref = np.interp(at, imu[:, 0], imu[:, k]).reshape(len(lags), -1)
            cost += (moc[None, :, k] - ref).var(axis=1)  # each stream's mean removed: a constant tilt of the markers
        i = int(np.argmin(cost))
        if 0 < i < len(lags) - 1:  # a parabola through the best lag and its neighbours
            c0, c1, c2 = cost[i - 1], cost[i], cost[i + 1]
            den = c0 - 2 * c1 + c2
            shift = 0.5 * (c0 - c2) / den if den > 0 else 0.0
            return float(lags[i] + np.clip(shift, -1, 1) * self.step)
        return None  # the best lag at an end of the range: no minimum inside it to read
