"""Excitation motions for identification (Section 3.1 / 4 of the paper), as pure functions.

Each experiment is a joint trajectory sampled at the controller cycle: positions [rad] and
velocities [rad/s] for every joint, starting and ending at rest at the start pose, so it can be
sent as position/velocity commands through the vendor's closed loop. Segments carry labels so
that a recording can be cut into runs afterwards.

* friction runs — one joint at a time reciprocates at constant speed over part of its range,
  parabolic blends (constant acceleration) in the first and last 5 % of each stroke, a dwell at
  each end equal to one one-way time; speeds 0.5–4 °/s and faster (paper, Section 4);
* gravity runs — slow forward/backward sweeps of one joint: at equal angles the half-sum of the
  two torques is gravity, the half-difference friction;
* inertia runs — joint i slow and constant while joint j accelerates (off-diagonal terms), and
  joint j alone accelerating (diagonal terms);
* multi-sine — every joint a sum of sines with different frequencies (a Fourier excitation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Segment:
    label: str  #: e.g. "friction/j2/2.0dps", "multisine/seed3"
    q_rad: np.ndarray  #: (T, n)
    dq_rad_s: np.ndarray  #: (T, n)


def _blend_stroke(distance: float, speed: float, dt: float, blend: float = 0.05) -> np.ndarray:
    """Positions (from 0 to ``distance``) of one stroke at constant ``speed`` whose first and
    last ``blend`` fraction of the path are constant-acceleration parabolas."""
    d = abs(distance)
    d_b = blend * d  # path in each blend
    t_b = 2.0 * d_b / speed  # time to reach speed with constant acceleration over d_b
    acc = speed / t_b
    t_c = (d - 2 * d_b) / speed
    total = 2 * t_b + t_c
    t = np.arange(0.0, total + dt / 2, dt)
    s = np.where(
        t < t_b,
        0.5 * acc * t**2,
        np.where(
            t < t_b + t_c,
            d_b + speed * (t - t_b),
            d - 0.5 * acc * np.clip(total - t, 0, None) ** 2,
        ),
    )
    return np.sign(distance) * np.clip(s, 0.0, d)


def _differentiate(q: np.ndarray, dt: float) -> np.ndarray:
    return np.gradient(q, dt, axis=0)


def reciprocating(
    q0: np.ndarray,
    joint: int,
    amplitude_rad: float,
    speed_rad_s: float,
    dt: float,
    strokes: int = 2,
) -> Segment:
    """Joint ``joint`` (0-based) goes +amplitude and back ``strokes`` times, dwelling at each end
    for one one-way time. Other joints stay at ``q0``."""
    stroke = _blend_stroke(amplitude_rad, speed_rad_s, dt)
    dwell = np.zeros(len(stroke))
    path = []
    for _ in range(strokes):
        path += [stroke, dwell + amplitude_rad, amplitude_rad - stroke, dwell]
    x = np.concatenate(path)
    q = np.tile(q0, (len(x), 1))
    q[:, joint] += x
    deg_s = np.degrees(speed_rad_s)
    return Segment(f"friction/j{joint + 1}/{deg_s:.1f}dps", q, _differentiate(q, dt))


def friction_runs(
    q0: np.ndarray,
    joints: list[int],
    amplitude_rad: float,
    speeds_deg_s: tuple[float, ...],
    dt: float,
) -> list[Segment]:
    """The paper's friction experiment: each joint alone, each speed, forward and back."""
    return [
        reciprocating(q0, j, amplitude_rad, np.radians(v), dt, strokes=1)
        for j in joints
        for v in speeds_deg_s
    ]


def gravity_runs(
    q0: np.ndarray, joints: list[int], amplitude_rad: float, speed_deg_s: float, dt: float
) -> list[Segment]:
    """Slow sweeps forward and backward (half-sum = gravity, half-difference = friction)."""
    out = []
    for j in joints:
        seg = reciprocating(q0, j, amplitude_rad, np.radians(speed_deg_s), dt, strokes=1)
        out.append(Segment(f"gravity/j{j + 1}", seg.q_rad, seg.dq_rad_s))
    return out


def inertia_runs(
    q0: np.ndarray,
    pairs: list[tuple[int, int]],
    amplitude_rad: float,
    period_s: float,
    slow_speed_rad_s: float,
    dt: float,
    cycles: int = 3,
) -> list[Segment]:
    """Joint i moves slowly at constant speed while joint j oscillates (accelerates); i == j
    gives the diagonal run."""
    t = np.arange(0.0, cycles * period_s, dt)
    w = 2 * np.pi / period_s
    ramp = np.minimum(1.0, np.minimum(t, t[-1] - t) / (0.5 * period_s))  # soft start and end
    out = []
    for i, j in pairs:
        q = np.tile(q0, (len(t), 1))
        q[:, j] += amplitude_rad * ramp * np.sin(w * t) ** 2
        if i != j:
            slow = _blend_stroke(slow_speed_rad_s * t[-1], slow_speed_rad_s, dt)
            slow = np.interp(t, np.arange(len(slow)) * dt, slow)
            q[:, i] += slow - slow * (t / t[-1]) ** 8  # returns near the start at the end
        out.append(Segment(f"inertia/j{i + 1}-j{j + 1}", q, _differentiate(q, dt)))
    return out


