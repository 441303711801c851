"""Eq. (29) of the paper: the dynamic parameters adapt to the measured motor torque, in free
motion only.

The paper adapts â_d along ``dâ_d/dt = -Γ_d Y_dᵀ e`` with ``e`` the difference between the
model's torque and the one the drive delivered. Three things decide how that can run next to
an operator:

- **When.** The motor current cannot tell the operator's hand from a model error: a hand
  pushing on the tool is, to the current, exactly a payload. So â_d never adapts while
  teaching (the hand is there by design). It adapts while the product replays a program in
  position mode (``REPLAYING``), where nobody is meant to touch the arm, and only on the
  joints that slide (``|dq_j| ≥ min_speed_rad_s``): at rest the drive's torque is the load
  plus any static friction up to breakaway, which no model predicts.
- **What.** Y_d is the regressor of a point mass on the last link, four parameters
  ``(δm, δm·c_x, δm·c_y, δm·c_z)`` in its frame added to the identified model: the change
  a painting cell sees between commissioning and teaching (another gun, a hose clipped on, a
  fitting taken off). The rest of the identified model stays: its inertia and friction were
  measured over the whole workspace, and a replayed raster excites them far less.
- **Where it may go: the paper's ν, a contact gate and a projection.** Per joint, an error
  inside ``dead_zone_factor`` times the model's held-out RMS (the error the identification
  measured on data it did not fit: the paper's bound ν on what the model does not describe)
  does not adapt. After each step the estimate is projected onto the point masses a
  painting robot may carry, ``|δm| ≤ max_mass_kg`` at ``|c| ≤ max_reach_m`` from the
  flange (a set a changed gun satisfies and a drift cannot leave); an error on a sliding
  joint larger than ν plus the most any such mass can weigh on that joint at that pose
  (``max_mass_kg (|Y_j,m| + max_reach_m |Y_j,mc|)``) is no payload: it is contact (the tool
  against a fixture, a hand on the arm, a collision), the sample is skipped and adaptation
  pauses for ``contact_hold_s``. A push no larger than a payload cannot be told from one:
  it moves the estimate, within the projection, until the motion without it moves it back.

The discrete law is a normalised gradient over whitened rows: each joint's row and error are
divided by its ν, and per window

    δ ← Π(δ + γ T Γ ỹᵀ ẽ / (1 + ỹ Γ ỹᵀ)),   Γ = diag(1, r², r², r²)  [kg, kg·m]

with ẽ the dead-zoned error, T the window's length, r = ``max_reach_m``. With ``γ T`` < 1
the step is stable for any load; a direction the motion excites converges with rate about γ.

The law steps once per window of ``window_s`` (0.1 s) of consecutive cycles, on the window's
means: a velocity differentiated over one 4 ms cycle carries the encoders' noise as
accelerations of the order of 0.5 rad/s², hundreds of N·m on the base joints, while over the
window the velocity's change measures the mean acceleration 25 times more quietly.

Samples are collected on the control cycle (:meth:`PayloadAdaptation.add`, a few list
appends) and processed in batches on the control process's slow loop
(:meth:`PayloadAdaptation.process`), so the cycle pays nothing for the regressor.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from control.identification.model import IdentifiedModel
from control.identification.terms import EffectTerm
from control.model.cylinders import cylinder_torque_nm
from gateway.config import ConfigError
from gateway.robot.description import RobotDescription

#: the point mass's parameters among the last link's 10 (m, m·c first: pinocchio's order)
POINT_MASS_PARAMETERS = 4
#: what the effect carrying the adapted payload is marked with in a saved model.json
APPEARED = "adapted_in_replay"
#: most samples kept between two batches (a stalled slow loop must not grow the buffer)
MAX_PENDING = 4096
#: ``format`` of the file the adapted mass is kept in across restarts
STATE_FORMAT = "leadthrough-adapted-payload"
STATE_VERSION = 1


@dataclass(frozen=True)
class AdaptationSettings:
    """``[control] model_adaptation_*`` (module docstring)."""

    rate_per_s: float = 0.5
    dead_zone_factor: float = 3.0
    window_s: float = 0.1
    contact_hold_s: float = 1.0
    min_speed_rad_s: float = 0.01
    max_mass_kg: float = 15.0
    max_reach_m: float = 0.5

    def __post_init__(self) -> None:
        for name in (
            "rate_per_s", "dead_zone_factor", "window_s", "min_speed_rad_s", "max_mass_kg",
            "max_reach_m",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"[control].model_adaptation {name} = {v}: must be > 0")
        if not (math.isfinite(self.contact_hold_s) and self.contact_hold_s >= 0):
            raise ConfigError(f"[control].model_adaptation contact_hold_s = {self.contact_hold_s}")


@dataclass
class _Pending:
    cycle: list[int]
    stamp_s: list[float]
    q: list[np.ndarray]
    dq: list[np.ndarray]
    tau: list[list[float]]
    p_bar: list[tuple[float, ...]]

    @classmethod
    def empty(cls) -> _Pending:
        return cls([], [], [], [], [], [])

    def __len__(self) -> int:
        return len(self.cycle)


class PayloadAdaptation:
    """Eq. (29) for a point mass on the last link (module docstring).

    ``heldout_rms_nm`` is the identified model's held-out RMS per joint (ν = factor × it).
    Thread use: :meth:`add` on the control cycle's thread, :meth:`process` and the readers on
    the slow loop's.
    """

    def __init__(
        self,
        identified: IdentifiedModel,
        desc: RobotDescription,
        heldout_rms_nm: Sequence[float],
        settings: AdaptationSettings | None = None,
    ) -> None:
        self.identified = identified
        self.desc = desc
        self.settings = st = settings or AdaptationSettings()
        n = self.n = identified.n
        rms = np.asarray(heldout_rms_nm, dtype=float)
        if rms.shape != (n,) or not np.all(np.isfinite(rms)) or np.any(rms < 0):
            raise ConfigError(f"model adaptation needs {n} held-out RMS values >= 0, got {rms}")
        #: the paper's ν per joint [N·m]: no joint's below 1 N·m (a model that fitted its
        #: test data to the noise floor would adapt on the current's noise)
        self.nu_nm = np.maximum(st.dead_zone_factor * rms, 1.0)
        reg = identified.regressor
        self._columns = reg.payload_indices[:POINT_MASS_PARAMETERS]
        self._gamma = np.array([1.0] + [st.max_reach_m**2] * 3)
        #: the adapted point mass (δm, δm·c) [kg, kg·m], in the last link's frame
        self.delta = np.zeros(POINT_MASS_PARAMETERS)
        self._lock = threading.Lock()
        self._pending = _Pending.empty()
        self._contact_until_s = -math.inf
        self.windows_used = 0  #: windows the law took (each ``window_s`` long)
        self.windows_seen = 0
        self.windows_contact = 0
        #: squared error sums per joint over the windows used, before each window's step
        #: (the model as identified, and as adapted so far) [N·m²], and their counts
        self._sq_identified = np.zeros(n)
        self._sq_adapted = np.zeros(n)
        self._rows = np.zeros(n, dtype=int)
        #: bumped whenever :attr:`delta` moved; readers rebuild their model on a change
        self.version = 0

    # --- the control cycle's side -----------------------------------------------------------
    def add(
        self,
        cycle: int,
        stamp_s: float,
        q_rad: np.ndarray,
        dq_rad_s: np.ndarray,
        motor_torque_nm: list[float],
        p_bar: tuple[float, ...],
    ) -> None:
        """One state of free motion: its joints, the motor torque it reports, the pressures."""
        with self._lock:
            p = self._pending
            if len(p) >= MAX_PENDING:
                return  # the slow loop stalled: the newest samples wait for the next batch
            p.cycle.append(cycle)
            p.stamp_s.append(stamp_s)
            p.q.append(q_rad)
            p.dq.append(dq_rad_s)
            p.tau.append(motor_torque_nm)
            p.p_bar.append(p_bar)

    # --- the slow loop's side ---------------------------------------------------------------
    def process(self) -> int:
        """Adapt on the windows completed since the last call; returns how many were used.

        A window is ``window_s`` of consecutive cycles; an unfinished one at the end stays
        for the next call."""
        with self._lock:
            p = self._pending
            self._pending = _Pending.empty()
        if not len(p):
            return 0
        t_all = np.asarray(p.stamp_s)
        arrays = (
            t_all, np.asarray(p.q), np.asarray(p.dq), np.asarray(p.tau, dtype=float),
            np.asarray(p.p_bar, dtype=float),
        )  # fmt: skip
        runs = _unbroken_runs(np.asarray(p.cycle))
        used = 0
        for k, run in enumerate(runs):
            wins = self._windows(t_all[run])
            for a, b in wins:
                used += self._adapt_window(*(x[run[a:b]] for x in arrays))
            done = wins[-1][1] if wins else 0
            if k == len(runs) - 1 and done < len(run):  # the last run goes on next time
                rest = run[done:]
                with self._lock:
                    newer = self._pending
                    self._pending = _Pending(
                        *(
                            [old[i] for i in rest] + new
                            for old, new in zip(_fields(p), _fields(newer), strict=True)
                        )
                    )
        self.windows_used += used
        return used

    def _windows(self, t: np.ndarray) -> list[tuple[int, int]]:
        """Complete windows of a run as (start, stop) index pairs: each spans at least
        ``window_s`` from its first sample to its last."""
        out, a = [], 0
        span = self.settings.window_s
        for b in range(1, len(t)):
            if t[b] - t[a] >= span:
                out.append((a, b + 1))
                a = b + 1
        return out

    def _adapt_window(
        self,
        t: np.ndarray,
        q_all: np.ndarray,
        dq_all: np.ndarray,
        tau_all: np.ndarray,
        p_all: np.ndarray,
    ) -> int:
        """One step of the law on one window's samples (stamps, joints, motor torques,
        pressures: rows in time order): 1 if it was used, else 0.

        The torque, velocity and pressures are the window's means, the pose its middle
        sample's, the acceleration the velocity's change over it (the mean of M q̈ over a
        window is M times that, up to M's change: the velocity's noise enters divided by the
        window's length, not by one cycle's)."""
        st = self.settings
        self.windows_seen += 1
        if t[-1] < self._contact_until_s:
            return 0
        if not (
            np.all(np.isfinite(q_all)) and np.all(np.isfinite(dq_all))
            and np.all(np.isfinite(tau_all))
        ):  # fmt: skip
            return 0  # the driver refuses such states; never learn from one
        if np.any(np.diff(t) <= 0.0):
            return 0
        # sliding all through the window, one way: at rest the drive's torque includes
        # static friction no model predicts, and a reversal is friction's own transient
        sliding = np.all(dq_all >= st.min_speed_rad_s, axis=0) | np.all(
            dq_all <= -st.min_speed_rad_s, axis=0
        )
        if not np.any(sliding):
            return 0
        q = q_all[len(t) // 2][None, :]
        dq = dq_all.mean(axis=0)[None, :]
        ddq = ((dq_all[-1] - dq_all[0]) / (t[-1] - t[0]))[None, :]
        pb = p_all.mean(axis=0)[None, :]
        im = self.identified
        # the motor's torque is the model's minus the cylinders' (model.json excludes them)
        predicted = (im.torque_nm(q, dq, ddq) - cylinder_torque_nm(q, pb, self.desc))[0]
        yk = im.regressor.regressor_columns(q, dq, ddq, self._columns)[:, 0, :]  # (n, 4)
        e_identified = tau_all.mean(axis=0) - predicted
        e = e_identified - yk @ self.delta
        payload_most = st.max_mass_kg * (
            np.abs(yk[:, 0]) + st.max_reach_m * np.linalg.norm(yk[:, 1:], axis=1)
        )
        if np.any((np.abs(e_identified) > self.nu_nm + payload_most) & sliding):
            self.windows_contact += 1
            self._contact_until_s = t[-1] + st.contact_hold_s
            return 0
        self._sq_identified += np.where(sliding, e_identified**2, 0.0)
        self._sq_adapted += np.where(sliding, e**2, 0.0)
        self._rows += sliding
        mag = np.maximum(np.abs(e) - self.nu_nm, 0.0)
        e_dz = np.where(sliding, np.sign(e) * mag, 0.0) / self.nu_nm
        if np.any(e_dz):
            y_w = np.where(sliding[:, None], yk, 0.0) / self.nu_nm[:, None]
            g = self._gamma * (y_w.T @ e_dz)
            norm = 1.0 + float(np.einsum("jk,k,jk->", y_w, self._gamma, y_w))
            step = min(st.rate_per_s * float(t[-1] - t[0]), 0.5)
            self.delta = self._project(self.delta + step * g / norm)
            self.version += 1
        return 1

    def _project(self, delta: np.ndarray) -> np.ndarray:
        """Onto point masses |m| ≤ max_mass_kg at |c| ≤ max_reach_m: |m·c| ≤ |m| · reach."""
        st = self.settings
        m = min(max(float(delta[0]), -st.max_mass_kg), st.max_mass_kg)
        mc = delta[1:]
        most = abs(m) * st.max_reach_m
        size = float(np.linalg.norm(mc))
        if size > most:  # so size > 0
            mc = mc * (most / size)
        return np.concatenate([[m], mc])

    def restore(self, delta: Sequence[float], windows: int) -> None:
        """Start from a mass adapted before (:func:`load_state`), projected like any step."""
        self.delta = self._project(np.asarray(delta, dtype=float))
        self.windows_used = int(windows)
        self.version += 1

    # --- readers ----------------------------------------------------------------------------
    @property
    def mass_kg(self) -> float:
        return float(self.delta[0])

    @property
    def com_m(self) -> list[float] | None:
        """The adapted mass's centre in the last link's frame [m] (None below 10 g)."""
        m = self.mass_kg
        return None if abs(m) < 0.01 else (self.delta[1:] / m).tolist()

    def residual_rms_nm(self) -> tuple[list[float | None], list[float | None]]:
        """Per joint, the RMS error of the window-mean motor torque over the windows used so
        far, of the model as identified and as adapted up to each window (each is scored
        before it moves the estimate: an error on data the adaptation had not seen) [N·m];
        None for a joint that never slid."""

        def rms(sq: np.ndarray) -> list[float | None]:
            return [
                None if r == 0 else round(math.sqrt(s / r), 3)
                for s, r in zip(sq.tolist(), self._rows.tolist(), strict=True)
            ]

        return rms(self._sq_identified), rms(self._sq_adapted)

    def verdict(self) -> str | None:
        """Why the adapted mass must not be taken (None: it may). On the windows of this run,
        each scored before it moved the estimate, the adapted model must explain the motor
        torque better than the identified one: the squared errors over ν², summed over the
        joints, lower with it. A payload that is there lowers J2/J3's error by tens of N·m
        (and may cost a wrist some of its small error); one learned from an error that is no
        payload moves the joints' errors either way: the demo's replays showed J2 1.3 → 1.7
        and J3 0.5 → 1.25 N·m RMS with it."""
        if not np.any(self._rows):
            return "no window of free motion scored yet"
        whitened = (self._sq_adapted - self._sq_identified) / self.nu_nm**2
        if float(np.sum(whitened)) < 0.0:
            return None
        before, after = self.residual_rms_nm()
        j = int(np.argmax(whitened))
        return (f"it does not explain this run's motor torque better (J{j + 1}: {after[j]} N·m "
                f"RMS with it against {before[j]} without)")  # fmt: skip

    def adapted(self) -> IdentifiedModel:
        """The identified model with the adapted point mass as a ``payload`` effect on every
        joint (added to the model's own payload effect if it has one)."""
        im = self.identified
        coef = np.zeros(len(im.regressor.payload_indices))
        coef[:POINT_MASS_PARAMETERS] = self.delta
        effects = list(im.effects)
        every = tuple(range(self.n))
        for k, (term, c, appeared) in enumerate(effects):
            if term.name == "payload" and term.joints == every:
                effects[k] = (term, np.asarray(c, dtype=float) + coef, appeared)
                break
        else:
            effects.append((EffectTerm("payload", every), coef, APPEARED))
        return replace(im, effects=effects)

    def report(self) -> dict:
        before, after = self.residual_rms_nm()
        com = self.com_m
        return {
            "mass_kg": round(self.mass_kg, 4),
            "com_m": None if com is None else [round(v, 4) for v in com],
            "windows_used": self.windows_used,
            "windows_contact": self.windows_contact,
            "windows_seen": self.windows_seen,
            "residual_rms_identified_nm": before,
            "residual_rms_adapted_nm": after,
            "not_taken": self.verdict(),
        }


def _fields(p: _Pending) -> tuple[list, ...]:
    return (p.cycle, p.stamp_s, p.q, p.dq, p.tau, p.p_bar)


def _unbroken_runs(cycles: np.ndarray) -> list[np.ndarray]:
    """Index runs of consecutive cycle numbers."""
    if cycles.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(cycles) != 1) + 1
    return np.split(np.arange(cycles.size), breaks)


