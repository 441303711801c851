"""Measured-robot data for :data:`.arm.ARM`: excitation, rigid body, friction, noise, effects.

Excitation
    Band-limited multi-sine per joint (a Fourier series like Swevers' excitation): base
    frequency :data:`F0_HZ`, harmonics :data:`HARMONICS` (0.06–0.8 Hz), amplitude ∝ 1/l (flat
    velocity spectrum), random phases per joint and harmonic from the run's seed. Each joint is
    scaled to stay within :data:`POSITION_FRACTION` (80 %) of its half range about the range's
    centre, under :data:`VELOCITY_FRACTION` of its velocity limit and under its acceleration cap
    :data:`ACCELERATION_CAP` (all checked on the run's own samples). q [rad], dq [rad/s],
    ddq [rad/s²] are analytic. Sample rate :data:`RATE_HZ`; train :data:`TRAIN_S`, test
    :data:`TEST_S`, from different seeds.

Torque (joint side, N·m)
    ``pin.rnea`` on the URDF of :func:`.arm.urdf` plus friction, eq. (15) of Liu et al.
    (Robotica 2022) as the brief writes it, per joint::

        τ_f = (τ_c + (τ_s - τ_c) exp(-(dq/q_e)²)) s(dq) + τ_v dq
              + Σ_{k=1..3} (a_k sin kq + b_k cos kq)

    with ``s(dq) = tanh(dq / 1e-4)`` for sgn. Magnitudes are fractions of the joint's nominal
    peak rigid-body torque P (:func:`nominal_peak_torque`): τ_c = :data:`COULOMB_FRACTION` P,
    τ_s = 1.4 τ_c, τ_v = 3 % P at the velocity cap, a_k, b_k = :data:`FOURIER_FRACTIONS` P. No
    rotor inertia.

Measurement
    Gaussian torque noise, std ``max(0.5 % P, 0.05 N·m)`` per joint (:func:`noise_std`), and q
    quantised to 2^20 counts per motor revolution through the joint's gear ratio. dq is written
    as the drive would report it: the analytic velocity (not quantised).

Cases (:data:`CASES`, :func:`make_case`): one undeclared effect each, truth in a JSON-able dict:
``null``; ``payload_both`` / ``payload_after`` (:data:`.arm.PAYLOAD`, 6 kg at 0.1 m from the
flange, in both runs / only in the test run); ``hose_spring`` (:data:`SPRING` on A4);
``ripple`` (:data:`RIPPLE` on A3); ``delay`` (torque lags kinematics by :data:`DELAY_S`, all
joints); ``thermal_drift`` (:data:`THERMAL`, test run only); ``wrist_coupling``
(:data:`COUPLING`, A6 measures 0.1 of A5's torque). Train and test share the arm, friction and
noise levels; their trajectories and noise draws differ.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from .arm import ARM, PAYLOAD, pin_model, urdf

RATE_HZ = 250.0
TRAIN_S = 50.0
TEST_S = 25.0
F0_HZ = 0.02
HARMONICS = np.arange(3, 41)
POSITION_FRACTION = 0.8
VELOCITY_FRACTION = 0.6
ACCELERATION_CAP = np.array([5.0, 5.0, 7.0, 12.0, 12.0, 16.0])  # rad/s²
SIGN_VELOCITY = 1e-4  # rad/s, tanh(dq / SIGN_VELOCITY) in place of sgn(dq)

COULOMB_FRACTION = np.array([0.05, 0.03, 0.04, 0.04, 0.04, 0.05])
STATIC_OVER_COULOMB = 1.4
VISCOUS_FRACTION = 0.03
Q_E = np.array([0.02, 0.02, 0.03, 0.03, 0.04, 0.05])  # rad/s
#: a_k, b_k (k = 1, 2, 3) as fractions of P; signs vary per joint (:func:`nominal_friction`).
FOURIER_FRACTIONS = np.array([[0.003, 0.0015, 0.0005], [0.002, 0.001, 0.0005]])
NOISE_FRACTION = 0.005
NOISE_FLOOR_NM = 0.05

TRAIN, TEST = 0, 1


# --------------------------------------------------------------------------- excitation


@dataclass(frozen=True)
class Excitation:
    """q_j(t) = c_j + s_j Σ_l (1/l) sin(2π F0 l t + φ_jl); ``phases`` (6, L) [rad], ``scale``
    s_j [rad], ``centre`` c_j [rad]."""

    phases: np.ndarray
    scale: np.ndarray
    centre: np.ndarray

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q [rad], dq [rad/s], ddq [rad/s²] at times ``t`` [s]; each (T, 6)."""
        x, dx, ddx = _unit_series(np.asarray(t, dtype=float), self.phases)
        return self.centre + self.scale * x, self.scale * dx, self.scale * ddx


