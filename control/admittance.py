"""Sensorless admittance: the second lead-through strategy (issue 9; the paper's refs. [25, 26]).

The zero-moment law of the paper asks the closed velocity loop for the model's torque and lets
the operator's hand move the arm. Through a stiff vendor loop that sees each command a cycle
late, the hand's push is resisted until the next command catches up, and the operator pays
the arm's whole inertia. Admittance turns it round: the vendor loop keeps the arm on a
reference the product integrates, and the hand's torque is *measured* as what the drives give
beyond the model (no force sensor):

    τ̂_h = M̂(q) q̈_r + g(q) + f(q, q̇_r) − τ_cyl(q, p) − K i − b                        (A1)

with ``K i`` the motor torque in the datasheet's unit (the identified model is in that unit too, so
a drive-gain error scales τ̂_h and nothing else), q̈_r the reference acceleration of the cycle the
current was measured over (known exactly: the product computed it), and ``b`` the residual at rest
when teaching engages (the operator's hand on the handle but not pushing), which takes the model's
static error at that pose and the current sensors' offsets out. τ̂_h is low-passed (the motor
current's noise is several N·m on the big joints) and passes a dead zone of the model's uncertainty
(the rest hold's band, control/rt/src/law/rest_hold.rs): below it the arm stays where it is, however
long. Like a joint's friction, the zone has a static and a kinetic width: a joint at rest breaks
away only when the push exceeds :data:`NOISE_SIGMAS` standard deviations of the filtered estimate's
noise (measured on the currents while the arm rests in the hold before teaching engages; at least
the configured band), so noise alone seldom moves it; once one joint moves, the arm is being guided
and every joint follows every push beyond the configured band (the model's held-out RMS), which is
all the painter pays while guiding the tool, until every joint is back inside it or the reference
has crept slower than :data:`SETTLE_RAD_S` for :data:`SETTLE_S`. The reference then follows

    α M̂(q) q̈_r + D q̇_r = dz(τ̂_h) + τ_walls                                           (A2)

so the operator moves α of the arm's inertia (M̂: the identified model's, or the nominal rigid
body's with rotor inertias) against a viscous damping D. A hand that does not push beyond the
dead zone is no hand: there the damping is ``rest_factor`` × D, blended in linearly as the
push falls from the band's width above it to nothing, so the arm a painter lets go of stops
in a fraction of a second instead of coasting on its small virtual mass, and a model error
at the edge of the band creeps ``rest_factor`` times slower. The command sent is the reference
plus the offset at which the vendor loop delivers the model's torque (eq. 21's steady state,
``ω̂ τ / Υ̂_I``).

Discretisation: per controller cycle, low-pass by exact first order, then semi-implicit Euler
on (A2) with the damping implicit, ``q̇_r ← (α M̂ q̇_r + dt τ) / (α M̂ + dt D)``, which is
stable for any dt and any D ≥ 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

#: the dead zone is at least this many standard deviations of the filtered estimate's noise at
#: rest: a Gaussian sample passes 3.5 σ once in ~2,000 (about every 10 s at 250 Hz, for one
#: cycle, against the rest damping); 2 σ (the first setting tried) let the reference random-walk
#: 6 mm in 5 s on the virtual cell
NOISE_SIGMAS = 3.5


#: a guided arm whose reference has been slower than SETTLE_RAD_S [rad/s] on every joint for
#: SETTLE_S [s] is at rest again (it needs the static dead zone to break away): a painter's
#: guided tool moves at centimetres per second, a model error's creep at a millimetre
SETTLE_RAD_S, SETTLE_S = 2e-3, 0.3


class Admittance:
    """(A1) after the model, and (A2): the reference the vendor loop follows (module docstring).

    ``mass_fraction`` α, ``damping`` D per joint [N·m·s/rad], ``band_nm`` the dead zone per
    joint, ``filter_hz`` the low-pass of τ̂_h, ``max_velocity`` per joint [rad/s].
    """

    def __init__(
        self,
        mass_fraction: float,
        damping: Sequence[float],
        band_nm: Sequence[float],
        filter_hz: float,
        max_velocity: Sequence[float],
        rest_factor: float = 1.0,
    ) -> None:
        if not (math.isfinite(rest_factor) and rest_factor >= 1):
            raise ValueError(f"admittance rest damping factor {rest_factor} must be >= 1")
        self.rest_factor = float(rest_factor)
        if not (math.isfinite(mass_fraction) and 0 < mass_fraction <= 2):
            raise ValueError(f"admittance mass fraction {mass_fraction} not in (0, 2]")
        if not (math.isfinite(filter_hz) and filter_hz > 0):
            raise ValueError(f"admittance filter {filter_hz} Hz must be > 0")
        self.alpha = float(mass_fraction)
        self.damping = np.array(damping, dtype=float)
        self.band = np.array(band_nm, dtype=float)
        self.filter_hz = float(filter_hz)
        self.max_velocity = np.array(max_velocity, dtype=float)
        n = self.damping.size
        if not (self.band.size == n == self.max_velocity.size):
            raise ValueError("admittance damping, band and max velocity need one value per joint")
        if (self.damping < 0).any() or (self.band < 0).any() or (self.max_velocity <= 0).any():
            raise ValueError("admittance damping, band >= 0 and max velocity > 0 per joint")
        #: the configured dead zone; :meth:`reset` widens :attr:`band` to the measured noise
        self.base_band = self.band.copy()
        #: the arm is guided: a joint broke away (pushed beyond :attr:`band`) and not every
        #: joint is back inside :attr:`base_band` since
        self.moving = False
        self._slow_s = 0.0  #: how long the guided reference has been slower than SETTLE_RAD_S
        self.q_r = np.zeros(n)
        self.dq_r = np.zeros(n)
        self.ddq_r = np.zeros(n)
        self.tau_h = np.zeros(n)  #: the low-passed hand torque estimate [N·m]
        #: ``(q, dq) -> scale`` in (0, 1] that keeps a Cartesian speed limit (None: none)
        self.speed_limit: Callable[[np.ndarray, np.ndarray], float] | None = None

    def filtered_noise(self, raw_std_nm: np.ndarray, dt_s: float) -> np.ndarray:
        """The standard deviation of τ̂_h after the low-pass, for white noise of
        ``raw_std_nm`` per sample at steps of ``dt_s``: a first-order filter of coefficient a
        keeps a / (2 - a) of a white sequence's variance."""
        a = 1.0 - math.exp(-2.0 * math.pi * self.filter_hz * dt_s)
        return np.asarray(raw_std_nm, dtype=float) * math.sqrt(a / (2.0 - a))

    def reset(self, q_rad: np.ndarray, noise_std_nm: np.ndarray | None = None) -> None:
        """Start at rest at ``q_rad``; with ``noise_std_nm``, the filtered estimate's noise
        per joint [N·m] (:meth:`filtered_noise`), the dead zone is at least
        :data:`NOISE_SIGMAS` of it, so the noise alone seldom moves the arm."""
        self.band = self.base_band.copy()
        self.moving = False
        self._slow_s = 0.0
        if noise_std_nm is not None:
            self.band = np.maximum(self.band, NOISE_SIGMAS * np.asarray(noise_std_nm))
        self.q_r = np.array(q_rad, dtype=float)
        self.dq_r[:] = 0.0
        self.ddq_r[:] = 0.0
        self.tau_h[:] = 0.0

    def dead_zone(self, tau: np.ndarray) -> np.ndarray:
        """The push beyond the dead zone per joint: an arm at rest needs ``band`` on a joint
        to break away, a guided one follows every push beyond ``base_band`` while one joint
        has it (module docstring); updates :attr:`moving`."""
        over = np.abs(tau) - self.base_band
        self.moving = bool(self.moving or (np.abs(tau) > self.band).any()) and bool(
            (over > 0.0).any()
        )
        if not self.moving:
            return np.zeros_like(tau)
        return np.sign(tau) * np.maximum(over, 0.0)

    def step(
        self, tau_h_raw: np.ndarray, tau_walls: np.ndarray, mass: np.ndarray, dt_s: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Take in one cycle's raw hand torque estimate (A1) [N·m] and the walls' torque,
        with M̂ at the reference; returns the new reference ``(q_r, dq_r)``."""
        a = 1.0 - math.exp(-2.0 * math.pi * self.filter_hz * dt_s)
        self.tau_h += a * (tau_h_raw - self.tau_h)
        pushed = self.dead_zone(self.tau_h)
        drive = pushed + tau_walls
        # the push's share of the band: 0 (no hand) → rest_factor × D, ≥ 1 → D
        share = np.minimum(np.abs(pushed) / np.maximum(self.base_band, 1e-9), 1.0)
        damping = self.damping * (self.rest_factor - (self.rest_factor - 1.0) * share)
        m = self.alpha * mass
        lhs = m + dt_s * np.diag(damping)
        dq_new = np.linalg.solve(lhs, m @ self.dq_r + dt_s * drive)
        dq_new = np.clip(dq_new, -self.max_velocity, self.max_velocity)
        if self.speed_limit is not None:
            dq_new = dq_new * self.speed_limit(self.q_r, dq_new)
        self.ddq_r = (dq_new - self.dq_r) / dt_s
        self.q_r = self.q_r + dt_s * 0.5 * (self.dq_r + dq_new)
        self.dq_r = dq_new
        # a guided arm that has crept slower than SETTLE_RAD_S for SETTLE_S is at rest again:
        # a model error past the kinetic band at a new pose does not keep it creeping
        if self.moving and float(np.max(np.abs(dq_new))) < SETTLE_RAD_S:
            self._slow_s += dt_s
            if self._slow_s >= SETTLE_S:
                self.moving = False
        else:
            self._slow_s = 0.0
        return self.q_r, self.dq_r


#: the engagement probe's ramps to and from its cruise speed [s]
PROBE_RAMP_S = 0.05
#: a probe side needs this many sliding cruise samples for its median
PROBE_MIN_SAMPLES = 3


class EngageProbe:
    """The residual ``b`` of (A1) without the share of the load stiction carries.

    At rest a joint's friction carries any share of the load up to its static level, so the
    residual at rest is the model's error *plus* that share; once the joint slides the share
    is gone, and a ``b`` that kept it reads as a hand pushing along the motion: the arm runs
    away (1 m in 5 s on the virtual cell with stiction). The probe moves every joint out to
    one side, back, out to the other side and back, a trapezoid of velocity per quarter
    (``speed_rad_s`` per joint for most of it, ramps of :data:`PROBE_RAMP_S`, ``duration_s``
    in all, back where it started): the residual on the samples that slid at cruise speed (the
    command that drove them had no acceleration, and the joint moved the commanded way faster
    than ``slide_rad_s``) is the model's error minus the friction at that speed one way and
    plus it the other way, so the mean of the two sides' medians is the model's error alone
    (friction taken as symmetric). Each way is sampled as much on either side of the start, so
    a hand holding the tool on a spring (the painter's grip) pulls as much one way as the
    other and cancels too; the first probe, out and back on one side only, took the grip's
    pull into b (-5 N·m on J2 and J3 on the teach bench). A joint with
    fewer than :data:`PROBE_MIN_SAMPLES` on a side keeps the residual at rest beyond its
    friction level.
    """

    def __init__(
        self, speed_rad_s: np.ndarray, duration_s: float, period_s: float, slide_rad_s: float
    ) -> None:
        speed = np.asarray(speed_rad_s, dtype=float)
        quarter = max(2, round(0.25 * duration_s / period_s))
        t = np.arange(quarter) * period_s
        ramp = max(PROBE_RAMP_S, period_s)
        up = np.clip(np.minimum(t / ramp, (quarter * period_s - t) / ramp), 0.0, 1.0)
        shape = np.concatenate([up, -up, -up, up, [0.0]])
        #: per probe cycle: +1 / -1 at cruise that way (no acceleration), 0 elsewhere
        self.cruise = np.concatenate([[0.0], (shape[1:] == shape[:-1]) * np.sign(shape[1:])])
        #: per probe cycle and joint: the velocity command [rad/s] and the offset from the
        #: start [rad] (the sum of the velocities before it: back to 0 at the end)
        self.velocity = shape[:, None] * speed[None, :]
        self.offset = np.vstack([np.zeros_like(speed), np.cumsum(self.velocity[:-1], 0) * period_s])
        self.slide_rad_s = float(slide_rad_s)
        self.n = n = speed.size
        self._sides: tuple[list[list[float]], ...] = tuple(([], []) for _ in range(n))  # type: ignore[assignment]

    def __len__(self) -> int:
        return len(self.velocity)

    def observe(self, k: int, dq_rad_s: np.ndarray, residual_nm: np.ndarray) -> None:
        """The state measured over the cycle the probe's sample ``k`` drove: its velocity
        and the residual ``model(q, 0, q̈) − K i`` (no friction in the model's part)."""
        if not 0 <= k < len(self.cruise) or self.cruise[k] == 0.0:
            return
        way = self.cruise[k]
        for j in range(self.n):
            if way * dq_rad_s[j] > self.slide_rad_s:
                self._sides[j][0 if way > 0 else 1].append(float(residual_nm[j]))

    def samples(self) -> list[tuple[int, int]]:
        """(samples sliding +, samples sliding −) per joint."""
        return [(len(a), len(b)) for a, b in self._sides]

    def bias(self, at_rest_nm: np.ndarray, stick_nm: np.ndarray) -> tuple[np.ndarray, list[int]]:
        """``b`` per joint, and the joints that did not slide both ways (too few samples):
        theirs is the residual at rest ``at_rest_nm`` less what friction may have carried
        there, ``stick_nm`` (towards 0; a stuck joint's residual within it is no error)."""
        at_rest = np.asarray(at_rest_nm, dtype=float)
        b = np.sign(at_rest) * np.maximum(np.abs(at_rest) - np.asarray(stick_nm), 0.0)
        kept = []
        for j, (pos, neg) in enumerate(self._sides):
            if min(len(pos), len(neg)) >= PROBE_MIN_SAMPLES:
                b[j] = 0.5 * (float(np.median(pos)) + float(np.median(neg)))
            else:
                kept.append(j)
        return b, kept