def transfer(
    q_from: np.ndarray, q_to: np.ndarray, peak_speed_rad_s: float, dt: float
) -> np.ndarray:
    """Positions (T, n) of a move from rest at ``q_from`` to rest at ``q_to``, every joint on
    one smoothstep profile (3s² − 2s³) timed so that no joint exceeds ``peak_speed_rad_s`` (its
    peak speed is 1.5 × distance / duration): a slow sweep, the speeds teaching uses."""
    d = np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float)
    if not peak_speed_rad_s > 0:
        raise ValueError(f"transfer speed {peak_speed_rad_s} rad/s must be > 0")
    duration = 1.5 * float(np.abs(d).max()) / peak_speed_rad_s
    steps = max(2, int(np.ceil(duration / dt)) + 1)
    s = np.linspace(0.0, 1.0, steps)
    s = s**2 * (3 - 2 * s)
    return q_from + s[:, None] * d


def multisine(
    q0: np.ndarray,
    amplitude_rad: np.ndarray,
    base_hz: float,
    harmonics: int,
    duration_s: float,
    dt: float,
    seed: int,
    offset_rad: np.ndarray | None = None,
    transfer_speed_rad_s: float = 0.1,
) -> Segment:
    """Every joint a sum of ``harmonics`` sines of the base frequency with random phases, faded
    in and out so the motion starts and ends at rest at ``q0``.

    With ``offset_rad`` the sines are centred on ``q0 + offset_rad``: the segment first moves
    there and at the end back to ``q0`` (:func:`transfer`, at most ``transfer_speed_rad_s``),
    so that a plan can excite the arm over the poses the operator works in, not only around
    the one it starts from (a model is not validated where it was never moved)."""
    if offset_rad is not None and np.any(np.asarray(offset_rad, dtype=float) != 0.0):
        centre = np.asarray(q0, dtype=float) + np.asarray(offset_rad, dtype=float)
        there = transfer(np.asarray(q0, dtype=float), centre, transfer_speed_rad_s, dt)
        core = multisine(centre, amplitude_rad, base_hz, harmonics, duration_s, dt, seed)
        q = np.vstack([there, core.q_rad[1:], there[::-1][1:]])
        return Segment(core.label, q, _differentiate(q, dt))
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, dt)
    n = len(q0)
    q = np.tile(q0, (len(t), 1)).astype(float)
    fade = np.clip(np.minimum(t, duration_s - t) / 1.0, 0.0, 1.0)
    # smootherstep: zero velocity and acceleration at both ends, where the sines (centred on
    # the centre pose, not starting at it) are faded in and out
    fade = fade**3 * (fade * (6 * fade - 15) + 10)
    for j in range(n):
        k = np.arange(1, harmonics + 1)
        phases = rng.uniform(0, 2 * np.pi, harmonics)
        weights = rng.uniform(0.5, 1.0, harmonics) / k
        x = (weights[:, None] * np.sin(2 * np.pi * base_hz * k[:, None] * t + phases[:, None])).sum(
            0
        )
        x -= x[0]
        x *= amplitude_rad[j] / max(np.abs(x).max(), 1e-12)
        x -= 0.5 * (x.max() + x.min())  # its excursion centred on the centre pose
        q[:, j] += fade * x
    return Segment(f"multisine/seed{seed}", q, _differentiate(q, dt))


