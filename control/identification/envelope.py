"""The training envelope of an identified model: the range of positions and velocities per
joint it was fitted on, which every friction and effect column clips its input to
(:mod:`.terms`), and, while the analysis runs, each joint's torque room, by which rule (vii)
of :mod:`.effect_rules` bounds a spring."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Envelope:
    """Range of positions [rad] and velocities [rad/s] per joint that a model was fitted on;
    arrays (n,). Friction and effect terms clip their inputs to it (module docstring)."""

    q_min: np.ndarray
    q_max: np.ndarray
    dq_min: np.ndarray
    dq_max: np.ndarray
    #: (n,) the joint's torque room on the fitted samples [N·m]: the largest torque its channel
    #: read plus the largest the URDF's rigid body asks of it (rule (vii) of
    #: :mod:`.effect_rules` bounds a spring by it); None where not known (a model read back
    #: from its file: only the analysis judges effects)
    torque_room_nm: np.ndarray | None = None

    @classmethod
    def of(
        cls, q: np.ndarray, dq: np.ndarray, torque_room_nm: np.ndarray | None = None
    ) -> Envelope:
        """The envelope of samples ``q``, ``dq`` (T, n); the velocity range always holds 0."""
        return cls(
            q.min(axis=0),
            q.max(axis=0),
            np.minimum(dq.min(axis=0), 0.0),
            np.maximum(dq.max(axis=0), 0.0),
            torque_room_nm,
        )

    def clip_q(self, j: int, q: np.ndarray) -> np.ndarray:
        return np.clip(q, self.q_min[j], self.q_max[j])

    def clip_dq(self, j: int, dq: np.ndarray) -> np.ndarray:
        return np.clip(dq, self.dq_min[j], self.dq_max[j])

    def outside(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """(T, n) True where a sample's position or velocity lies outside the envelope."""
        return (q < self.q_min) | (q > self.q_max) | (dq < self.dq_min) | (dq > self.dq_max)

    def to_json(self) -> dict[str, list[float]]:
        return {
            "q_min_rad": self.q_min.tolist(),
            "q_max_rad": self.q_max.tolist(),
            "dq_min_rad_s": self.dq_min.tolist(),
            "dq_max_rad_s": self.dq_max.tolist(),
        }

    @classmethod
    def from_json(cls, doc: dict[str, list[float]]) -> Envelope:
        keys = ("q_min_rad", "q_max_rad", "dq_min_rad_s", "dq_max_rad_s")
        return cls(*(np.asarray(doc[k], dtype=float) for k in keys))
