"""The whole models of an analysis: one fit, the effects of both cases, the joints on a fallback.

Every model ``leadthrough analyze`` judges or writes is assembled here from the same parts, so
that each carries the same effects whatever predicts a joint's own torque:

- the training guard's choice (:func:`.guard.guard_joints`) and the model file;
- the second look's three candidates on the leading test rows (:func:`.guard.guard_on_test`):
  that choice, every joint on plain least squares, every joint zero.

The effects found on the training files (case (A) of :mod:`.effects`) leave a joint on a
fallback: their columns were fitted with the full model's parameters, which that joint no longer
uses (:func:`restricted`). The effects that appeared between the runs (case (B)) stay on every
joint they act on: they were fitted on the residual of each joint's own prediction, plain ones
included, and a tool mounted between the runs weighs on a joint whatever predicts the rest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from control.identification import effects as fx
from control.identification.envelope import Envelope
from control.identification.fit import FrictionFit, model_from_solution
from control.identification.guard import CHOSEN
from control.identification.lsq import Solution
from control.identification.model import PLAIN_LS, ZERO, IdentifiedModel, PlainJoint, plain_key
from control.identification.rigid import RobotRegressor
from control.identification.terms import EffectTerm


def restricted(effects: Sequence[fx.Accepted], plain: set[int]) -> list[tuple[Any, Any, str]]:
    """Training-fitted effects without the joints kept on a fallback (their columns were
    fitted with the full model's parameters, which those joints no longer use)."""
    out = []
    for a in effects:
        joints = tuple(j for j in a.term.joints if j not in plain)
        if not a.term.is_linear:
            out.append((a.term, a.coef, a.appeared))
        elif joints:
            term = EffectTerm(a.term.name, joints, dict(a.term.setting))
            out.append((term, a.coef, a.appeared))
    return out


@dataclass(frozen=True)
class Assembly:
    """The parts of every whole model of one analysis (module docstring)."""

    reg: RobotRegressor
    friction: FrictionFit
    solution: Solution
    urdf: str
    metadata: dict[str, Any]
    envelope: Envelope | None
    chain: Any
    #: each joint's plain least-squares coefficients (``plain_key(j)`` → (m,) array)
    plain_coef: dict[str, np.ndarray]
    #: case (A): fitted on the training files with the model's parameters
    trained: Sequence[fx.Accepted] = ()
    #: case (B): appeared between the training and the test run
    between: Sequence[fx.Accepted] = ()

    def model(self, joints: dict[int, PlainJoint], between: bool = True) -> IdentifiedModel:
        """The model with ``joints`` (index → fallback) on their fallback; ``between`` False
        leaves case (B) out (the prediction case (B) searches the residual of)."""
        effects = restricted(self.trained, set(joints))
        if between:
            effects += [(a.term, a.coef, a.appeared) for a in self.between]
        return model_from_solution(
            self.reg, self.friction, self.solution, effects, self.urdf, self.metadata,
            self.envelope, joints, self.chain,
        )  # fmt: skip

    def fallback(self, j: int, kind: str) -> PlainJoint:
        """Joint ``j`` on plain least squares (``kind`` PLAIN_LS) or zero (ZERO)."""
        if kind not in (PLAIN_LS, ZERO):
            raise ValueError(f"a fallback is {PLAIN_LS!r} or {ZERO!r}, not {kind!r}")
        coef = np.asarray(self.plain_coef[plain_key(j)], dtype=float)
        return PlainJoint.from_coef(j, coef if kind == PLAIN_LS else 0.0 * coef, kind)

    def second_look(self, plain: dict[int, PlainJoint]) -> dict[str, IdentifiedModel]:
        """The three whole models the second look compares (:func:`.guard.guard_on_test`):
        the training guard's choice ``plain``, every joint on plain least squares, every
        joint zero; each with the effects that appeared between the runs."""
        every = range(self.reg.n)
        return {
            CHOSEN: self.model(dict(plain)),
            PLAIN_LS: self.model({j: self.fallback(j, PLAIN_LS) for j in every}),
            ZERO: self.model({j: self.fallback(j, ZERO) for j in every}),
        }