def teaching_strokes(
    q0: np.ndarray,
    amplitude_rad: np.ndarray,
    speeds_deg_s: tuple[float, float],
    strokes: int,
    rest_s: float,
    dt: float,
    seed: int,
    offset_rad: np.ndarray | None = None,
    transfer_speed_rad_s: float = 0.1,
) -> Segment:
    """A motion like a painter's teaching: every joint at once, ``strokes`` slow strokes, each
    joint at its own speed drawn log-uniformly in ``speeds_deg_s`` [°/s], reversing at each
    stroke (to 50-100 % of ``amplitude_rad`` on the other side of the centre) and resting
    ``rest_s`` between strokes, so each stroke starts from rest (breakaway). Centred on ``q0 +
    offset_rad``, reached from ``q0`` and left back to it at rest (:func:`transfer`)."""
    rng = np.random.default_rng(seed)
    q0 = np.asarray(q0, dtype=float)
    n = q0.size
    lo, hi = (float(v) for v in speeds_deg_s)
    if not 0 < lo <= hi:
        raise ValueError(f"teaching speeds {speeds_deg_s} °/s must be 0 < low <= high")
    if strokes < 1 or rest_s < 0:
        raise ValueError(f"teaching strokes {strokes} must be >= 1 and rest {rest_s} s >= 0")
    amp = np.broadcast_to(np.asarray(amplitude_rad, dtype=float), (n,))
    centre = q0 + (0.0 if offset_rad is None else np.asarray(offset_rad, dtype=float))
    rest = max(1, round(rest_s / dt))
    pos = centre.copy()
    side = rng.choice([-1.0, 1.0], n)
    pieces = [np.tile(pos, (rest, 1))]
    for _ in range(strokes):
        speed = np.radians(np.exp(rng.uniform(np.log(lo), np.log(hi), n)))
        target = centre + side * amp * rng.uniform(0.5, 1.0, n)
        paths = [
            _blend_stroke(target[j] - pos[j], speed[j], dt) if target[j] != pos[j] else np.zeros(1)
            for j in range(n)
        ]
        steps = max(p.size for p in paths)
        block = np.column_stack([np.pad(p, (0, steps - p.size), mode="edge") for p in paths])
        pieces += [pos + block, np.tile(target, (rest, 1))]
        pos, side = target, -side
    q = np.vstack(pieces)
    if np.any(centre != q0):
        q = np.vstack([transfer(q0, centre, transfer_speed_rad_s, dt), q[1:]])
    q = np.vstack([q, transfer(pos, q0, transfer_speed_rad_s, dt)[1:]])
    return Segment(f"teaching/seed{seed}", q, _differentiate(q, dt))


def velocity_steps(
    q0: np.ndarray, joints: list[int], speed_rad_s: float, step_s: float, dt: float
) -> list[Segment]:
    """The inner-loop experiment, one segment per joint: at rest, a velocity step to
    ``+speed`` for ``step_s``, rest, a step to ``-speed`` for ``step_s`` (back at ``q0``), rest.
    The command's velocity jumps, so the loop's velocity error is large for a few cycles: the
    current then shows K_p and K_I of eq. (19) apart (:mod:`control.identification.inner_loop`).
    """
    if speed_rad_s <= 0 or step_s <= 0:
        raise ValueError(f"velocity steps need speed and step_s > 0, got {speed_rad_s}, {step_s}")
    rest, moving = round(0.3 / dt), round(step_s / dt)
    profile = np.r_[np.zeros(rest), np.full(moving, speed_rad_s), np.zeros(rest),
                    np.full(moving, -speed_rad_s), np.zeros(rest)]  # fmt: skip
    travel = np.r_[0.0, np.cumsum(profile[:-1]) * dt]
    out = []
    for j in joints:
        q = np.tile(np.asarray(q0, dtype=float), (len(profile), 1))
        dq = np.zeros_like(q)
        q[:, j] += travel
        dq[:, j] = profile
        out.append(Segment(f"inner_loop/j{j + 1}", q, dq))
    return out


def with_limits(seg: Segment, lower: np.ndarray, upper: np.ndarray, margin: float) -> Segment:
    """Refuse (ValueError) a segment that would leave the joint range minus ``margin``."""
    lo, hi = seg.q_rad.min(0), seg.q_rad.max(0)
    bad = np.flatnonzero((lo < lower + margin) | (hi > upper - margin))
    if bad.size:
        j = int(bad[0])
        raise ValueError(
            f"{seg.label}: joint {j + 1} would reach [{lo[j]:.3f}, {hi[j]:.3f}] rad, outside "
            f"its range [{lower[j]:.3f}, {upper[j]:.3f}] less {margin} rad"
        )
    return seg