def _unit_series(t: np.ndarray, phases: np.ndarray) -> tuple[np.ndarray, ...]:
    w = 2.0 * np.pi * F0_HZ * HARMONICS  # (L,)
    amp = 1.0 / HARMONICS
    arg = t[:, None, None] * w[None, None, :] + phases[None, :, :]  # (T, 6, L)
    s, c = np.sin(arg), np.cos(arg)
    x = np.einsum("tjl,l->tj", s, amp)
    dx = np.einsum("tjl,l->tj", c, amp * w)
    ddx = -np.einsum("tjl,l->tj", s, amp * w * w)
    return x, dx, ddx


def sample_times(duration_s: float) -> np.ndarray:
    """Sample times [s]: ``round(duration * RATE_HZ)`` samples from 0 at :data:`RATE_HZ`."""
    return np.arange(round(duration_s * RATE_HZ)) / RATE_HZ


def excitation(seed: int, role: int, duration_s: float) -> Excitation:
    """The excitation of run ``role`` (:data:`TRAIN` or :data:`TEST`) for ``seed``: random phases
    from ``SeedSequence([seed, role])``, scaled on the run's samples (module docstring)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, role, 11]))
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(ARM.n, HARMONICS.size))
    x, dx, ddx = _unit_series(sample_times(duration_s), phases)
    scale = np.min(
        [
            POSITION_FRACTION * ARM.half_range / np.max(np.abs(x), axis=0),
            VELOCITY_FRACTION * ARM.velocity_limit / np.max(np.abs(dx), axis=0),
            ACCELERATION_CAP / np.max(np.abs(ddx), axis=0),
        ],
        axis=0,
    )
    return Excitation(phases, scale, ARM.centre.copy())


# --------------------------------------------------------------------------- torques


def rigid_torque(q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, payload: bool = False):
    """Rigid-body joint torque [N·m], (T, 6), by ``pin.rnea`` on the arm's URDF (with
    :data:`.arm.PAYLOAD` on the flange when ``payload``)."""
    return rnea_rows(pin_model(payload), q, dq, ddq)


def rnea_rows(model, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """``pin.rnea`` of ``model`` per sample [N·m], (T, n)."""
    data = model.createData()
    out = np.empty_like(q)
    for i in range(q.shape[0]):
        out[i] = pin.rnea(model, data, q[i], dq[i], ddq[i])
    return out


@dataclass(frozen=True)
class Friction:
    """Eq. (15) parameters per joint, arrays of shape (6,) unless noted: Coulomb ``coulomb``
    [N·m], static ``static`` [N·m], viscous ``viscous`` [N·m·s/rad], Stribeck velocity ``q_e``
    [rad/s], position Fourier ``a``, ``b`` (6, 3) [N·m] for k = 1, 2, 3."""

    coulomb: np.ndarray
    static: np.ndarray
    viscous: np.ndarray
    q_e: np.ndarray
    a: np.ndarray
    b: np.ndarray

    def to_json(self) -> dict[str, Any]:
        return {
            "coulomb_nm": self.coulomb.tolist(),
            "static_nm": self.static.tolist(),
            "viscous_nm_s_per_rad": self.viscous.tolist(),
            "q_e_rad_s": self.q_e.tolist(),
            "fourier_sin_nm": self.a.tolist(),
            "fourier_cos_nm": self.b.tolist(),
            "formula": "(tc + (ts - tc) exp(-(dq/qe)^2)) tanh(dq/1e-4) + tv dq "
            "+ sum_k (a_k sin(k q) + b_k cos(k q))",
        }


def friction_torque(
    fr: Friction,
    q: np.ndarray,
    dq: np.ndarray,
    coulomb_scale: np.ndarray | float = 1.0,
    viscous_scale: np.ndarray | float = 1.0,
) -> np.ndarray:
    """Eq. (15) friction torque [N·m], (T, 6), at q [rad], dq [rad/s] of shape (T, 6).

    ``coulomb_scale`` and ``viscous_scale`` (scalar or broadcastable to (T, 6)) multiply τ_c and
    τ_v (τ_s is left as is): the thermal-drift case lowers them over time."""
    tc = fr.coulomb * coulomb_scale
    s = np.tanh(dq / SIGN_VELOCITY)
    stribeck = tc + (fr.static - tc) * np.exp(-((dq / fr.q_e) ** 2))
    out = stribeck * s + fr.viscous * viscous_scale * dq
    for k in range(3):
        out = out + fr.a[:, k] * np.sin((k + 1) * q) + fr.b[:, k] * np.cos((k + 1) * q)
    return out


@cache
def nominal_peak_torque() -> np.ndarray:
    """P [N·m] per joint: the largest |rigid-body torque| over a reference excitation (seed
    10_000, train length), rounded to 3 significant digits. Sets friction and noise levels."""
    exc = excitation(10_000, TRAIN, TRAIN_S)
    q, dq, ddq = exc.evaluate(sample_times(TRAIN_S))
    peak = np.max(np.abs(rigid_torque(q, dq, ddq)), axis=0)
    return np.array([float(f"{p:.3g}") for p in peak])


@cache
def nominal_friction() -> Friction:
    """The arm's friction (module docstring)."""
    p = nominal_peak_torque()
    coulomb = COULOMB_FRACTION * p
    signs = np.array([[1, -1, 1], [-1, 1, 1], [1, 1, -1], [-1, -1, 1], [1, -1, -1], [-1, 1, -1]])
    return Friction(
        coulomb=coulomb,
        static=STATIC_OVER_COULOMB * coulomb,
        viscous=VISCOUS_FRACTION * p / (VELOCITY_FRACTION * ARM.velocity_limit),
        q_e=Q_E.copy(),
        a=signs * FOURIER_FRACTIONS[0] * p[:, None],
        b=-signs[:, ::-1] * FOURIER_FRACTIONS[1] * p[:, None],
    )


