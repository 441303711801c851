"""The declared dynamic model the control process compensates: gravity, friction, cylinders.

File format (TOML), versioned::

    format = "leadthrough-model"
    version = 1
    robot = "gr630st"            # packaged description, or a path to a description TOML
    [[friction]]                 # one table per joint, eq. (15) (control/model/friction.py)
    tau_s_nm = ...

The rigid-body part is the description's inertial parameters. A ``.json`` path instead loads
a model identified by `leadthrough identify` / `analyze` (format version 2, base parameters,
fitted friction and accepted effect terms): see :class:`IdentifiedControlModel`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from control import _rt
from control.model.cylinders import cylinder_torque_nm
from control.model.dynamics import RigidBodyModel
from control.model.friction import Eq15Friction, FrictionParams
from control.rt_tables import point_model_table, to_json
from gateway.config import ConfigError, from_mapping, load_toml, require, resolve_path
from gateway.robot.description import RobotDescription, load_description

if TYPE_CHECKING:
    from control.identification.model import IdentifiedModel

MODEL_FORMAT = "leadthrough-model"
MODEL_VERSION = 1


@dataclass(frozen=True)
class FrictionEntry:
    tau_s_nm: float
    tau_c_nm: float
    tau_v1_nm_s_per_rad: float
    q_e_rad_s: float
    tau_v2_nm_s2_per_rad2: float = 0.0
    fourier_nm: tuple[float, float, float, float, float, float] = (0.0,) * 6

    def __post_init__(self) -> None:
        require(self.q_e_rad_s > 0, "[[friction]].q_e_rad_s", "must be > 0")


class DeclaredModel:
    def __init__(self, desc: RobotDescription, friction: list[FrictionParams]) -> None:
        self.desc = desc
        self.n = len(desc.joints)
        #: the model's held-out RMS error per joint [N·m], when it was measured (identified)
        self.heldout_rms_nm: tuple[float, ...] | None = None
        self.torque_gain, self.torque_offset_nm = np.ones(self.n), np.zeros(self.n)
        self.rigid = RigidBodyModel.from_description(desc)
        self.friction = Eq15Friction(friction)
        #: the compiled per-cycle form (control/rt/src/point_model.rs)
        self.point = _rt.PointModel(
            to_json(point_model_table(desc, rigid=self.rigid, friction_rows=self.friction.rows))
        )

    @classmethod
    def load(cls, path: str | Path) -> DeclaredModel:
        if Path(path).suffix == ".json":
            return IdentifiedControlModel(Path(path))
        raw = load_toml(path)
        where = str(path)
        if raw.get("format") != MODEL_FORMAT or raw.get("version") != MODEL_VERSION:
            raise ConfigError(
                f"{where}: not a {MODEL_FORMAT} v{MODEL_VERSION} file "
                f"(format={raw.get('format')!r}, version={raw.get('version')!r})"
            )
        robot = raw.get("robot", "gr630st")
        desc = load_description(None if robot == "gr630st" else resolve_path(path, robot))
        entries = raw.get("friction", [])
        require(
            isinstance(entries, list) and len(entries) == len(desc.joints),
            f"{where} [[friction]]",
            f"needs one table per joint ({len(desc.joints)})",
        )
        params = []
        for i, (e, js) in enumerate(zip(entries, desc.joints, strict=True)):
            fe = from_mapping(FrictionEntry, e, f"{where} [[friction]][{i}]")
            params.append(FrictionParams.from_table(fe, js.gear_ratio))
        return cls(desc, params)

    def torque_per_amp_nm(self) -> tuple[np.ndarray, np.ndarray]:
        """``(k [N·m/A], b [N·m])`` per joint: the joint torque of motor currents ``i`` is
        ``k i - b``. The datasheet's K of eq. (1) over the torque channel's gain the
        identification measured (:attr:`torque_gain`, ``control/identification/chain.py``),
        and its reading at zero torque over that gain (:attr:`torque_offset_nm`): the model
        predicts the physical torque, and every comparison of it with a drive's reading
        (the law's hand torque, the static-load check, the adaptation's residual) goes
        through here. A declared model measured neither: K and 0."""
        k = self.desc.drive_gains_nm_per_a / self.torque_gain
        return k, self.torque_offset_nm / self.torque_gain

    def motor_torque_nm(self, current_a: np.ndarray) -> np.ndarray:
        """The joint torque motor currents ``current_a`` [A] report [N·m]
        (:meth:`torque_per_amp_nm`)."""
        k, b = self.torque_per_amp_nm()
        return k * np.asarray(current_a, dtype=float) - b

    def gravity_nm(self, q_rad: np.ndarray) -> np.ndarray:
        return self.rigid.gravity_nm(q_rad)

    def friction_nm(self, q_rad: np.ndarray, dq_rad_s: np.ndarray) -> np.ndarray:
        return self.friction(q_rad, dq_rad_s)

    def cylinder_nm(self, q_rad: np.ndarray, p_bar: np.ndarray) -> np.ndarray:
        return np.asarray(cylinder_torque_nm(q_rad, p_bar, self.desc))

    def cycle_torques_nm(
        self, q_rad: np.ndarray, dq_rad_s: Sequence[float], p_bar: Sequence[float]
    ) -> tuple[list[float], list[float]]:
        """``(gravity_nm(q) - cylinder_nm(q, p), friction_nm(q, dq))`` of one sample as plain
        floats [N·m], from the compiled model (control/rt/src/point_model.rs), equal to those
        three methods to rounding.

        ``q_rad`` is a float64 array of shape (n,); ``dq_rad_s`` [rad/s] and ``p_bar`` [bar]
        are sequences of floats. Raises ``ArithmeticError`` naming the joint where the torque
        is not finite, ``ValueError`` on a wrong length.
        """
        return self.point.cycle_torques_nm(q_rad.tolist(), list(dq_rad_s), list(p_bar))


class IdentifiedControlModel(DeclaredModel):
    """An identified model (control/identification/model.py) behind the DeclaredModel methods.

    ``gravity_nm`` is everything that acts at rest (rigid-body gravity plus position effects
    such as a spring or a ripple); ``friction_nm`` is everything that grows with velocity
    (friction, velocity effects, and the small Coriolis/centrifugal torque). The cylinders
    stay on the description's eqs. (10), (12) (they were taken out before fitting), with the
    piston diameters the identification measured (control/identification/cylinders.py):
    :attr:`desc` is the description with those.
    """

    def __init__(self, path: Path | IdentifiedModel, desc: RobotDescription | None = None) -> None:
        """From a ``model.json`` path, or an :class:`IdentifiedModel` already in memory (the
        model adapted in replay, control/model_adaptation.py)."""
        from control.identification.model import IdentifiedModel

        loaded = isinstance(path, IdentifiedModel)
        where = "model" if loaded else str(path)
        self.identified = path if loaded else IdentifiedModel.load(path)
        try:
            self.desc = self.identified.with_measured_cylinders(desc or load_description())
        except ValueError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        except (KeyError, TypeError, AttributeError) as exc:
            raise ConfigError(f"{where}: analysis.cylinders malformed: {exc!r}") from None
        self.n = len(self.desc.joints)
        if self.identified.n != self.n:
            raise ConfigError(f"{where}: model has {self.identified.n} joints, robot {self.n}")
        self._zeros = np.zeros(self.n)
        #: the compiled per-cycle form (control/rt/src/point_model.rs); an effect it cannot
        #: evaluate is refused here, by name
        try:
            self.point = _rt.PointModel(to_json(point_model_table(self.desc, self.identified)))
        except ValueError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        self.torque_gain, self.torque_offset_nm = self.identified.chain_arrays()
        rms = self.identified.metadata.get("heldout_rms_nm")
        self.heldout_rms_nm = None if rms is None else tuple(float(v) for v in rms)
        if rms is not None and (len(rms) != self.n or not all(v >= 0 for v in rms)):
            raise ConfigError(f"{where}: heldout_rms_nm {rms} is not {self.n} values >= 0")

    def gravity_nm(self, q_rad: np.ndarray) -> np.ndarray:
        return self.identified.torque_nm(q_rad, self._zeros, self._zeros)

    def friction_nm(self, q_rad: np.ndarray, dq_rad_s: np.ndarray) -> np.ndarray:
        im = self.identified
        return im.torque_nm(q_rad, dq_rad_s, self._zeros) - im.torque_nm(
            q_rad, self._zeros, self._zeros
        )