def build_plan(
    plan: dict, q0: np.ndarray, lower: np.ndarray, upper: np.ndarray, dt: float, margin: float
) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """Turn a plan (JSON object, see PLAN_KEYS) into (label, role, q, dq) segments, each
    starting and ending at rest at ``q0``, separated by ``pause_s`` holds. Raises ValueError
    naming what is wrong. Joints in the plan are 1-based.

    Plan keys: ``plan_id``; ``friction`` {joints, amplitude_rad, speeds_deg_s}; ``gravity``
    {joints, amplitude_rad, speed_deg_s}; ``inertia`` {pairs, amplitude_rad, period_s,
    slow_speed_deg_s}; ``inner_loop`` {joints, speed_rad_s, step_s} (velocity steps, role
    "inner_loop"); ``multisine`` [{seed, duration_s, amplitude_rad, base_hz, harmonics, role,
    offset_rad, transfer_speed_rad_s}] (role "train" or "test"; the optional offset centres the
    sines away from the start pose, :func:`multisine`); ``teaching`` [{seed, strokes,
    amplitude_rad, speeds_deg_s: [low, high], rest_s, offset_rad, transfer_speed_rad_s, role}]
    (:func:`teaching_strokes`; role "train", "test" or "validate", the default: recorded and
    scored on the identified model, never given to the fit); ``pause_s``.
    """
    unknown = set(plan) - PLAN_KEYS
    if unknown:
        raise ValueError(f"unknown plan key(s) {sorted(unknown)}; allowed {sorted(PLAN_KEYS)}")
    n = len(q0)

    def joints(spec: dict, key: str = "joints") -> list[int]:
        js = [int(j) - 1 for j in spec[key]]
        if any(not 0 <= j < n for j in js):
            raise ValueError(f"{key} {spec[key]} must be 1..{n}")
        return js

    segs: list[Segment] = []
    roles: list[str] = []
    try:
        if "friction" in plan:
            f = plan["friction"]
            s = friction_runs(q0, joints(f), float(f["amplitude_rad"]),
                              tuple(float(v) for v in f["speeds_deg_s"]), dt)  # fmt: skip
            segs += s
            roles += ["train"] * len(s)
        if "gravity" in plan:
            g = plan["gravity"]
            s = gravity_runs(q0, joints(g), float(g["amplitude_rad"]), float(g["speed_deg_s"]), dt)
            segs += s
            roles += ["train"] * len(s)
        if "inertia" in plan:
            m = plan["inertia"]
            pairs = [(int(i) - 1, int(j) - 1) for i, j in m["pairs"]]
            if any(not (0 <= i < n and 0 <= j < n) for i, j in pairs):
                raise ValueError(f"inertia pairs {m['pairs']} must be 1..{n}")
            s = inertia_runs(q0, pairs, float(m["amplitude_rad"]), float(m["period_s"]),
                             np.radians(float(m["slow_speed_deg_s"])), dt)  # fmt: skip
            segs += s
            roles += ["train"] * len(s)
        if "inner_loop" in plan:
            v = plan["inner_loop"]
            s = velocity_steps(q0, joints(v), float(v["speed_rad_s"]), float(v["step_s"]), dt)
            segs += s
            roles += ["inner_loop"] * len(s)
        for spec in plan.get("multisine", []):
            amp = np.broadcast_to(np.asarray(spec["amplitude_rad"], dtype=float), (n,))
            offset = np.broadcast_to(np.asarray(spec.get("offset_rad", 0.0), dtype=float), (n,))
            segs.append(multisine(q0, amp, float(spec["base_hz"]), int(spec["harmonics"]),
                                  float(spec["duration_s"]), dt, int(spec["seed"]), offset,
                                  float(spec.get("transfer_speed_rad_s", 0.1))))  # fmt: skip
            role = spec.get("role", "train")
            if role not in ("train", "test"):
                raise ValueError(f"multisine role {role!r} must be train or test")
            roles.append(role)
        for spec in plan.get("teaching", []):
            amp = np.broadcast_to(np.asarray(spec["amplitude_rad"], dtype=float), (n,))
            offset = np.broadcast_to(np.asarray(spec.get("offset_rad", 0.0), dtype=float), (n,))
            lo, hi = (float(v) for v in spec["speeds_deg_s"])
            segs.append(teaching_strokes(q0, amp, (lo, hi), int(spec["strokes"]),
                                         float(spec["rest_s"]), dt, int(spec["seed"]), offset,
                                         float(spec.get("transfer_speed_rad_s", 0.1))))  # fmt: skip
            role = spec.get("role", VALIDATE)
            if role not in ("train", "test", VALIDATE):
                raise ValueError(f"teaching role {role!r} must be train, test or {VALIDATE}")
            roles.append(role)
    except KeyError as exc:
        raise ValueError(f"plan entry is missing {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"bad plan value: {exc}") from None
    if not segs:
        raise ValueError(
            "plan has no experiment (friction, gravity, inertia, inner_loop, multisine, teaching)"
        )
    pause = np.tile(q0, (max(1, round(float(plan.get("pause_s", 0.5)) / dt)), 1))
    out = []
    for seg, role in zip(segs, roles, strict=True):
        with_limits(seg, lower, upper, margin)
        q = np.vstack([seg.q_rad, pause])
        dq = np.vstack([seg.dq_rad_s, np.zeros_like(pause)])
        out.append((seg.label, role, q, dq))
    return out


PLAN_KEYS = {
    "plan_id", "friction", "gravity", "inertia", "inner_loop", "multisine", "teaching", "pause_s",
}  # fmt: skip

#: the role of a segment recorded to judge the identified model on, never given to the fit
VALIDATE = "validate"
