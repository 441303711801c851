"""Undeclared effects of the hard world (:mod:`.world`): 0, 1 or 2 per draw, never two of the
same case, each with the declared world's parameterisation (:mod:`.family`, "Cases").

The draw: no effect with probability :data:`.family.NULL_SHARE`, else one or two (even odds)
cases among :data:`.family.EFFECT_CASES` without repetition, each from its own random stream.
An effect acts on the kinematics the torque sees (the true motion, shifted by the delay when
``time_delay`` is one of them) over the session (training run, then test run with its holdout;
``t`` each file's own stamps [s]):

``payload``      mass 1-20 % of M, 0.05-0.15 m from the flange; in both runs or the test only;
                 its torque from the arm's model with the payload link;
``spring``       +k (q_j - q0), k = 3-20 × noise per half training range of q_j;
``position_ripple``  A sin(c q_j + φ), c 10-60, A 3-10 × noise;
``time_delay``   the torque lags the kinematics by 2-15 ms (all joints; :mod:`.world` applies it);
``thermal_drift``    test run only: on 1-2 joints the Coulomb level F_c of the joint's law falls
                 linearly by 10-40 % over the test run: + rate t s(v), rate = -drop F_c / T_test;
``wrist_coupling``   the last joint measures 0.05-0.2 of its neighbour's (rigid + friction)
                 torque.

Each effect also gives the oracle's columns (:mod:`.oracle`) with its true nonlinear
parameters: spring q_j - q0; ripple sin c q_j, cos c q_j; thermal drift t s(v) on the test run;
coupling the neighbour's torque; payload, when it appears between the runs, its own torque (its
body's regressor times its true inertial parameters: one column, zero on the training run;
carried in both runs it is inside the last link's parameters); the delay none (the rigid and
friction columns are built on the delayed kinematics).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from . import family as fam
from .friction_laws import FrictionLaw, sign

_COUNT_STREAM = 40
_EFFECT_STREAM = 41  # + index of the case in EFFECT_CASES


def draw_cases(seed: int, pool: tuple[str, ...] | None = None) -> list[str]:
    """The effect cases of draw ``seed`` (module docstring); ``pool`` restricts them."""
    rng = fam._rng(seed, _COUNT_STREAM)
    cases = tuple(c for c in (pool or fam.EFFECT_CASES) if c in fam.EFFECT_CASES)
    allow_null = pool is None or "null" in pool
    if (allow_null and rng.random() < fam.NULL_SHARE) or not cases:
        return []
    count = 1 if rng.random() < 0.5 or len(cases) < 2 else 2
    chosen = rng.choice(len(cases), count, replace=False)
    return sorted((cases[int(i)] for i in chosen), key=fam.EFFECT_CASES.index)


def draw_delay(seed: int, cases: list[str]) -> float:
    """The time delay [s] (0 without the case)."""
    if "time_delay" not in cases:
        return 0.0
    rng = fam._rng(seed, _EFFECT_STREAM + fam.EFFECT_CASES.index("time_delay"))
    return float(rng.uniform(0.002, 0.015))


@dataclass
class Session:
    """What the effects act on, per run name (``train``, ``test``): stamps ``t`` [s], the
    kinematics the torque sees ``q``, ``dq``, ``ddq`` (T, n) and the nominal torque (rigid +
    friction, (T, n)) [N·m]."""

    t: dict[str, np.ndarray]
    q: dict[str, np.ndarray]
    dq: dict[str, np.ndarray]
    ddq: dict[str, np.ndarray]
    nominal: dict[str, np.ndarray]


@dataclass
class Applied:
    """The effects' truth records, added torque per run (T, n) [N·m] and oracle columns per
    run and joint ((T, m) each)."""

    effects: list[dict[str, Any]] = field(default_factory=list)
    added: dict[str, np.ndarray] = field(default_factory=dict)
    columns: dict[str, list[list[np.ndarray]]] = field(default_factory=dict)


def coulomb_level(law: FrictionLaw) -> float:
    p = law.parameters
    return float(p.get("coulomb_nm", p.get("positive_nm", 0.0)))


def apply_effects(
    seed: int,
    cases: list[str],
    arm: fam.FamilyArm,
    model,
    laws: tuple[FrictionLaw, ...],
    sigma: np.ndarray,
    s: Session,
    delay_s: float,
) -> Applied:
    """The effects ``cases`` on session ``s`` (module docstring)."""
    n = arm.n
    runs = ("train", "test")
    out = Applied(
        added={r: np.zeros_like(s.nominal[r]) for r in runs},
        columns={r: [[] for _ in range(n)] for r in runs},
    )

    def col(j: int, per_run: dict[str, np.ndarray]) -> None:
        for r in runs:
            out.columns[r][j].append(per_run[r])

    for case in cases:
        rng = fam._rng(seed, _EFFECT_STREAM + fam.EFFECT_CASES.index(case))
        if case == "payload":
            appeared = fam.ALL_ALONG if rng.random() < 0.5 else fam.BETWEEN
            mass = float(arm.mass_scale_kg * rng.uniform(0.01, 0.2))
            direction = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 1.0])
            dist = float(rng.uniform(0.05, 0.15))
            com = direction / np.linalg.norm(direction) * dist
            side = float(np.clip((mass / 2000.0) ** (1.0 / 3.0), 0.02, 0.3))
            inertia = fam._box_inertia(mass, side * rng.uniform(0.7, 1.3, 3))
            pl = fam.Payload(mass, com, inertia)
            pmodel = pin.buildModelFromXML(fam.urdf(arm, payload=pl))
            extra = {
                r: fam.rigid_torque(pmodel, s.q[r], s.dq[r], s.ddq[r])
                - fam.rigid_torque(model, s.q[r], s.dq[r], s.ddq[r])
                for r in runs
            }
            if appeared == fam.BETWEEN:
                extra["train"][:] = 0.0
                for j in range(n):  # fixed to the last link in both runs: no column needed
                    col(j, {r: extra[r][:, j : j + 1] for r in runs})
            for r in runs:
                out.added[r] += extra[r]
            eff = fam._effect("payload", range(1, n + 1), appeared, "mass_kg", mass_kg=mass,
                              com_m=pl.in_last_link(arm).tolist(), com_from_flange_m=com.tolist(),
                              distance_from_flange_m=dist,
                              inertia_about_com_kgm2=inertia.tolist(),
                              fraction_of_payload_scale=mass / arm.mass_scale_kg)  # fmt: skip
            if appeared == fam.ALL_ALONG:
                eff["separable_from_rigid_model"] = False
        elif case == "spring":
            j = int(rng.integers(n))
            multiple = float(rng.uniform(3.0, 20.0))
            q_min, q_max = s.q["train"][:, j].min(), s.q["train"][:, j].max()
            k = float(multiple * sigma[j] / (0.5 * (q_max - q_min)))
            q0 = float(rng.uniform(q_min, q_max))
            for r in runs:
                out.added[r][:, j] += k * (s.q[r][:, j] - q0)
            col(j, {r: (s.q[r][:, j] - q0)[:, None] for r in runs})
            eff = fam._effect("spring", [j + 1], fam.ALL_ALONG, "k_nm_per_rad", k_nm_per_rad=k,
                              q0_rad=q0, torque_at_zero_nm=-k * q0, noise_multiple=multiple,
                              convention="motor adds +k (q - q0)")  # fmt: skip
        elif case == "position_ripple":
            j = int(rng.integers(n))
            cycles = int(rng.integers(10, 61))
            multiple = float(rng.uniform(3.0, 10.0))
            amp, phase = float(multiple * sigma[j]), float(rng.uniform(0.0, 2.0 * np.pi))
            for r in runs:
                out.added[r][:, j] += amp * np.sin(cycles * s.q[r][:, j] + phase)
            col(j, {r: np.column_stack([np.sin(cycles * s.q[r][:, j]),
                                        np.cos(cycles * s.q[r][:, j])]) for r in runs})  # fmt: skip
            eff = fam._effect("position_ripple", [j + 1], fam.ALL_ALONG, "cycles_per_rev",
                              cycles_per_rev=cycles, amplitude_nm=amp, phase_rad=phase,
                              noise_multiple=multiple)  # fmt: skip
        elif case == "time_delay":
            eff = fam._effect("time_delay", range(1, n + 1), fam.ALL_ALONG, "delay_s",
                              delay_s=delay_s,
                              convention="tau_measured(t) = tau(t - delay_s)")  # fmt: skip
        elif case == "thermal_drift":
            joints = sorted(int(j) for j in rng.choice(n, int(rng.integers(1, 3)), replace=False))
            drops = rng.uniform(0.1, 0.4, len(joints))
            duration = s.t["test"][-1] - s.t["test"][0]
            before = [coulomb_level(laws[j]) for j in joints]
            rates = [float(-d * c / duration) for d, c in zip(drops, before, strict=True)]
            for j, rate in zip(joints, rates, strict=True):
                shape = s.t["test"] * sign(s.dq["test"][:, j])
                out.added["test"][:, j] += rate * shape
                col(j, {"train": np.zeros((s.t["train"].size, 1)), "test": shape[:, None]})
            eff = fam._effect("thermal_drift", [j + 1 for j in joints], fam.BETWEEN,
                              "rate_nm_per_s", rate_nm_per_s=rates, coulomb_rate_nm_per_s=rates,
                              drop_fraction_at_end=drops.tolist(), coulomb_nm_before=before,
                              shape="test run only: the law's Coulomb level F_c (1 - drop t "
                              "/ T_test), added as rate t tanh(dq/1e-4); train at nominal",
                              )  # fmt: skip
        elif case == "wrist_coupling":
            coef = float(rng.uniform(0.05, 0.2))
            for r in runs:
                out.added[r][:, n - 1] += coef * s.nominal[r][:, n - 2]
            col(n - 1, {r: s.nominal[r][:, n - 2 : n - 1] for r in runs})
            eff = fam._effect("wrist_coupling", [n], fam.ALL_ALONG, "coefficient",
                              coefficient=coef, from_joint=n - 1, source="torque")  # fmt: skip
        else:
            raise KeyError(f"unknown case {case!r}")
        out.effects.append(eff)
    return out
