"""The hard world: the seeded family (:mod:`.family`) made as hard as the real world (issue 46).

A draw of the hard world (:func:`draw_world`, deterministic from the seed) keeps the declared
world's arm, sample rate, durations, training multisine and test multisine (same streams), and
changes what the real world changes:

- the URDF handed to analyze (``robot.urdf``) is wrong: masses, centres of mass and inertias
  off (:mod:`.wrong_urdf`); the torque comes from the generating arm (``truth_robot.urdf``);
- friction follows a law drawn per joint, mostly not the product's eq. (15): asymmetric
  Coulomb, other Stribeck shapes, LuGre, Dahl, temperature-dependent viscous
  (:mod:`.friction_laws`), over one continuous session: training run, then test run, then its
  holdout (session time of a test sample = training length + its stamp);
- the torque channel always reads k_j τ + b_j (:func:`.family.draw_chain`: gain 1 ± 5 %, offset
  ± 0.5 % of the joint's peak), then noise as the declared world's (:func:`.family.draw_levels`,
  q quantised, dq and τ noisy), plus single-sample outliers; the stamps are jittered and each
  file misses a few stretches (:mod:`.stamps`);
- 0, 1 or 2 undeclared effects (:mod:`.world_effects`), never two of a case;
- the test run stops its multisine for teaching-like stretches (rests, slow minimum-jerk
  moves, reversals); the holdout is about half teaching, half multisine (:mod:`.teaching`).

The holdout (the last :data:`.referee.HOLDOUT_SHARE` of the test run's samples) is cut before
the gaps are made. ``truth.json`` records the laws per joint (``friction_laws``), the chain,
stamps, gaps and outliers (``recording``), the effects, the teaching plan, the wrong URDF's
factors (``urdf_errors``) and ``thermal_drift_exempt_joints`` (1-based joints with
temperature-dependent viscous friction, on which a named ``thermal_drift`` is not false).

:class:`World` holds, beside the :class:`.family.Draw`, what the oracle (:mod:`.oracle`) needs:
the generating URDF, the kinematics the torque sees on every kept row (delayed when the draw
has a time delay) and per joint the friction laws' and effects' columns.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pinocchio as pin

from . import family as fam
from .friction_laws import STATEFUL_KINDS, FrictionLaw, draw_laws
from .referee import HOLDOUT_SHARE
from .stamps import JITTER_FRACTION, gap_mask, jittered_times, outliers
from .teaching import TestMotion, plan_test_motion
from .world_effects import Session, apply_effects, draw_cases, draw_delay
from .wrong_urdf import wrong_arm

_JITTER, _GAPS, _OUTLIERS, _TEACH, _LAWS, _WRONG = range(30, 36)
RUNS = ("train", "test", "holdout")


@dataclass(frozen=True)
class World:
    """A hard-world draw: ``draw`` (its ``urdf`` the wrong one), ``truth_urdf`` (the
    generating arm), per run name (train, test, holdout) the kinematics the torque sees
    (``seen``: q, dq, ddq (T, n) each) and per joint the columns of its friction law and
    effects (``columns``: (T, m_j))."""

    draw: fam.Draw
    truth_urdf: str
    laws: tuple[FrictionLaw, ...]
    motion: TestMotion
    seen: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    columns: dict[str, list[np.ndarray]]
    #: per joint the holdout's columns as its file alone determines them: a bristle state
    #: (LuGre, Dahl) started at 0 at the file's first row (:func:`draw_world`)
    holdout_from_file: list[np.ndarray]

    @property
    def n(self) -> int:
        return self.draw.n

    @property
    def exempt_joints(self) -> list[int]:
        return list(self.draw.truth["thermal_drift_exempt_joints"])


def _split(a: np.ndarray, n_train: int, cut: int) -> dict[str, np.ndarray]:
    return {"train": a[:n_train], "test": a[n_train : n_train + cut], "holdout": a[n_train + cut :]}


def draw_world(seed: int, duration_scale: float = 1.0, pool: tuple[str, ...] | None = None):
    """Hard-world draw ``seed`` (module docstring); ``duration_scale`` shortens the runs as
    :func:`.family.draw` does; ``pool`` restricts the effect cases
    (:func:`.world_effects.draw_cases`)."""
    arm = fam.draw_arm(seed)
    n = arm.n
    settings = fam.draw_settings(seed)
    rate = settings["rate_hz"]
    grid_tr = fam._times(settings["train_s"] * duration_scale, rate)
    grid_te = fam._times(settings["test_s"] * duration_scale / (1.0 - HOLDOUT_SHARE), rate)
    n_tr, n_te = grid_tr.size, grid_te.size
    cut = round((1.0 - HOLDOUT_SHARE) * n_te)
    f0 = max(settings["f0_hz"], min(1.5 * rate / n_tr, fam.F_MAX_HZ / 3.0))
    exc_tr = fam.train_excitation(arm, f0, grid_tr, fam._rng(seed, fam._TRAIN_EXC))
    env = fam.envelope(*exc_tr.evaluate(grid_tr)[:2])
    exc_te, outside_rec = fam.held_out_excitation(
        arm, exc_tr, env, grid_te[:cut], fam._rng(seed, fam._TEST_EXC)
    )
    motion = plan_test_motion(
        exc_te, grid_te[cut], n_te / rate, arm.lower, arm.upper, fam._rng(seed, _TEACH)
    )
    jr = fam._rng(seed, _JITTER)
    jitter = float(jr.uniform(*JITTER_FRACTION))
    t_tr, t_te = jittered_times(n_tr, rate, jitter, jr), jittered_times(n_te, rate, jitter, jr)

    cases = draw_cases(seed, pool)
    delay = draw_delay(seed, cases)
    true = {"train": exc_tr.evaluate(t_tr), "test": motion.evaluate(t_te)}
    seen = dict(true)
    if delay:
        seen = {"train": exc_tr.evaluate(t_tr - delay), "test": motion.evaluate(t_te - delay)}
    model = pin.buildModelFromXML(fam.urdf(arm))
    rigid = {r: fam.rigid_torque(model, *seen[r]) for r in ("train", "test")}
    peak = np.array([float(f"{p:.3g}") for p in np.max(np.abs(rigid["train"]), axis=0)])
    peak = np.maximum(peak, 1e-3)
    train_s = n_tr / rate
    session_t = np.concatenate([t_tr, train_s + t_te])
    laws = draw_laws(
        fam._rng(seed, _LAWS),
        peak,
        np.max(np.abs(true["train"][1]), axis=0),
        float(session_t[-1]),
    )
    q_all = np.vstack([seen["train"][0], seen["test"][0]])
    v_all = np.vstack([seen["train"][1], seen["test"][1]])
    law_cols = [law.columns(session_t, q_all[:, j], v_all[:, j]) for j, law in enumerate(laws)]
    friction_all = np.column_stack([c.sum(axis=1) for c in law_cols])
    friction = {"train": friction_all[:n_tr], "test": friction_all[n_tr:]}
    nominal = {r: rigid[r] + friction[r] for r in ("train", "test")}

    levels = fam.draw_levels(seed, arm, peak)
    sigma = np.asarray(levels["torque_noise_std_nm"])
    session = Session(
        t={"train": t_tr, "test": t_te},
        q={r: seen[r][0] for r in seen},
        dq={r: seen[r][1] for r in seen},
        ddq={r: seen[r][2] for r in seen},
        nominal=nominal,
    )
    applied = apply_effects(seed, cases, arm, model, laws, sigma, session, delay)
    chain = fam.draw_chain(seed, peak)
    k, b = np.asarray(chain["gain"]), np.asarray(chain["offset_nm"])
    effort_peak = np.max(np.abs(np.vstack([nominal[r] + applied.added[r] for r in nominal])), 0)

    runs: dict[str, fam.Run] = {}
    for r, t in (("train", t_tr), ("test", t_te)):
        clean = k * (nominal[r] + applied.added[r]) + b
        q, dq, ddq = true[r]
        qm, dqm, taum = fam._measure(arm, t, q, dq, clean, levels, fam._rng(seed, fam._NOISE[r]))
        runs[r] = fam.Run(t, qm, dqm, taum, q, dq, ddq, clean, nominal[r], rigid[r], friction[r])
    runs["test"], runs["holdout"] = (
        fam._rows(runs["test"], slice(0, cut)),
        fam._rows(runs["test"], slice(cut, None)),
    )

    # per joint: the law's columns and the effects' columns, over the session, then per file
    columns_all = []
    for j in range(n):
        pairs = zip(applied.columns["train"][j], applied.columns["test"][j], strict=True)
        eff = [np.vstack([a, c]) for a, c in pairs]
        columns_all.append(np.column_stack([law_cols[j], *eff]))
    columns = {r: [] for r in RUNS}
    for c in columns_all:
        for r, part in _split(c, n_tr, cut).items():
            columns[r].append(part)
    seen_rows = {
        r: tuple(
            _split(np.vstack([seen["train"][i], seen["test"][i]]), n_tr, cut)[r] for i in range(3)
        )
        for r in RUNS
    }

    gap_rng, out_rng = fam._rng(seed, _GAPS), fam._rng(seed, _OUTLIERS)
    recording: dict[str, Any] = {"jitter_fraction_of_period": jitter, "gaps": {}, "outliers": {}}
    for r in RUNS:
        keep = gap_mask(runs[r].t.size, gap_rng)
        spikes, count = outliers((int(keep.sum()), n), sigma, out_rng)
        run = fam._rows(runs[r], keep)
        runs[r] = replace(run, tau=run.tau + spikes)
        seen_rows[r] = tuple(a[keep] for a in seen_rows[r])
        columns[r] = [c[keep] for c in columns[r]]
        missing = np.flatnonzero(np.diff(np.flatnonzero(keep)) > 1)
        recording["gaps"][r] = {
            "missing_samples": int((~keep).sum()),
            "stretches": int(missing.size),
        }
        recording["outliers"][r] = count

    # The oracle predicts the holdout from its file as any predictor must: a bristle's state at
    # the file's first row is the torque a resting joint holds, set by the motion before the
    # file, which no row of it records. Started at 0 there (the product's predict does the
    # same); the session's state, which the generator knows and no file carries, is kept in
    # ``columns`` (the oracle's columns on the training and test files, and its other figure).
    t_hold = train_s + runs["holdout"].t
    q_hold, v_hold = seen_rows["holdout"][0], seen_rows["holdout"][1]
    holdout_from_file = []
    for j, law in enumerate(laws):
        c = columns["holdout"][j]
        if law.kind in STATEFUL_KINDS:
            c = c.copy()
            c[:, : law_cols[j].shape[1]] = law.columns(t_hold, q_hold[:, j], v_hold[:, j])
        holdout_from_file.append(c)

    wrong, urdf_errors = wrong_arm(arm, fam._rng(seed, _WRONG))
    effort = np.array([float(f"{3.0 * p:.3g}") for p in np.maximum(effort_peak, 1.0)])
    case = "+".join(e["name"] for e in applied.effects) or "null"
    exempt = [j + 1 for j, law in enumerate(laws) if law.kind == "temperature_viscous"]
    labels = motion.labels(runs["holdout"].t)
    truth = {
        "world": "hard",
        "seed": seed,
        "case": case,
        "effects": applied.effects,
        "arm": arm.to_json(),
        "effort_limit_nm": effort.tolist(),
        "rate_hz": rate,
        "duration_s": {r: runs[r].t.size / rate for r in RUNS},
        "n_samples": {r: int(runs[r].t.size) for r in RUNS},
        "session_offset_s": {"train": 0.0, "test": train_s, "holdout": train_s},
        "excitation": {"train": exc_tr.to_json(), "test": exc_te.to_json()},
        "teaching": motion.to_json(),
        "holdout_motion_share": {
            lab: float(np.mean(labels == lab)) for lab in ("multisine", "ramp", "rest", "move")
        },
        "outside_envelope": {
            **outside_rec,
            "share_measured": float(
                fam.outside(
                    fam.envelope(runs["train"].q, runs["train"].dq), runs["test"].q, runs["test"].dq
                )
                .any(axis=1)
                .mean()
            ),
        },
        "peak_rigid_torque_nm": peak.tolist(),
        "friction_laws": [law.to_json() for law in laws],
        "thermal_drift_exempt_joints": exempt,
        "noise": levels,
        "measurement_chain": {**chain, "applied": True},
        "recording": recording,
        "urdf_errors": urdf_errors,
        "gravity_m_s2": [0.0, 0.0, -9.81],
    }
    d = fam.Draw(
        seed, case, arm, fam.urdf(wrong, effort, name=f"family_seed{seed}"), runs["train"],
        runs["test"], truth, (exc_tr, exc_te), None, runs["holdout"],
    )  # fmt: skip
    return World(
        d,
        fam.urdf(arm, effort, name=f"family_seed{seed}_truth"),
        laws,
        motion,
        seen_rows,
        columns,
        holdout_from_file,
    )
