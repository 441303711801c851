"""One robot description for both engines: the GR630ST painting robot as frozen dataclasses.

Kinematics come from Table I of the paper. The table's header says ``a_{i-1}, α_{i-1}``
(modified DH), but read literally in modified DH joints 5 and 6 fall on one axis (α_5 = 0 and
a_5 = 0 put z_6 on z_5), which is not a 6-DOF arm. We read each row as **standard DH**
``(a_i, α_i, d_i, θ_i = q_i + θ_offset_i)``::

    frame(i-1)_T_frame(i) = Rz(θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i)

which gives a sound UR-like arm: joint 1 vertical, joints 2-4 parallel and horizontal at the
zero pose, joints 5 and 6 a wrist with offsets d_5 and d_6. Joint ``i`` turns about ``z_{i-1}``.
At ``q = 0`` (the Table I zero pose) the upper arm stands upright and the forearm points forward,
almost horizontal.

The TOML file (``gr630st.toml`` next to this module) writes lengths in mm and angles in degrees
as Table I does; :func:`load_description` converts to m and rad. Every number not from the
paper is marked "assumption" in the file: inertial parameters, gear ratios, rotor inertias,
current limits, the tool offset, the J3 piston diameter and the cylinder sign convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gateway.config import from_mapping, load_toml, require
from gateway.errors import ConfigError

DEFAULT_DESCRIPTION_PATH = Path(__file__).with_name("gr630st.toml")
CYLINDER_KINDS = ("j2_crank", "j3_lever")
BAR_TO_PA = 1.0e5  #: 1 bar = 1e5 Pa

_INERTIA_TOL_KGM2 = 1e-12
_INERTIA_FIELDS = "ixx_kgm2..izz_kgm2"


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


@dataclass(frozen=True)
class JointSpec:
    """One revolute joint: its standard-DH row (Table I), limits and drive.

    ``theta_offset_rad`` is added to the joint angle: ``θ_i = q_i + theta_offset_rad``.
    ``drive_gain_nm_per_a`` is K of eq. (1) (joint-side torque per motor ampere);
    ``rotor_inertia_kgm2`` is on the motor side, so its reflected (armature) inertia is
    ``rotor_inertia_kgm2 · gear_ratio²``.
    """

    name: str
    a_m: float
    alpha_rad: float
    d_m: float
    theta_offset_rad: float
    lower_rad: float
    upper_rad: float
    gear_ratio: float
    drive_gain_nm_per_a: float
    rotor_inertia_kgm2: float
    max_current_a: float

    def __post_init__(self) -> None:
        require(bool(self.name), "name", "must not be empty")
        for field in ("a_m", "alpha_rad", "d_m", "theta_offset_rad", "lower_rad", "upper_rad"):
            require(_finite(getattr(self, field)), field, f"{getattr(self, field)!r} not finite")
        require(
            self.lower_rad < self.upper_rad,
            "lower_rad",
            f"{self.lower_rad!r} must be below upper_rad {self.upper_rad!r}",
        )
        require(self.gear_ratio > 0, "gear_ratio", f"{self.gear_ratio!r} must be > 0")
        require(
            self.drive_gain_nm_per_a > 0,
            "drive_gain_nm_per_a",
            f"{self.drive_gain_nm_per_a!r} must be > 0",
        )
        require(
            self.rotor_inertia_kgm2 >= 0,
            "rotor_inertia_kgm2",
            f"{self.rotor_inertia_kgm2!r} must be >= 0",
        )
        require(self.max_current_a > 0, "max_current_a", f"{self.max_current_a!r} must be > 0")

    @property
    def armature_kgm2(self) -> float:
        """Rotor inertia reflected to the joint side [kg·m²]: ``J_rotor · R²``."""
        return self.rotor_inertia_kgm2 * self.gear_ratio**2

    @property
    def max_torque_nm(self) -> float:
        """Joint-side torque at the current limit [N·m]: ``K · i_max``."""
        return self.drive_gain_nm_per_a * self.max_current_a


@dataclass(frozen=True)
class LinkInertial:
    """Mass, centre of mass and inertia of link i, all in link i's DH frame (frame i).

    ``com_m`` is the centre of mass [m] in frame i; the inertia tensor [kg·m²] is taken about
    the centre of mass with axes parallel to frame i.
    """

    mass_kg: float
    com_m: tuple[float, float, float]
    ixx_kgm2: float
    ixy_kgm2: float
    ixz_kgm2: float
    iyy_kgm2: float
    iyz_kgm2: float
    izz_kgm2: float

    def __post_init__(self) -> None:
        require(
            _finite(self.mass_kg) and self.mass_kg > 0,
            "mass_kg",
            f"{self.mass_kg!r} must be > 0",
        )
        require(len(self.com_m) == 3 and _finite(*self.com_m), "com_m", "needs 3 finite values")
        inertia = self.inertia_kgm2
        require(bool(np.all(np.isfinite(inertia))), _INERTIA_FIELDS, "values must be finite")
        moments = np.linalg.eigvalsh(inertia)
        require(
            moments[0] > _INERTIA_TOL_KGM2,
            _INERTIA_FIELDS,
            f"inertia tensor not positive definite (principal moments {moments.tolist()})",
        )
        require(
            moments[2] <= moments[0] + moments[1] + _INERTIA_TOL_KGM2,
            _INERTIA_FIELDS,
            f"principal moments {moments.tolist()} break the triangle inequality",
        )

    @property
    def inertia_kgm2(self) -> np.ndarray:
        """3x3 inertia tensor about the COM, frame-i axes [kg·m²]."""
        return np.array(
            [
                [self.ixx_kgm2, self.ixy_kgm2, self.ixz_kgm2],
                [self.ixy_kgm2, self.iyy_kgm2, self.iyz_kgm2],
                [self.ixz_kgm2, self.iyz_kgm2, self.izz_kgm2],
            ]
        )


@dataclass(frozen=True)
class ToolSpec:
    """The tool point (spray-gun tip) in the link-6 DH frame [m]; its axes are frame 6's."""

    position_in_link6_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        require(
            len(self.position_in_link6_m) == 3 and _finite(*self.position_in_link6_m),
            "position_in_link6_m",
            "needs 3 finite values",
        )