def noise_std() -> np.ndarray:
    """Torque noise std [N·m] per joint: ``max(0.5 % P, 0.05)``."""
    return np.maximum(NOISE_FRACTION * nominal_peak_torque(), NOISE_FLOOR_NM)


def quantise(q: np.ndarray) -> np.ndarray:
    """q [rad] rounded to whole encoder counts (2^20 per motor rev through the gear ratio)."""
    step = ARM.encoder_step
    return np.round(q / step) * step


# --------------------------------------------------------------------------- runs


@dataclass(frozen=True)
class Run:
    """One recorded trajectory: T samples of 6 joints.

    Measured (written to CSV): ``t`` [s], ``q`` [rad] (quantised), ``dq`` [rad/s], ``tau``
    [N·m] (noisy). Truth: ``q_true`` [rad], ``ddq`` [rad/s²], ``tau_clean`` [N·m] the
    noise-free measured torque (with the case's effect), ``tau_nominal`` [N·m] the noise-free
    torque without any effect (rigid + nominal friction), ``tau_rigid`` [N·m] its rigid part,
    ``noise_std`` [N·m] per joint, ``role`` "train" or "test"."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    q_true: np.ndarray
    ddq: np.ndarray
    tau_clean: np.ndarray
    tau_nominal: np.ndarray
    tau_rigid: np.ndarray
    noise_std: np.ndarray
    role: str


def _frozen(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    for a in arrays:
        a.flags.writeable = False
    return arrays


@cache
def _kinematics(seed: int, role: int, shift_s: float = 0.0) -> tuple[np.ndarray, ...]:
    duration = TRAIN_S if role == TRAIN else TEST_S
    t = sample_times(duration)
    q, dq, ddq = excitation(seed, role, duration).evaluate(t - shift_s)
    return _frozen(t, q, dq, ddq)


@cache
def _rigid(seed: int, role: int, shift_s: float = 0.0, payload: bool = False) -> np.ndarray:
    _, q, dq, ddq = _kinematics(seed, role, shift_s)
    return _frozen(rigid_torque(q, dq, ddq, payload))[0]


def _noise(seed: int, role: int, shape: tuple[int, int]) -> np.ndarray:
    rng = np.random.default_rng(np.random.SeedSequence([seed, role, 23]))
    return rng.standard_normal(shape) * noise_std()


def base_run(seed: int, role: int) -> Run:
    """The run without any effect (``tau_clean == tau_nominal``)."""
    t, q, dq, ddq = _kinematics(seed, role)
    rigid = _rigid(seed, role)
    nominal = rigid + friction_torque(nominal_friction(), q, dq)
    return Run(
        t=t,
        q=quantise(q),
        dq=dq,
        tau=nominal + _noise(seed, role, q.shape),
        q_true=q,
        ddq=ddq,
        tau_clean=nominal,
        tau_nominal=nominal,
        tau_rigid=rigid,
        noise_std=noise_std(),
        role="train" if role == TRAIN else "test",
    )


def with_clean(run: Run, clean: np.ndarray, seed: int, role: int) -> Run:
    """``run`` with noise-free torque ``clean`` [N·m] and the run's own noise added to it."""
    return replace(run, tau_clean=clean, tau=clean + _noise(seed, role, clean.shape))


