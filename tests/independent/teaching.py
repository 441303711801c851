"""Test motions with slow teaching-like stretches (the hard world, :mod:`.world`).

A test run is the declared world's multisine test excitation x(τ) (:class:`.family.Excitation`)
played on a warped clock τ(t), interrupted by teaching stretches. Before a stretch the
multisine's clock slows to a stop over a ramp of R s (clock speed s = 1 - σ(u), σ the quintic
smoothstep 10u³ - 15u⁴ + 6u⁵, u = (t - t_0)/R): the arm follows the multisine's own path and
comes to rest with zero velocity and acceleration at q_stop. Then the stretch, as an operator
teaching points by hand would move: rests of 0.5-3 s and point-to-point moves of 2-4 joints
together, each a minimum-jerk profile (q = q_0 + D σ(u), peak speed 1.875 D/T) of 1.5-4 s at
0.02-0.2 rad/s peak per joint, every move out followed (after a rest) by the same move back (a
reversal), towards the roomier joint limit and inside the limits; the stretch ends at rest at
q_stop, and the multisine's clock speeds up again over R s (s = σ(u)). q, dq, ddq are continuous
everywhere: dq = x'(τ) s, ddq = x''(τ) s² + x'(τ) ds/dt.

Layout (:func:`plan_test_motion`): the holdout (the last :data:`.referee.HOLDOUT_SHARE` of the
run) starts inside a teaching stretch, whose part in the holdout is half the holdout minus R/2,
followed by the ramp back and multisine for the rest: teaching and multisine each about 45 % of
the holdout (R = min(1 s, 10 % of the holdout)). The part of the test run analyze sees holds
one shorter stretch (10-20 % of it) at about 40 % of its length when there is room.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

REST_S = (0.5, 3.0)
MOVE_S = (1.5, 4.0)
TEACH_SPEED_RAD_S = (0.02, 0.2)
JOINTS_PER_MOVE = (2, 4)
RAMP_S = 1.0
LIMIT_MARGIN = 0.05  # of the half range

MULTISINE, RAMP, REST, MOVE = "multisine", "ramp", "rest", "move"


def smoothstep(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """σ(u), σ'(u), σ''(u) and ∫_0^u σ, u clipped to [0, 1]."""
    u = np.clip(u, 0.0, 1.0)
    return (
        u**3 * (10.0 - 15.0 * u + 6.0 * u * u),
        30.0 * u**2 * (1.0 - u) ** 2,
        60.0 * u - 180.0 * u**2 + 120.0 * u**3,
        u**4 * (2.5 - 3.0 * u + u * u),
    )


@dataclass(frozen=True)
class Segment:
    """One part of a stretch: ``kind`` rest or move, start [s] from the stretch's start,
    duration [s], displacement (n,) [rad] (zeros for a rest)."""

    kind: str
    start: float
    duration: float
    delta: np.ndarray


@dataclass(frozen=True)
class Stretch:
    """A teaching stretch from ``t0`` [s] (the arm at rest at q_stop) lasting ``length``."""

    t0: float
    segments: tuple[Segment, ...]

    @property
    def length(self) -> float:
        last = self.segments[-1]
        return last.start + last.duration


