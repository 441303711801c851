"""Column groups of the identified model: rigid body, friction, and the effect vocabulary.

A *term* turns samples (a :class:`Context`) into regressor columns, per joint it acts on, and
its fitted coefficients into named physical parameters. The same term objects build the
columns for fitting (:mod:`.fit`, :mod:`.effects`) and evaluate the loaded model
(:class:`.model.IdentifiedModel`), so the two cannot drift apart.

Effect vocabulary (names are part of the model and report formats; joints are 1-based there,
0-based in code). Each adds ``columns @ coefficients`` to the joint torque:

Bounded extrapolation: every friction and effect column that is not bounded by construction
sees its input clipped to the training envelope (:class:`Envelope`, carried in the
:class:`Context` and the model file), so no fitted term grows beyond what it was fitted on:
outside the envelope it holds its value at the envelope's edge. That is every velocity input
(viscous ``dq``, eq. (15)'s ``dq |dq|``). Periodic functions of the position (``sin(c q)``,
the friction families' Fourier terms) are bounded by their amplitude everywhere and stay
periodic — clipping them would cut a gear ripple off wherever the test motion leaves the
training range. The rigid-body and payload columns are physics and are not clipped, nor is the
spring's position: Hooke's law is physics too (a balancer spring held at the envelope's edge,
named within 1 %, was 21.6 N·m off where the test run left the joint's range; the guard still
falls back where a spring extrapolates worse than plain least squares). ``thermal_drift`` is
linear in time by definition.

Filtering: when the :class:`Context` carries the measured torque's low-pass (``lowpass``),
every column is passed through it, so the model is fitted to and judged on the filtered
torque with the same filter on both sides (:meth:`.preprocess.Prepared.lowpass`). Where the
analysis rate is below the recorded one, the friction columns and the effect columns with a
velocity sign in them are first averaged over the recorded samples each kept sample stands for
(:meth:`Context.sample_mean`), so a friction reversal falls where the filtered measurement has
it, not on the decimated grid.

- ``position_ripple`` on joint j: ``sin(c q_j)``, ``cos(c q_j)``, c scanned; parameters
  ``cycles_per_rev`` c, ``amplitude_nm`` A, ``phase_rad`` φ (``A sin(c q_j + φ)``).
- ``payload``, all joints (or those listed: a joint kept on plain least squares drops out):
  the last link's ten regressor columns [m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz];
  parameters ``mass_kg``, ``com_m`` (in the last link's frame, as the URDF/pinocchio defines
  it) and ``inertia_at_origin_kgm2`` (about that frame's origin).
- ``spring`` on joint j: ``q_j``, ``1``; parameters ``k_nm_per_rad``, ``q0_rad`` and
  ``torque_at_zero_nm`` (= -k q0). A restoring spring (k > 0) pushes with ``-k (q - q0)``, which
  the motor must add: ``+k (q_j - q0)``. With k ≈ 0 it is a constant torque offset.
- ``stribeck`` on joint j: ``exp(-(dq_j/v_s)²) sgn(dq_j)``; parameters ``amplitude_nm``,
  ``velocity_rad_s`` v_s. Read from model files; the search no longer offers it: a Stribeck
  curve of another shape than the family's is the friction's own
  (:attr:`FrictionTerm.stribeck_rad_s`), not an effect the model lacks.
- ``load_dependent_friction`` on joint j: ``|τ_rigid,j| sgn(dq_j)`` with τ_rigid the model's
  rigid-body torque; parameter ``coefficient``.
- ``time_delay``, all joints: no columns; the measured torque lags the kinematics by δ,
  ``τ_meas(t) = τ_model(t - δ)``, δ scanned; parameter ``delay_s``.
- ``thermal_drift`` on joint j: friction that changes as the gear warms, ``t sgn(dq_j)`` and
  ``t dq_j`` (t each file's own clock [s]): the Coulomb and viscous levels drift linearly in
  time; parameters ``rate_nm_per_s`` (Coulomb level change per second, negative when the
  friction drops) and ``viscous_rate_nm_per_rad`` (viscous coefficient change per second,
  [N·m·s/rad per s]). A warming gear's drift multiplies the sign of the velocity; a plain
  ``t`` column (a growing offset) left it half-absorbed by spurious negative Stribeck terms.
- ``wrist_coupling`` on joint j from joint k (k ≠ j, both of the wrist,
  :func:`.effect_candidates.wrist_start`): joint k's
  model torque (rigid + friction, ``source = "torque"``) or its friction torque
  (``source = "friction"``); parameters ``from_joint`` k, ``coefficient``, ``source``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from control.identification.envelope import Envelope
from control.identification.friction_law import (
    FRICTION_PARAM_NAMES,
    STRIBECK_PARAM_NAMES,
    friction_basis,
    friction_memory,
    gaussian_stribeck,
    qe_columns,
    qe_part,
    rest_log_odds_per_joint,
    rest_probability,
)

EFFECT_NAMES = (
    "position_ripple",
    "payload",
    "spring",
    "stribeck",
    "load_dependent_friction",
    "time_delay",
    "thermal_drift",
    "wrist_coupling",
)
COUPLING_SOURCES = ("torque", "friction")


@dataclass
class Context:
    """Samples a term needs; arrays (T, n) unless noted.

    ``y_base`` (n, T, nb) base regressor per joint and ``y_payload`` (n, T, 10) the last link's
    regressor columns (None until computed; already filtered when ``lowpass`` is set);
    ``rigid`` and ``friction`` [N·m] are the current model's rigid-body and friction torques,
    needed by terms built on the model itself (load-dependent friction, wrist coupling).
    ``envelope`` clips the inputs of friction and effect terms, ``lowpass`` filters every
    column like the measured torque (module docstring); both None at run time. ``sample_hz``
    and ``raw_hz`` (T,) are each sample's rate after decimation and as recorded
    (:class:`.preprocess.Prepared`): where a kept sample stands for several recorded ones, the
    velocity-discontinuous columns are averaged over them (:meth:`sample_mean`); None at run
    time.
    """

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    t: np.ndarray | None = None
    y_base: np.ndarray | None = None
    y_payload: np.ndarray | None = None
    rigid: np.ndarray | None = None
    friction: np.ndarray | None = None
    envelope: Envelope | None = None
    lowpass: Callable[[np.ndarray], np.ndarray] | None = None
    sample_hz: np.ndarray | None = None
    raw_hz: np.ndarray | None = None
    #: (n,) the std of the noise on friction's velocity [rad/s] (None or 0: exact): each
    #: function of it is taken in expectation over it (:meth:`sample_mean`)
    dq_noise: np.ndarray | None = None
    #: (T, n) the log prior odds that each joint rests (:func:`.friction_law.rest_log_odds`,
    #: :attr:`.preprocess.Prepared.dq_rest_odds`) with which :meth:`sample_mean` and
    #: :meth:`memory` weigh each reading; (n,) for every row alike; None: estimated from
    #: these rows' own velocities, all taken as one motion
    rest_odds: np.ndarray | None = None
    #: True: the rows are one motion in time order, whose history a friction with memory
    #: follows (:meth:`memory`); False: unrelated states (one sample at run time): it slides
    sequence: bool = True
    #: friction's memory given by a caller that follows the motion across several contexts
    #: (:meth:`.model.IdentifiedModel.friction_directions`): (T, n, 2) each joint's direction
    #: and speed (:func:`.friction_law.friction_memory`), or (T, n) directions alone (the
    #: speed then 0: the static level at rest); None: computed here
    directions: np.ndarray | None = None
    #: (T, n) friction's velocity (:mod:`.friction_velocity`; None: ``dq``)
    dq_friction: np.ndarray | None = None
    #: (T, 3) how each sample of a resampled recording mixes the recorded samples around it
    #: (:attr:`.preprocess.Prepared.resample_mix`; None: it does not): :meth:`sample_mean`
    #: mixes each friction column as the torque was mixed
    resample_mix: np.ndarray | None = None
    _directions: dict[tuple[int, float], tuple[np.ndarray, np.ndarray]] = field(
        default_factory=dict, repr=False, compare=False
    )
    #: :meth:`FrictionTerm.columns`' last, by what they depend on but q_e (one entry)
    _friction_at: dict[tuple, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_rows(self) -> int:
        return int(self.q.shape[0])

    def q_of(self, j: int) -> np.ndarray:
        """Joint j's positions [rad], clipped to the envelope."""
        q = self.q[:, j]
        return q if self.envelope is None else self.envelope.clip_q(j, q)

    @property
    def v_friction(self) -> np.ndarray:  # :attr:`dq_friction`, else ``dq``
        return self.dq if self.dq_friction is None else self.dq_friction

    def _odds(self) -> np.ndarray:
        """:attr:`rest_odds`, estimated from the rows' velocities under :attr:`dq_noise` the
        first time when none were given, and kept."""
        if self.rest_odds is None:
            self.rest_odds = rest_log_odds_per_joint(self.v_friction, self.dq_noise)
        return np.asarray(self.rest_odds, dtype=float)

    def rest_log_odds(self, j: int) -> np.ndarray:
        """Joint j's log prior odds of rest per row, (T,) (:meth:`_odds`)."""
        odds = self._odds()
        return odds[:, j] if odds.ndim == 2 else np.full(self.dq.shape[0], odds[j])

    def memory(self, j: int, presliding_rad: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint j's friction memory (:func:`friction_memory`): its direction and its speed,
        each (T,); computed once per joint and presliding travel."""
        if self.directions is not None:
            given = np.asarray(self.directions)
            if given.ndim == 3:
                return given[:, j, 0], given[:, j, 1]
            return given[:, j], np.zeros(given.shape[0])
        key = (j, float(presliding_rad))
        if key not in self._directions:
            sigma = 0.0 if self.dq_noise is None else float(self.dq_noise[j])
            self._directions[key] = friction_memory(
                self.q[:, j], self.v_friction[:, j], sigma, presliding_rad,
                log_odds=self.rest_log_odds(j),
            )  # fmt: skip
        return self._directions[key]

    def sample_mean(
        self,
        j: int,
        fn: Callable[[np.ndarray], np.ndarray],
        at_rest_fn: Callable[[], np.ndarray] | None = None,
    ) -> np.ndarray:
        """``fn`` (columns (T,) or (T, m) of a velocity array (T,)) of joint j's velocity,
        clipped to the envelope, per sample averaged over the recorded samples it stands for.

        The measured torque was low-passed at the recorded rate and then decimated
        (:mod:`.preprocess`), so a friction reversal sits in it where the velocity crossed zero
        to within one *recorded* sample. A column computed only at the kept samples jumps on
        the decimated grid instead, up to ``raw_hz / sample_hz`` recorded samples off; the
        fit then bends the friction's shape (a wider smooth sign, another Stribeck velocity)
        to stand in for that timing error, and the bent shape is tuned to how fast the
        training motion crosses zero, not to the friction: a run reversing at other
        accelerations gets it wrong. Here each kept sample's column is the mean of ``fn`` at
        the recorded samples around it, the velocity carried there by the acceleration
        (``dq + ddq δ``, δ their time offsets): the reversal lands at its recorded time, as
        in the measurement. One recorded sample per kept one (or no rates known) is ``fn``
        of the velocity itself. ``at_rest_fn``: the columns of a resting joint per sample
        (T, m) where they are not ``fn`` at 0 (a friction with memory holds the level of its
        last motion, :class:`FrictionTerm`).
        """
        dq = self.v_friction[:, j]
        env = self.envelope

        def exact(v: np.ndarray) -> np.ndarray:
            out = np.asarray(fn(v if env is None else env.clip_dq(j, v)), dtype=float)
            return out[:, None] if out.ndim == 1 else out

        sigma = 0.0 if self.dq_noise is None else float(self.dq_noise[j])
        odds = self.rest_log_odds(j) if np.isfinite(sigma) and sigma > 0.0 else None
        # ``fn`` at rest is the same for every recorded sample a kept one stands for: once
        at_rest = None
        if odds is not None:
            at_rest = exact(np.zeros_like(dq)) if at_rest_fn is None else at_rest_fn()

        def at(v: np.ndarray) -> np.ndarray:
            """``fn`` in expectation over whether the joint moves (class docstring). A joint
            at rest reads its velocity noise, and ``fn`` of that alone takes a coin toss's sign
            at face value: ± the Coulomb level from one sample to the next while the joint
            holds still. Given the measured v̂, the joint rests with the probability
            :func:`rest_probability` under the prior :meth:`rest_log_odds`, and there
            friction is ``fn`` at 0 (no sign, nothing a function of the velocity can know of
            the torque a stuck joint holds); it moves with the rest, at v̂."""
            if at_rest is None:  # no velocity noise: the joint moves at v
                return exact(v)
            rest = rest_probability(v, sigma, odds)[:, None]
            return rest * at_rest + (1.0 - rest) * exact(v)

        ddq = self.ddq[:, j]
        if self.sample_hz is None or self.raw_hz is None or dq.size == 0:
            return self._resampled(at, dq, ddq)
        raw = np.asarray(self.raw_hz, dtype=float)
        k = np.maximum(1, np.round(raw / np.asarray(self.sample_hz, dtype=float))).astype(int)
        if int(k.max()) == 1:
            return self._resampled(at, dq, ddq)
        acc: np.ndarray | None = None
        for i in range(int(k.max())):
            live = i < k
            dt = np.where(live, (i - 0.5 * (k - 1)) / raw, 0.0)
            part = at(dq + ddq * dt) * (live / k)[:, None]
            acc = part if acc is None else acc + part
        assert acc is not None
        if int(k.min()) > 1:  # every kept sample stands for several: the mean alone
            return acc
        # a kept sample that stands for one recorded (or resampled) sample: as that one
        return np.where((k == 1)[:, None], self._resampled(at, dq, ddq), acc)

    def _resampled(
        self, at: Callable[[np.ndarray], np.ndarray], dq: np.ndarray, ddq: np.ndarray
    ) -> np.ndarray:
        """``at`` of the velocity per sample, mixed over the two recorded samples around it
        where the recording was resampled onto a uniform grid (:attr:`resample_mix`), as the
        torque there was mixed; the velocity at each is carried by the acceleration. Where a
        kept sample stands for several (decimation), their mean above has the larger share
        of the blur, and this is not applied to them."""
        mix = self.resample_mix
        if mix is None or dq.size == 0 or not np.any(mix[:, 2] > 0.0):
            return at(dq)
        w = mix[:, 2:3]
        return (1.0 - w) * at(dq + ddq * mix[:, 0]) + w * at(dq + ddq * mix[:, 1])

    def _rest_odds_of(self, index: np.ndarray | slice) -> np.ndarray | None:
        """:attr:`rest_odds` for the rows ``index`` (a subset keeps its parent's prior)."""
        if self.dq.ndim != 2 or self.dq.shape[1] == 0:
            return self.rest_odds
        odds = self._odds()
        return odds[index] if odds.ndim == 2 else odds

    def filtered(self, cols: np.ndarray) -> np.ndarray:
        """Columns (T, m) through :attr:`lowpass` (unchanged without one)."""
        return cols if self.lowpass is None else self.lowpass(cols)

    def rows(self, index: np.ndarray | slice) -> Context:
        """The samples ``index`` (rows) of this context; the filter is kept only for a slice,
        which keeps segments contiguous."""

        def take(a: np.ndarray | None, axis: int = 0) -> np.ndarray | None:
            if a is None:
                return None
            return a[index] if axis == 0 else a[:, index]

        return Context(
            self.q[index],
            self.dq[index],
            self.ddq[index],
            take(self.t),
            take(self.y_base, 1),
            take(self.y_payload, 1),
            take(self.rigid),
            take(self.friction),
            self.envelope,
            None,
            take(self.sample_hz),
            take(self.raw_hz),
            self.dq_noise,
            self._rest_odds_of(index),
            self.sequence,
            take(self.directions),
            take(self.dq_friction),
            take(self.resample_mix),
        )


@dataclass(frozen=True)
class RigidTerm:
    """``Y_b(q, dq, ddq) β``: the base-parameter rigid-body model, all joints."""

    key: str = "rigid"

    def columns(self, ctx: Context) -> dict[int, np.ndarray]:
        assert ctx.y_base is not None
        return {j: ctx.y_base[j] for j in range(ctx.y_base.shape[0])}


@dataclass(frozen=True)
class FrictionTerm:
    """Friction of one joint (0-based ``joint``) with transition velocity ``q_e`` [rad/s] and,
    for eq. (15), the smooth sign's own width ``sign_width_rad_s`` (None: q_e).

    With ``presliding_rad`` x_c set, the friction has memory: the family's sign of the
    velocity becomes the state of Dahl's model over the joint's travel
    (:func:`friction_memory`), which turns round over x_c of travel after a reversal and
    holds at rest. A gear's friction is a deformation of its contacts before it is a sliding:
    after a reversal the torque crosses from one level to the other over a small travel, not
    at one velocity, and a joint that stops keeps the torque its last motion loaded the teeth
    with (LuGre, Dahl, Maxwell-slip models). A memoryless law puts zero friction at rest, a
    whole static level off at every pause of a teaching motion. Columns are then the family's
    with ``direction`` for the sign, taken in expectation over whether the joint moves
    (:meth:`Context.sample_mean`): at rest the level of the joint's last presliding travel in
    the held direction, its Stribeck rises taken at the speed it had there
    (:func:`friction_memory`): the sliding level after a stop from speed, the static level
    (eq. 15's τ_s + τ_c) after a creep. In a context that is not a sequence
    (:attr:`Context.sequence`) the joint slides: the family's own sign.

    With ``stribeck_rad_s`` v_s set, the friction has a second Stribeck rise, of Gaussian shape
    (Armstrong's ``exp(-(dq/v_s)²)``, LuGre's steady state), beside the family's own (eq. 15's
    ``exp(-|dq|/q_e)``): drives differ in how their friction falls from the static level, and
    a shape the family lacks is the friction's, not an effect the model lacks. It was an effect
    of the search (``stribeck``), and was named on joints whose Stribeck curve had another
    shape than eq. (15)'s (issue 46: on the hidden cases beside a gear ripple and a coupling;
    on the hard world's Lorentz and power-law curves and LuGre joints).
    """

    joint: int
    kind: str
    q_e_rad_s: float
    gear_ratio: float
    sign_width_rad_s: float | None = None
    presliding_rad: float | None = None
    #: v_s [rad/s] of a Gaussian Stribeck rise beside the family's own (None: none): one more
    #: column ``exp(-(dq / v_s)²) sgn(dq)`` (the direction with memory)
    stribeck_rad_s: float | None = None

    @property
    def key(self) -> str:
        return f"friction-{self.kind}:{self.joint}"

    def columns(self, ctx: Context) -> dict[int, np.ndarray]:
        j = self.joint
        q = ctx.q_of(j)
        direction = speed = None
        if self.presliding_rad is not None and ctx.sequence:
            direction, speed = ctx.memory(j, self.presliding_rad)
        v_s = self.stribeck_rad_s
        kind, q_e, width = self.kind, self.q_e_rad_s, self.sign_width_rad_s
        # the columns that depend on q_e: the Stribeck rise (the others are the same for
        # every q_e, so a search over q_e computes them once)
        moving = qe_columns(kind, width, direction is not None)

        def basis(dq: np.ndarray) -> np.ndarray:
            return friction_basis(kind, q, dq, q_e, self.gear_ratio, width, direction)

        def stribeck(dq: np.ndarray) -> np.ndarray:
            return qe_part(kind, dq, q_e, width, direction)

        def columns(
            fn: Callable[[np.ndarray], np.ndarray], at_speed: Callable[[], np.ndarray] | None
        ) -> np.ndarray:
            return ctx.filtered(ctx.sample_mean(j, fn, at_speed))

        # A friction with memory at rest holds the level of its last motion: the Stribeck
        # rises taken at the speed of the joint's last x_c of travel (friction_memory), the
        # rest as at 0 (no viscous part).
        basis_at_rest = stribeck_at_rest = gauss_at_rest = None
        if speed is not None:
            held = speed

            def basis_at_rest() -> np.ndarray:
                out = basis(np.zeros_like(held))
                if moving:
                    out[:, moving] = stribeck(held)
                return out

            def stribeck_at_rest() -> np.ndarray:
                return stribeck(held)

            if v_s is not None:

                def gauss_at_rest() -> np.ndarray:
                    return gaussian_stribeck(held, v_s, direction)[:, None]

        # Every step is column by column, so the columns that do not depend on q_e are those
        # of the last call that differed only in q_e, to the last bit (a search over q_e).
        memory = self.presliding_rad if direction is not None else None
        key = (j, kind, self.gear_ratio, width, memory)
        kept = None if moving is None else ctx._friction_at.get(key)
        if kept is None:
            out = columns(basis, basis_at_rest)
            if moving is not None:
                ctx._friction_at.clear()
                ctx._friction_at[key] = out.copy()
        else:
            out = kept.copy()
            if moving:
                out[:, moving] = columns(stribeck, stribeck_at_rest)
        if v_s is not None:
            gauss = columns(lambda dq: gaussian_stribeck(dq, v_s, direction), gauss_at_rest)
            out = np.column_stack([out, gauss])
        return {j: out}

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the fitted coefficients, in column order."""
        extra = STRIBECK_PARAM_NAMES if self.stribeck_rad_s is not None else ()
        return (*FRICTION_PARAM_NAMES[self.kind], *extra)

    def parameters(self, coef: np.ndarray) -> dict[str, float]:
        out = {name: float(v) for name, v in zip(self.parameter_names, coef, strict=True)}
        out["q_e_rad_s"] = float(self.q_e_rad_s)
        if self.kind == "eq15":
            out["gear_ratio"] = float(self.gear_ratio)
        if self.sign_width_rad_s is not None:
            out["sign_width_rad_s"] = float(self.sign_width_rad_s)
        if self.presliding_rad is not None:
            out["presliding_rad"] = float(self.presliding_rad)
        if self.stribeck_rad_s is not None:
            out["gauss_stribeck_rad_s"] = float(self.stribeck_rad_s)
        return out


@dataclass(frozen=True)
class EffectTerm:
    """One effect of the vocabulary (module docstring); ``joints`` are 0-based here.

    ``setting`` holds what is fixed before the linear fit (scanned values: cycles per rev,
    v_s, delay; the source joint of a coupling).
    """

    name: str
    joints: tuple[int, ...]
    setting: dict[str, Any] = field(default_factory=dict)

    @property
    def key(self) -> str:
        extra = ",".join(f"{k}={v}" for k, v in sorted(self.setting.items()))
        return f"{self.name}:{'/'.join(map(str, self.joints))}:{extra}"

    @property
    def is_linear(self) -> bool:
        """False for the time delay, which shifts signals instead of adding columns."""
        return self.name != "time_delay"

    def columns(self, ctx: Context) -> dict[int, np.ndarray]:
        """Columns per joint acted on, clipped to the envelope and filtered (module docstring)."""
        if self.name == "payload":
            assert ctx.y_payload is not None
            return {j: ctx.y_payload[j] for j in self.joints}
        (j,) = self.joints
        cols = self._raw_columns(ctx, j)
        # A coupling copies the model's torques, which are already as filtered as the measurement.
        return {j: cols if self.name == "wrist_coupling" else ctx.filtered(cols)}

    def _raw_columns(self, ctx: Context, j: int) -> np.ndarray:
        name, s = self.name, self.setting
        if name == "position_ripple":
            c = float(s["cycles_per_rev"])
            q = ctx.q[:, j]  # periodic: bounded without clipping (module docstring)
            return np.column_stack([np.sin(c * q), np.cos(c * q)])
        if name == "spring":
            q = ctx.q[:, j]  # Hooke's law is physics: extrapolates (module docstring)
            return np.column_stack([q, np.ones_like(q)])
        if name == "stribeck":
            v = float(s["velocity_rad_s"])
            return ctx.sample_mean(j, lambda x: gaussian_stribeck(x, v))
        if name == "load_dependent_friction":
            assert ctx.rigid is not None
            return np.abs(ctx.rigid[:, j : j + 1]) * ctx.sample_mean(j, np.sign)
        if name == "thermal_drift":
            if ctx.t is None:
                return np.zeros((ctx.n_rows, 2))
            t = np.asarray(ctx.t, dtype=float)[:, None]
            return t * ctx.sample_mean(j, lambda x: np.column_stack([np.sign(x), x]))
        if name == "wrist_coupling":
            assert ctx.friction is not None and ctx.rigid is not None
            k = int(s["from_joint"])
            src = (
                ctx.friction[:, k]
                if s["source"] == "friction"
                else ctx.rigid[:, k] + ctx.friction[:, k]
            )
            return src[:, None]
        raise ValueError(f"effect {name!r} has no columns")

    def parameters(self, coef: np.ndarray) -> dict[str, Any]:
        """Physical parameters (units in the keys) from the fitted coefficients."""
        c = [float(v) for v in np.asarray(coef, dtype=float).ravel()]
        name, s = self.name, self.setting
        if name == "position_ripple":
            return {
                "cycles_per_rev": int(s["cycles_per_rev"]),
                "amplitude_nm": math.hypot(c[0], c[1]),
                "phase_rad": math.atan2(c[1], c[0]),
            }
        if name == "payload":
            m = c[0]
            com = [v / m for v in c[1:4]] if abs(m) > 1e-9 else [0.0, 0.0, 0.0]
            return {"mass_kg": m, "com_m": com, "inertia_at_origin_kgm2": c[4:10]}
        if name == "spring":
            k, b = c
            q0 = -b / k if abs(k) > 1e-12 else 0.0
            return {"k_nm_per_rad": k, "q0_rad": q0, "torque_at_zero_nm": b}
        if name == "stribeck":
            return {"amplitude_nm": c[0], "velocity_rad_s": float(s["velocity_rad_s"])}
        if name == "load_dependent_friction":
            return {"coefficient": c[0]}
        if name == "time_delay":
            return {"delay_s": float(s["delay_s"])}
        if name == "thermal_drift":
            return {"rate_nm_per_s": c[0], "viscous_rate_nm_per_rad": c[1] if len(c) > 1 else 0.0}
        if name == "wrist_coupling":
            return {
                "from_joint": int(s["from_joint"]) + 1,
                "coefficient": c[0],
                "source": str(s["source"]),
            }
        raise ValueError(f"unknown effect {name!r}")

    def to_json(self, coef: np.ndarray, appeared: str) -> dict[str, Any]:
        return {
            "name": self.name,
            "joints": [j + 1 for j in self.joints],
            "parameters": self.parameters(coef),
            "appeared": appeared,
            "setting": dict(self.setting),
            "coefficients": [float(v) for v in np.asarray(coef, dtype=float).ravel()],
        }

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> EffectTerm:
        name = doc["name"]
        if name not in EFFECT_NAMES:
            raise ValueError(f"unknown effect {name!r} (known: {list(EFFECT_NAMES)})")
        return cls(name, tuple(int(j) - 1 for j in doc["joints"]), dict(doc.get("setting", {})))