# --------------------------------------------------------------------------- cases

#: Spring (a hose pulled by A4's roll): motor adds +k (q4 - q0) [N·m/rad, rad].
SPRING = {"joint": 4, "k_nm_per_rad": 0.5, "q0_rad": 0.3}
#: Gear ripple on A3: A sin(c q3 + φ), A = 5 noise std.
RIPPLE = {"joint": 3, "cycles_per_rev": 30, "noise_multiple": 5.0, "phase_rad": 0.7}
DELAY_S = 0.010
#: Warm-up: τ_c and τ_v of A1 and A3 fall linearly by 25 % over the test run.
THERMAL = {"joints": [1, 3], "drop_fraction_at_end": 0.25}
#: A6's measured torque includes 0.1 of A5's torque (rigid + friction).
COUPLING = {"joint": 6, "from_joint": 5, "coefficient": 0.1}


def _truth(name: str, seed: int, effects: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "case": name,
        "seed": seed,
        "effects": effects,
        "noise_std_nm": noise_std().tolist(),
        "nominal_peak_torque_nm": nominal_peak_torque().tolist(),
        "friction": nominal_friction().to_json(),
        "rate_hz": RATE_HZ,
        "duration_s": {"train": TRAIN_S, "test": TEST_S},
        "gear_ratios": ARM.gear_ratios.tolist(),
        "encoder_counts_per_motor_rev": ARM.encoder_counts_per_motor_rev,
        "arm": ARM.name,
        "joints": [j.name for j in ARM.joints],
    }


def _effect(
    name: str, joints: list[int], appeared: str, main: str, **parameters: Any
) -> dict[str, Any]:
    return {
        "name": name,
        "joints": joints,
        "appeared": appeared,
        "main_parameter": main,
        "parameters": parameters,
    }


ALL_ALONG = "all_along"
BETWEEN = "between_train_and_test"


def _case_null(seed: int) -> tuple[Run, Run, list[dict[str, Any]]]:
    return base_run(seed, TRAIN), base_run(seed, TEST), []


def _payload_run(seed: int, role: int) -> Run:
    run = base_run(seed, role)
    rigid = _rigid(seed, role, payload=True)
    clean = rigid + friction_torque(nominal_friction(), run.q_true, run.dq)
    return with_clean(run, clean, seed, role)


def _payload_truth(appeared: str) -> dict[str, Any]:
    effect = _effect("payload", list(range(1, 7)), appeared, "mass_kg", **PAYLOAD.in_last_link(ARM))
    if appeared == ALL_ALONG:
        # Rigidly fixed to link 6 in both runs, the payload only changes link 6's ten inertial
        # parameters: the rigid-body model absorbs it exactly, no data can tell it apart.
        effect["separable_from_rigid_model"] = False
    return effect


