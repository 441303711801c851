"""The compiled per-cycle model's tables (control/rt, issue 48), made once at load.

The control cycle evaluates the model the law compensates in Rust (``control._rt``): the
rigid-body chain (``chain.rs``: inverse dynamics, its regressor, the mass matrix, the tool's
Jacobian) and the model on it (``point_model.rs``: rigid body and payload as the regressor times
fixed weights, friction of each family, the identified effects, the cylinders). It has no
pinocchio and reads no model file: this module hands it the same numbers as plain JSON:

* :func:`chain_table` reads a pinocchio model (the one :class:`RigidBodyModel` or the
  identification's :class:`RobotRegressor` built from the URDF): per joint its parent, its
  placement at q = 0, its kind and axis (revolute or prismatic: another type is refused by
  name), the
  ten dynamic parameters of its body and its armature; the gravity; the tool frame.
* :func:`point_model_table` turns a model, declared (the description's rigid body and eq. 15
  friction) or identified (an :class:`IdentifiedModel`), into the point model's table: the weights
  ``W`` with ``rigid_j = Y(q, dq, 0)[j] · W[j]`` (an identified model's base parameters on their
  independent columns, a plain joint's own row; a declared model's link parameters on every row),
  the friction of each joint, the effects that act at run time, the training envelope, the
  cylinders' constants.

tests/unit/test_control_rt_chain.py and test_control_rt_model.py check the compiled numbers
against pinocchio and the vectorised model.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pinocchio as pin

    from control.identification.model import IdentifiedModel
    from control.model.dynamics import RigidBodyModel
    from gateway.robot.description import RobotDescription

CHAIN_FORMAT = "leadthrough-rigid-chain"
CHAIN_VERSION = 1
MODEL_FORMAT = "leadthrough-point-model"
MODEL_VERSION = 1

#: pinocchio's revolute (R) and prismatic (P) joints along a frame axis
_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}

#: effects with no run-time torque (a lag of the measurement chain, a drift in a recording's
#: own clock): left out as ``IdentifiedModel.torque_nm`` leaves them out without a time
NOT_AT_RUN_TIME = ("time_delay", "thermal_drift")


def _floats(values: Any) -> Any:
    return np.asarray(values, dtype=float).tolist()


def _placement(se3: pin.SE3) -> dict[str, Any]:
    return {"rotation": _floats(se3.rotation), "translation": _floats(se3.translation)}


def _kind_axis(joint: Any, name: str) -> tuple[str, list[float]]:
    """("revolute" or "prismatic", the unit axis in the joint's frame) of a pinocchio joint."""
    short = joint.shortname()
    for prefix, kind in (("JointModelR", "revolute"), ("JointModelP", "prismatic")):
        rest = short.removeprefix(prefix)
        if rest in _AXES:
            return kind, list(_AXES[rest])
        if rest in ("evoluteUnaligned", "rismaticUnaligned"):
            axis = np.asarray(joint.extract().axis, dtype=float)
            return kind, _floats(axis / np.linalg.norm(axis))
    raise ValueError(
        f"joint {name!r} is a {short}: the compiled model takes revolute and prismatic joints "
        "only (a continuous joint: give it limits, type revolute)"
    )


def chain_table(
    model: pin.Model, armature_kgm2: Any = None, tool_frame: str | None = None
) -> dict[str, Any]:
    """The chain of the pinocchio ``model`` (module docstring); ``armature_kgm2`` per joint
    (default 0); the tool frame named ``tool_frame`` (default: the last joint's frame)."""
    n = model.njoints - 1
    kinds = [_kind_axis(model.joints[i], model.names[i]) for i in range(1, model.njoints)]
    if model.nq != n or model.nv != n:  # pragma: no cover - every kind above has one
        raise ValueError(f"the model has {model.nq} positions for {n} joints: one each expected")
    armature = np.zeros(n) if armature_kgm2 is None else np.asarray(armature_kgm2, dtype=float)
    joints = []
    for i in range(1, model.njoints):
        parent = int(model.parents[i])
        kind, axis = kinds[i - 1]
        joints.append({
            "name": model.names[i],
            "parent": None if parent == 0 else parent - 1,
            "placement": _placement(model.jointPlacements[i]),
            "kind": kind,
            "axis": axis,
            "inertia": _floats(model.inertias[i].toDynamicParameters()),
            "armature": float(armature[i - 1]),
        })  # fmt: skip
    if tool_frame is None:
        tool = {"joint": n - 1, "placement": {"rotation": _floats(np.eye(3)),
                                              "translation": [0.0, 0.0, 0.0]}}  # fmt: skip
    else:
        if not model.existFrame(tool_frame):
            raise ValueError(f"the model has no frame {tool_frame!r}")
        frame = model.frames[model.getFrameId(tool_frame)]
        tool = {"joint": int(frame.parentJoint) - 1, "placement": _placement(frame.placement)}
    return {
        "format": CHAIN_FORMAT,
        "version": CHAIN_VERSION,
        "gravity_m_s2": _floats(model.gravity.linear),
        "joints": joints,
        "tool": tool,
    }


def _cylinders(desc: RobotDescription) -> list[dict[str, Any]]:
    out = []
    for spec in desc.cylinders:
        crank = spec.kind == "j2_crank"
        ab, ac = float(spec.ab_m), float(spec.ac_m) if crank else 0.0  # type: ignore[arg-type]
        lever = spec.piston_area_m2 * ab * (ac if crank else 1.0)
        out.append({"joint": int(spec.joint_index), "crank": crank, "ab_m": ab, "ac_m": ac,
                    "lever": float(lever), "sign": float(spec.torque_sign)})  # fmt: skip
    return out


def _identified(im: IdentifiedModel) -> dict[str, Any]:
    """The weights, friction, effects and envelope of an identified model (the module
    docstring; the same reading as ``IdentifiedModel.torque_nm`` at ddq = 0)."""
    from control.identification.terms import EffectTerm

    reg = im.regressor
    n = reg.n
    n_link = 10 * n
    base = reg.base.independent
    links = base < n_link  # Y_b β = Y[:, independent] β: armature columns vanish at ddq = 0
    w_rigid = np.zeros((n, n_link))
    w_rigid[:, base[links]] = np.asarray(im.beta, dtype=float)[links]
    for j, pj in im.plain_joints.items():
        w_rigid[j] = 0.0
        w_rigid[j, base[links]] = np.asarray(pj.beta, dtype=float)[links]
    w_payload = np.zeros((n, n_link))
    friction: list[dict[str, Any] | None] = [None] * n
    effects = []
    for term, coef in zip(im.friction_terms, im.friction_coef, strict=True):
        friction[term.joint] = friction_table(term, coef)
        if term.stribeck_rad_s is not None and term.joint not in im.plain_joints:
            # the friction's Gaussian Stribeck rise: the cycle's stribeck column, same formula
            rise = EffectTerm("stribeck", (term.joint,), {"velocity_rad_s": term.stribeck_rad_s})
            effects.append(_effect(rise, coef[-1:]))
    for j, pj in im.plain_joints.items():
        coef = [pj.coulomb_nm, pj.viscous_nm_s_per_rad, pj.offset_nm]
        friction[j] = {"kind": "plain", "coef": _floats(coef)}
    for term, coef, _ in im.effects:
        if term.name in NOT_AT_RUN_TIME:
            continue
        if term.name == "payload":
            for j in term.joints:
                w_payload[j, reg.payload_indices] += np.asarray(coef, dtype=float)
            continue
        effects.append(_effect(term, coef))
    env = im.envelope
    envelope = None
    if env is not None:
        envelope = {"q_min": _floats(env.q_min), "q_max": _floats(env.q_max),
                    "dq_min": _floats(env.dq_min), "dq_max": _floats(env.dq_max)}  # fmt: skip
    return {
        "coriolis": True,
        "w_rigid": _floats(w_rigid),
        "w_payload": _floats(w_payload) if np.any(w_payload) else None,
        "envelope": envelope,
        "friction": friction,
        "effects": effects,
    }


def friction_table(term: Any, coef: Any) -> dict[str, Any]:
    """One joint's friction entry of the point model: a fitted :class:`FrictionTerm` and its
    coefficients. A friction with memory (``presliding_rad``) enters as the sliding friction
    of its family, the same coefficients with the velocity's sign: the cycle evaluates one
    state at a time, where the model slides (:attr:`.identification.terms.Context.sequence`);
    what the memory adds, the torque a joint holds at rest and across a reversal, is the
    stiction the law meets at rest, not a torque the model commands."""
    from control.identification.friction_law import FRICTION_PARAM_NAMES
    from control.model.friction import eq15_row

    n_family = len(FRICTION_PARAM_NAMES[term.kind])
    coef = list(coef)[:n_family]  # a Gaussian Stribeck rise goes with the effects (_identified)
    if term.kind == "eq15":
        row = eq15_row(coef, term.q_e_rad_s, term.gear_ratio, term.sign_width_rad_s)
        return {"kind": "eq15", "row": _floats(row)}
    if term.kind in ("eq14", "simple"):
        return {"kind": term.kind, "coef": _floats(coef), "q_e_rad_s": float(term.q_e_rad_s)}
    raise ValueError(f"unknown friction model {term.kind!r}")


def _effect(term: Any, coef: Any) -> dict[str, Any]:
    """One effect on its single joint; an effect the compiled model does not know is refused
    here, at load, by name (never dropped)."""
    name, s = term.name, term.setting
    if len(term.joints) != 1:
        raise ValueError(f"effect {name!r} acts on {len(term.joints)} joints: one expected")
    out: dict[str, Any] = {"name": name, "joint": int(term.joints[0]), "coef": _floats(coef)}
    if name == "position_ripple":
        out["cycles_per_rev"] = float(s["cycles_per_rev"])
    elif name == "stribeck":
        out["velocity_rad_s"] = float(s["velocity_rad_s"])
    elif name == "wrist_coupling":
        out["from_joint"], out["source"] = int(s["from_joint"]), str(s["source"])
    elif name not in ("spring", "load_dependent_friction"):
        raise ValueError(f"effect {name!r} cannot be evaluated per cycle")
    return out


def point_model_table(
    desc: RobotDescription,
    identified: IdentifiedModel | None = None,
    rigid: RigidBodyModel | None = None,
    friction_rows: Any = None,
) -> dict[str, Any]:
    """The point model (module docstring) of the robot ``desc`` (its cylinders) with an
    ``identified`` model, or else a declared one: the ``rigid`` body and eq. (15) friction
    ``friction_rows`` (n, 10) (:class:`~control.model.friction.Eq15Friction` ``.rows``)."""
    if identified is not None:
        chain = chain_table(identified.regressor.model)
        parts = _identified(identified)
    else:
        if rigid is None or friction_rows is None:
            raise ValueError("a declared point model needs its rigid body and friction rows")
        chain = chain_table(rigid.model, rigid.armature_kgm2)
        params = rigid.parameters()
        parts = {
            "coriolis": False,  # a declared model's friction_nm is eq. (15) alone
            "w_rigid": _floats(np.tile(params, (len(desc.joints), 1))),
            "w_payload": None,
            "envelope": None,
            "friction": [{"kind": "eq15", "row": _floats(row)} for row in friction_rows],
            "effects": [],
        }
    return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "chain": chain,
            "cylinders": _cylinders(desc), **parts}  # fmt: skip


def to_json(table: dict[str, Any]) -> str:
    """The table as the extension reads it (no NaN: refused by name if one slipped in)."""
    return json.dumps(table, allow_nan=False)