def plan_stretch(
    rng: np.random.Generator,
    target_s: float,
    q_stop: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> tuple[Segment, ...]:
    """Rests and out-and-back moves from ``q_stop`` for about ``target_s`` [s] (at least one
    out-and-back; the last rest may end past the target). The timing takes the same draws
    whatever ``q_stop`` and the limits are."""
    n = q_stop.size
    margin = LIMIT_MARGIN * 0.5 * (upper - lower)
    room_up, room_down = upper - margin - q_stop, q_stop - (lower + margin)
    segs: list[Segment] = []
    t = 0.0

    def add(kind: str, duration: float, delta: np.ndarray) -> None:
        nonlocal t
        segs.append(Segment(kind, t, float(duration), delta))
        t += float(duration)

    while True:
        add(REST, rng.uniform(*REST_S), np.zeros(n))
        k = int(rng.integers(JOINTS_PER_MOVE[0], min(JOINTS_PER_MOVE[1], n) + 1))
        joints = rng.choice(n, k, replace=False)
        speeds = rng.uniform(*TEACH_SPEED_RAD_S, k)
        out_s, rest_s = rng.uniform(*MOVE_S), rng.uniform(*REST_S)
        back_s = out_s  # the same profile back: the same peak speeds
        # one out-and-back at least; more while they end before the target
        if len(segs) > 1 and t + out_s + rest_s + back_s + REST_S[0] > target_s:
            break
        delta = np.zeros(n)
        for j, v in zip(joints, speeds, strict=True):
            up = room_up[j] >= room_down[j]
            room = max(room_up[j] if up else room_down[j], 0.0)
            size = min(v * out_s / 1.875, 0.9 * room)
            delta[j] = size if up else -size
        add(MOVE, out_s, delta)
        add(REST, rest_s, np.zeros(n))
        add(MOVE, back_s, -delta)
    return tuple(segs)


@dataclass(frozen=True)
class TestMotion:
    """The multisine ``exc`` on the warped clock with teaching ``stretches`` (module
    docstring), ramps of ``ramp_s`` [s]."""

    exc: Any
    stretches: tuple[Stretch, ...]
    ramp_s: float

    def _clock(self, t: np.ndarray):
        """τ(t), s(t), ds/dt and the index of the stretch a sample is in (-1 outside)."""
        tau, s, ds = t.astype(float).copy(), np.ones_like(t), np.zeros_like(t)
        inside = np.full(t.shape, -1)
        r = self.ramp_s
        shift = 0.0  # how far the clock lags t after the stretches passed
        for i, st in enumerate(self.stretches):
            d0, u0 = st.t0 - r, st.t0 + st.length  # ramp down start, ramp up start
            down = (t >= d0) & (t < st.t0)
            sig, dsig, _, integral = smoothstep((t[down] - d0) / r)
            tau[down] = d0 - shift + r * ((t[down] - d0) / r - integral)
            s[down], ds[down] = 1.0 - sig, -dsig / r
            stop = d0 - shift + 0.5 * r
            still = (t >= st.t0) & (t < u0)
            tau[still], s[still] = stop, 0.0
            inside[still] = i
            up = (t >= u0) & (t < u0 + r)
            sig, dsig, _, integral = smoothstep((t[up] - u0) / r)
            tau[up], s[up], ds[up] = stop + r * integral, sig, dsig / r
            after = t >= u0 + r
            shift = (u0 + r) - (stop + 0.5 * r)
            tau[after] = t[after] - shift
        return tau, s, ds, inside

    def q_stop(self, i: int) -> np.ndarray:
        """Where the multisine stops before stretch ``i``."""
        tau, _, _, _ = self._clock(np.array([self.stretches[i].t0]))
        return self.exc.evaluate(tau)[0][0]

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q [rad], dq [rad/s], ddq [rad/s²] at times ``t`` [s], each (T, n)."""
        t = np.asarray(t, dtype=float)
        tau, s, ds, inside = self._clock(t)
        x, dx, ddx = self.exc.evaluate(tau)
        q, dq = x, dx * s[:, None]
        ddq = ddx * (s * s)[:, None] + dx * ds[:, None]
        for i, st in enumerate(self.stretches):
            rows = inside == i
            if not rows.any():
                continue
            tt = t[rows] - st.t0
            qi = np.repeat(x[rows][:1], rows.sum(), axis=0)  # q_stop
            dqi, ddqi = np.zeros_like(qi), np.zeros_like(qi)
            for seg in st.segments:
                if seg.kind != MOVE:
                    continue
                sig, dsig, ddsig, _ = smoothstep((tt - seg.start) / seg.duration)
                qi += sig[:, None] * seg.delta
                dqi += (dsig / seg.duration)[:, None] * seg.delta
                ddqi += (ddsig / seg.duration**2)[:, None] * seg.delta
            q[rows], dq[rows], ddq[rows] = qi, dqi, ddqi
        return q, dq, ddq

    def labels(self, t: np.ndarray) -> np.ndarray:
        """Per sample: multisine, ramp, rest or move."""
        t = np.asarray(t, dtype=float)
        out = np.full(t.shape, MULTISINE, dtype=object)
        for st in self.stretches:
            out[(t >= st.t0 - self.ramp_s) & (t < st.t0 + st.length + self.ramp_s)] = RAMP
            for seg in st.segments:
                a = st.t0 + seg.start
                out[(t >= a) & (t < a + seg.duration)] = seg.kind
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "ramp_s": self.ramp_s,
            "stretches": [
                {
                    "t0_s": st.t0,
                    "length_s": st.length,
                    "segments": [
                        {"kind": g.kind, "start_s": g.start, "duration_s": g.duration,
                         "delta_rad": g.delta.tolist(),
                         "peak_speed_rad_s": (1.875 * np.abs(g.delta) / g.duration).tolist()}
                        for g in st.segments
                    ],
                }
                for st in self.stretches
            ],
        }  # fmt: skip


def plan_test_motion(
    exc: Any, t_cut: float, t_end: float, lower: np.ndarray, upper: np.ndarray, rng
) -> TestMotion:
    """The test run's motion (module docstring): the holdout is [t_cut, t_end) [s]. A plan's
    timing takes the same draws whatever q_stop is, so a stretch is timed first (to know where
    it starts), then planned again from the same stream at its q_stop."""
    holdout = t_end - t_cut
    r = min(RAMP_S, 0.1 * holdout)
    inside = 0.5 * holdout - 0.5 * r  # teaching in the holdout
    early_seed, late_seed = (int(v) for v in rng.integers(2**32, size=2))
    early_t0 = 0.4 * t_cut
    early_target = rng.uniform(0.1, 0.2) * t_cut
    q0 = exc.evaluate(np.array([early_t0 - 0.5 * r]))[0][0]
    early = Stretch(
        early_t0, plan_stretch(np.random.default_rng(early_seed), early_target, q0, lower, upper)
    )
    late_length = Stretch(0.0, _timing(late_seed, inside, lower.size)).length
    t0 = t_cut + inside - late_length
    stretches = [early] if early_t0 + early.length + r < t0 - 2.0 * r else []
    tau, _, _, _ = TestMotion(exc, tuple(stretches), r)._clock(np.array([t0 - r]))
    q_stop = exc.evaluate(tau + 0.5 * r)[0][0]
    late = plan_stretch(np.random.default_rng(late_seed), inside, q_stop, lower, upper)
    stretches.append(Stretch(t0, late))
    return TestMotion(exc, tuple(stretches), r)


def _timing(seed: int, target_s: float, n: int) -> tuple[Segment, ...]:
    """The segments :func:`plan_stretch` draws from ``seed``, with the limits out of reach."""
    big = np.full(n, 1e9)
    return plan_stretch(np.random.default_rng(seed), target_s, np.zeros(n), -big, big)