@dataclass(frozen=True)
class CylinderSpec:
    """A pneumatic assist cylinder on one joint, eqs. (3)-(12) of the paper.

    ``kind`` selects the geometry: ``"j2_crank"`` is eq. (10) (needs ``ab_m`` = |A2B2| and
    ``ac_m`` = |A2C2|), ``"j3_lever"`` is eq. (12) (needs ``ab_m`` = |A3B3|).
    ``joint_index`` is 0-based (J2 is 1). The equation's angle θ is the joint angle q itself
    (our convention, see the module docstring of :mod:`control.model.cylinders`), and
    ``torque_sign`` (+1 or -1) maps the equation's positive torque onto the joint's positive
    direction, chosen so that the cylinder opposes gravity.
    """

    joint_index: int
    kind: str
    piston_diameter_m: float
    ab_m: float
    torque_sign: float
    nominal_pressure_bar: float
    ac_m: float | None = None

    def __post_init__(self) -> None:
        require(self.joint_index >= 0, "joint_index", f"{self.joint_index!r} must be >= 0")
        require(
            self.kind in CYLINDER_KINDS,
            "kind",
            f"{self.kind!r} is not one of {list(CYLINDER_KINDS)}",
        )
        require(
            _finite(self.piston_diameter_m) and self.piston_diameter_m > 0,
            "piston_diameter_m",
            f"{self.piston_diameter_m!r} must be > 0",
        )
        require(_finite(self.ab_m) and self.ab_m > 0, "ab_m", f"{self.ab_m!r} must be > 0")
        require(
            self.torque_sign in (1.0, -1.0),
            "torque_sign",
            f"{self.torque_sign!r} must be +1 or -1",
        )
        require(
            _finite(self.nominal_pressure_bar) and self.nominal_pressure_bar >= 0,
            "nominal_pressure_bar",
            f"{self.nominal_pressure_bar!r} must be >= 0",
        )
        if self.kind == "j2_crank":
            require(
                self.ac_m is not None and _finite(self.ac_m) and self.ac_m > 0,
                "ac_m",
                f"{self.ac_m!r}: a j2_crank cylinder needs |A2C2| > 0",
            )
        else:
            require(self.ac_m is None, "ac_m", "only a j2_crank cylinder takes ac_m")

    @property
    def piston_area_m2(self) -> float:
        """Piston area S = π d² / 4 [m²] (eq. 9)."""
        return math.pi * self.piston_diameter_m**2 / 4.0