def _case_payload_both(seed: int):
    return (
        _payload_run(seed, TRAIN),
        _payload_run(seed, TEST),
        [_payload_truth(ALL_ALONG)],
    )


def _case_payload_after(seed: int):
    return base_run(seed, TRAIN), _payload_run(seed, TEST), [_payload_truth(BETWEEN)]


def _add_on_joint(seed: int, role: int, joint: int, fn: Callable[[Run], np.ndarray]) -> Run:
    run = base_run(seed, role)
    clean = run.tau_nominal.copy()
    clean[:, joint - 1] += fn(run)
    return with_clean(run, clean, seed, role)


def _case_hose_spring(seed: int):
    j, k, q0 = SPRING["joint"], SPRING["k_nm_per_rad"], SPRING["q0_rad"]

    def spring(run: Run) -> np.ndarray:
        return k * (run.q_true[:, j - 1] - q0)

    runs = [_add_on_joint(seed, role, j, spring) for role in (TRAIN, TEST)]
    truth = _effect(
        "spring",
        [j],
        ALL_ALONG,
        "k_nm_per_rad",
        k_nm_per_rad=k,
        q0_rad=q0,
        torque_at_zero_nm=-k * q0,
        convention="spring pushes -k (q - q0); measured motor torque includes +k (q - q0)",
    )
    return runs[0], runs[1], [truth]


def ripple_amplitude() -> float:
    """Ripple amplitude [N·m]: :data:`RIPPLE` ``noise_multiple`` × that joint's noise std."""
    return float(RIPPLE["noise_multiple"] * noise_std()[RIPPLE["joint"] - 1])


def _case_ripple(seed: int):
    j, c, phi = RIPPLE["joint"], RIPPLE["cycles_per_rev"], RIPPLE["phase_rad"]
    amp = ripple_amplitude()

    def ripple(run: Run) -> np.ndarray:
        return amp * np.sin(c * run.q_true[:, j - 1] + phi)

    runs = [_add_on_joint(seed, role, j, ripple) for role in (TRAIN, TEST)]
    truth = _effect(
        "position_ripple",
        [j],
        ALL_ALONG,
        "cycles_per_rev",
        cycles_per_rev=c,
        amplitude_nm=amp,
        phase_rad=phi,
    )
    return runs[0], runs[1], [truth]


def _delayed_run(seed: int, role: int) -> Run:
    """The torque measured at t is the torque of the motion at t - DELAY_S."""
    run = base_run(seed, role)
    _, q, dq, _ = _kinematics(seed, role, DELAY_S)
    clean = _rigid(seed, role, DELAY_S) + friction_torque(nominal_friction(), q, dq)
    return with_clean(run, clean, seed, role)


def _case_delay(seed: int):
    truth = _effect("time_delay", list(range(1, 7)), ALL_ALONG, "delay_s", delay_s=DELAY_S)
    return _delayed_run(seed, TRAIN), _delayed_run(seed, TEST), [truth]


def _case_thermal_drift(seed: int):
    train, test = base_run(seed, TRAIN), base_run(seed, TEST)
    drop = THERMAL["drop_fraction_at_end"]
    factor = np.ones_like(test.q)
    cols = [j - 1 for j in THERMAL["joints"]]
    factor[:, cols] = (1.0 - drop * test.t / TEST_S)[:, None]
    fr = nominal_friction()
    clean = test.tau_rigid + friction_torque(fr, test.q_true, test.dq, factor, factor)
    test = with_clean(test, clean, seed, TEST)
    truth = _effect(
        "thermal_drift",
        list(THERMAL["joints"]),
        BETWEEN,
        "drop_fraction_at_end",
        drop_fraction_at_end=drop,
        shape="tau_c and tau_v times (1 - drop t / T_test) in the test run; train at nominal",
        coulomb_nm_before=[float(fr.coulomb[c]) for c in cols],
        viscous_nm_s_per_rad_before=[float(fr.viscous[c]) for c in cols],
        coulomb_rate_nm_per_s=[float(-drop * fr.coulomb[c] / TEST_S) for c in cols],
    )
    return train, test, [truth]