def model_sha256(path: str | Path) -> str:
    """The identity of the model file an adapted mass belongs to."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def state_document(adaptation: PayloadAdaptation, model_sha256: str) -> dict:
    """What :func:`write_state` keeps of ``adaptation``, as it is now (a copy: the adaptation
    may go on while another thread writes it)."""
    return {
        "format": STATE_FORMAT,
        "version": STATE_VERSION,
        "model_sha256": model_sha256,
        "saved_unix_s": round(time.time(), 3),
        "delta": [float(v) for v in adaptation.delta],
        "mass_kg": round(adaptation.mass_kg, 4),
        "com_m": adaptation.com_m,
        "windows_used": adaptation.windows_used,
    }


def write_state(path: str | Path, doc: dict) -> None:
    """Write ``doc`` to a temporary file, flush it to disk and rename it over ``path`` (a crash
    leaves the old file or the new one, never half of one)."""
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    with tmp.open("w") as f:
        f.write(json.dumps(doc, indent=1) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, p)
    fd = os.open(p.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def load_state(path: str | Path, model_sha256: str) -> tuple[list[float], int] | None:
    """The adapted mass kept in ``path`` for the model ``model_sha256``: (δ, windows), or None
    when there is none or it belongs to another model (re-identified since). A file that is
    not one raises ValueError naming what is wrong."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{p}: not a readable adapted-payload file: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != STATE_FORMAT:
        raise ValueError(f"{p}: not a {STATE_FORMAT} file")
    if doc.get("version") != STATE_VERSION:
        raise ValueError(f"{p}: version {doc.get('version')!r}, this build reads {STATE_VERSION}")
    if doc.get("model_sha256") != model_sha256:
        return None
    delta, windows = doc.get("delta"), doc.get("windows_used", 0)
    if not (
        isinstance(delta, list) and len(delta) == POINT_MASS_PARAMETERS
        and all(isinstance(v, int | float) and math.isfinite(v) for v in delta)
    ):  # fmt: skip
        raise ValueError(f"{p}: delta {delta!r} is not {POINT_MASS_PARAMETERS} finite numbers")
    if not isinstance(windows, int) or windows < 0:
        raise ValueError(f"{p}: windows_used {windows!r} is not a count")
    return [float(v) for v in delta], windows