@dataclass(frozen=True)
class RobotDescription:
    """The whole arm: joints and links in chain order, tool, cylinders and gravity [m/s², world]."""

    name: str
    joints: tuple[JointSpec, ...]
    links: tuple[LinkInertial, ...]
    tool: ToolSpec
    cylinders: tuple[CylinderSpec, ...]
    gravity_m_s2: tuple[float, float, float]

    def __post_init__(self) -> None:
        require(len(self.joints) > 0, "joints", "at least one joint is needed")
        require(
            len(self.links) == len(self.joints),
            "links",
            f"{len(self.links)} links for {len(self.joints)} joints",
        )
        names = [j.name for j in self.joints]
        require(len(set(names)) == len(names), "joints", f"duplicate joint names {names}")
        seen: set[int] = set()
        for k, cyl in enumerate(self.cylinders):
            require(
                cyl.joint_index < len(self.joints),
                f"cylinders[{k}].joint_index",
                f"{cyl.joint_index} is not a joint index (0..{len(self.joints) - 1})",
            )
            require(
                cyl.joint_index not in seen,
                f"cylinders[{k}].joint_index",
                f"joint {cyl.joint_index} already has a cylinder",
            )
            seen.add(cyl.joint_index)
        require(
            len(self.gravity_m_s2) == 3 and _finite(*self.gravity_m_s2),
            "gravity_m_s2",
            "needs 3 finite values",
        )

    @property
    def n_dof(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def lower_rad(self) -> np.ndarray:
        return np.array([j.lower_rad for j in self.joints])

    @property
    def upper_rad(self) -> np.ndarray:
        return np.array([j.upper_rad for j in self.joints])

    @property
    def gear_ratios(self) -> np.ndarray:
        return np.array([j.gear_ratio for j in self.joints])

    @property
    def drive_gains_nm_per_a(self) -> np.ndarray:
        """K of eq. (1), per joint [N·m/A]."""
        return np.array([j.drive_gain_nm_per_a for j in self.joints])

    @property
    def max_current_a(self) -> np.ndarray:
        return np.array([j.max_current_a for j in self.joints])

    @property
    def armature_kgm2(self) -> np.ndarray:
        """Reflected rotor inertia per joint [kg·m²]: ``J_rotor · R²``."""
        return np.array([j.armature_kgm2 for j in self.joints])

    @property
    def nominal_pressures_bar(self) -> np.ndarray:
        """Nominal pressure per cylinder, in ``cylinders`` order [bar]."""
        return np.array([c.nominal_pressure_bar for c in self.cylinders])


# --- TOML schema: Table I units (mm, deg) for the joints; SI everywhere else ---------------


@dataclass(frozen=True)
class _JointToml:
    name: str
    a_mm: float
    alpha_deg: float
    d_mm: float
    theta_offset_deg: float
    lower_deg: float
    upper_deg: float
    gear_ratio: float
    drive_gain_nm_per_a: float
    rotor_inertia_kgm2: float
    max_current_a: float

    def __post_init__(self) -> None:
        require(
            self.lower_deg < self.upper_deg,
            "lower_deg",
            f"{self.lower_deg!r} must be below upper_deg {self.upper_deg!r}",
        )

    def to_spec(self) -> JointSpec:
        return JointSpec(
            name=self.name,
            a_m=self.a_mm * 1e-3,
            alpha_rad=math.radians(self.alpha_deg),
            d_m=self.d_mm * 1e-3,
            theta_offset_rad=math.radians(self.theta_offset_deg),
            lower_rad=math.radians(self.lower_deg),
            upper_rad=math.radians(self.upper_deg),
            gear_ratio=self.gear_ratio,
            drive_gain_nm_per_a=self.drive_gain_nm_per_a,
            rotor_inertia_kgm2=self.rotor_inertia_kgm2,
            max_current_a=self.max_current_a,
        )


def _prefixed(where: str, build: Any, sep: str = ".") -> Any:
    """Run ``build()``; give any ConfigError the ``where`` prefix (once)."""
    try:
        return build()
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(where) else f"{where}{sep}{msg}") from None