def _case_wrist_coupling(seed: int):
    j, src, coef = COUPLING["joint"], COUPLING["from_joint"], COUPLING["coefficient"]

    def coupling(run: Run) -> np.ndarray:
        return coef * run.tau_nominal[:, src - 1]

    runs = [_add_on_joint(seed, role, j, coupling) for role in (TRAIN, TEST)]
    truth = _effect(
        "wrist_coupling",
        [j],
        ALL_ALONG,
        "coefficient",
        from_joint=src,
        coefficient=coef,
        source="torque",
    )
    return runs[0], runs[1], [truth]


CASES: dict[str, Callable[[int], tuple[Run, Run, list[dict[str, Any]]]]] = {
    "null": _case_null,
    "payload_both": _case_payload_both,
    "payload_after": _case_payload_after,
    "hose_spring": _case_hose_spring,
    "ripple": _case_ripple,
    "delay": _case_delay,
    "thermal_drift": _case_thermal_drift,
    "wrist_coupling": _case_wrist_coupling,
}


def make_case(name: str, seed: int = 0) -> tuple[Run, Run, dict[str, Any]]:
    """(train run, test run, truth dict) of case ``name`` (a key of :data:`CASES`).

    Train and test come from different excitations (``SeedSequence([seed, 0])`` and
    ``[seed, 1]``); all cases with the same seed share them and their noise, so
    ``tau_clean - tau_nominal`` is exactly the case's effect. The truth dict holds ``effects``
    (each ``name`` in the product's vocabulary, ``joints`` 1-based, ``appeared``,
    ``main_parameter``, ``parameters``), the noise std, friction and sampling settings."""
    if name not in CASES:
        raise KeyError(f"unknown case {name!r}; known: {', '.join(CASES)}")
    train, test, effects = CASES[name](seed)
    return train, test, _truth(name, seed, effects)


# --------------------------------------------------------------------------- files

CSV_DIGITS = 12


def csv_header(n: int = 6) -> list[str]:
    """Column names: ``t``, ``q1..qN``, ``dq1..dqN``, ``tau1..tauN``."""
    return [
        "t",
        *(f"q{i}" for i in range(1, n + 1)),
        *(f"dq{i}" for i in range(1, n + 1)),
        *(f"tau{i}" for i in range(1, n + 1)),
    ]


def write_csv(path: Path, run: Run) -> None:
    """The measured columns of ``run`` as the project's measurement CSV (t [s], q [rad],
    dq [rad/s], tau [N·m] joint side; ``,``-separated, one header row, ``\\n`` line ends)."""
    table = np.column_stack([run.t, run.q, run.dq, run.tau])
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write(",".join(csv_header(run.q.shape[1])) + "\n")
        np.savetxt(fh, table, fmt=f"%.{CSV_DIGITS}g", delimiter=",")


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """A CSV written by :func:`write_csv`: ``t`` (T,), ``q``, ``dq``, ``tau`` (T, N)."""
    with open(path, encoding="ascii") as fh:
        names = fh.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    col = {n: i for i, n in enumerate(names)}
    n = sum(1 for name in names if name.startswith("tau"))

    def block(prefix: str) -> np.ndarray:
        return data[:, [col[f"{prefix}{i}"] for i in range(1, n + 1)]]

    return {"t": data[:, col["t"]], "q": block("q"), "dq": block("dq"), "tau": block("tau")}


def write_case(directory: Path | str, name: str, seed: int = 0) -> dict[str, Path]:
    """Write ``train.csv``, ``test.csv``, ``robot.urdf`` (no payload: it is undeclared) and
    ``truth.json`` of case ``name`` into ``directory`` (created); returns their paths."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    train, test, truth = make_case(name, seed)
    paths = {
        k: out / f
        for k, f in (
            ("train", "train.csv"),
            ("test", "test.csv"),
            ("urdf", "robot.urdf"),
            ("truth", "truth.json"),
        )
    }
    write_csv(paths["train"], train)
    write_csv(paths["test"], test)
    paths["urdf"].write_text(urdf(ARM), encoding="ascii")
    paths["truth"].write_text(json.dumps(truth, indent=2) + "\n", encoding="ascii")
    return paths