def _table_list(raw: dict[str, Any], key: str, where: str) -> list[dict[str, Any]]:
    value = raw.get(key)
    require(isinstance(value, list), f"{where} {key}", "expected an array of tables [[...]]")
    return value


def description_from_mapping(raw: dict[str, Any], where: str = "robot") -> RobotDescription:
    """Build a :class:`RobotDescription` from a parsed TOML mapping (see ``gr630st.toml``)."""
    allowed = {"name", "gravity_m_s2", "joints", "links", "tool", "cylinders"}
    unknown = sorted(set(raw) - allowed)
    require(not unknown, where, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    for key in ("name", "gravity_m_s2", "joints", "links", "tool"):
        require(key in raw, where, f"missing required key {key!r}")
    joints = tuple(
        _prefixed(
            f"{where} joints[{i}]",
            lambda t=t, i=i: from_mapping(_JointToml, t, f"{where} joints[{i}]").to_spec(),
        )
        for i, t in enumerate(_table_list(raw, "joints", where))
    )
    links = tuple(
        _prefixed(
            f"{where} links[{i}]",
            lambda t=t, i=i: from_mapping(LinkInertial, t, f"{where} links[{i}]"),
        )
        for i, t in enumerate(_table_list(raw, "links", where))
    )
    cylinders = tuple(
        _prefixed(
            f"{where} cylinders[{i}]",
            lambda t=t, i=i: from_mapping(CylinderSpec, t, f"{where} cylinders[{i}]"),
        )
        for i, t in enumerate(raw.get("cylinders", []))
    )
    tool = _prefixed(f"{where} tool", lambda: from_mapping(ToolSpec, raw["tool"], f"{where} tool"))

    def build() -> RobotDescription:
        name = raw["name"]
        require(isinstance(name, str) and bool(name), "name", f"{name!r} must be a string")
        gravity = raw["gravity_m_s2"]
        require(
            isinstance(gravity, list)
            and len(gravity) == 3
            and all(isinstance(g, int | float) and not isinstance(g, bool) for g in gravity),
            "gravity_m_s2",
            f"{gravity!r} must be 3 numbers",
        )
        return RobotDescription(
            name=name,
            joints=joints,
            links=links,
            tool=tool,
            cylinders=cylinders,
            gravity_m_s2=(float(gravity[0]), float(gravity[1]), float(gravity[2])),
        )

    return _prefixed(where, build, sep=" ")


def load_description(path: str | Path | None = None) -> RobotDescription:
    """Load and validate a robot description TOML; default: the packaged ``gr630st.toml``.

    A bad file raises :class:`ConfigError` naming the file, the entry and the field, e.g.
    ``gr630st.toml links[2].mass_kg: -1.0 must be > 0``.
    """
    p = Path(path) if path is not None else DEFAULT_DESCRIPTION_PATH
    return description_from_mapping(load_toml(p), where=str(p))
