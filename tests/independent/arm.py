"""A mid-size 6-axis industrial arm (KUKA/ABB-like), written as URDF and as MJCF by this module.

Kinematics (all joint frames parallel to their parent's at q = 0, z up, lengths [m]):

- A1 about z, 0.45 above the base; A2 about y, offset a1 = 0.26 forward and 0.225 up from A1;
- A3 about y, 0.68 above A2 (A2 and A3 parallel; upper arm vertical at q2 = 0, forearm
  horizontal at q3 = 0);
- A4 about x (forearm roll), 0.20 forward and 0.035 up from A3; A5 about y and A6 about x, both
  at the wrist centre 0.47 further along A4: a spherical wrist (A4, A5, A6 meet in one point);
- a flange 0.115 beyond the wrist centre along A6 (fixed ``flange`` link, massless).

Reach to the wrist centre 1.61 m. Each link's inertia is that of a homogeneous box of the given
size and mass, turned by ``box_rpy`` so the tensor is full (non-zero products of inertia), about
the link's centre of mass: positive definite and satisfying the triangle inequality by
construction. Units: m, kg, kg·m², rad, rad/s, N·m.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation matrix R = Rz(yaw) Ry(pitch) Rx(roll) (the URDF convention), shape (3, 3)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def box_inertia(mass: float, size: tuple[float, float, float], rpy: tuple[float, float, float]):
    """Inertia [kg·m²] about the centre of a homogeneous box of ``mass`` [kg] and edge lengths
    ``size`` [m], its edges turned by ``rpy`` [rad] from the frame's axes; shape (3, 3)."""
    a, b, c = size
    principal = mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    r = rpy_matrix(*rpy)
    inertia = r @ principal @ r.T
    return 0.5 * (inertia + inertia.T)


@dataclass(frozen=True)
class Body:
    """Mass [kg], centre of mass ``com`` [m] in the body frame, and the box (size [m],
    orientation [rad]) whose inertia the body has about its centre of mass."""

    mass: float
    com: tuple[float, float, float]
    box: tuple[float, float, float]
    box_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def inertia(self) -> np.ndarray:
        """Inertia tensor [kg·m²] about the centre of mass, body-frame axes, shape (3, 3)."""
        return box_inertia(self.mass, self.box, self.box_rpy)


@dataclass(frozen=True)
class Joint:
    """A revolute joint: frame ``origin`` [m] in the parent link's frame (no rotation), unit
    ``axis``, position limits [rad], velocity limit [rad/s], effort limit [N·m], gear ratio
    (motor turns per joint turn) and the child link's name and body."""

    name: str
    child: str
    origin: tuple[float, float, float]
    axis: tuple[float, float, float]
    lower: float
    upper: float
    velocity: float
    effort: float
    gear_ratio: float
    body: Body

    @property
    def centre(self) -> float:
        """Middle of the range [rad]."""
        return 0.5 * (self.lower + self.upper)

    @property
    def half_range(self) -> float:
        """Half the range [rad]."""
        return 0.5 * (self.upper - self.lower)


@dataclass(frozen=True)
class ArmSpec:
    """A serial arm: base link, six joints in chain order, flange offset [m] from the last link."""

    name: str
    base: Body
    joints: tuple[Joint, ...]
    flange_offset: tuple[float, float, float]
    encoder_counts_per_motor_rev: int = 2**20
    base_name: str = "base_link"
    flange_name: str = "flange"

    @property
    def n(self) -> int:
        return len(self.joints)

    @property
    def lower(self) -> np.ndarray:
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        return np.array([j.upper for j in self.joints])

    @property
    def centre(self) -> np.ndarray:
        return np.array([j.centre for j in self.joints])

    @property
    def half_range(self) -> np.ndarray:
        return np.array([j.half_range for j in self.joints])

    @property
    def velocity_limit(self) -> np.ndarray:
        return np.array([j.velocity for j in self.joints])

    @property
    def gear_ratios(self) -> np.ndarray:
        return np.array([j.gear_ratio for j in self.joints])

    @property
    def encoder_step(self) -> np.ndarray:
        """Joint-side position resolution [rad] per joint: one encoder count through the gear."""
        return 2.0 * np.pi / (self.encoder_counts_per_motor_rev * self.gear_ratios)


@dataclass(frozen=True)
class Payload:
    """A rigid payload fixed to the flange: ``body.com`` is in the flange frame [m]."""

    body: Body
    name: str = "payload"

    def in_last_link(self, arm: ArmSpec) -> dict[str, object]:
        """Mass [kg], centre of mass [m] in the last link's frame and inertia [kg·m²] about the
        centre of mass, as a JSON-able dict."""
        com = np.add(arm.flange_offset, self.body.com)
        return {
            "mass_kg": self.body.mass,
            "com_m": [float(v) for v in com],
            "com_from_flange_m": list(self.body.com),
            "distance_from_flange_m": float(np.linalg.norm(self.body.com)),
            "inertia_about_com_kgm2": self.body.inertia.tolist(),
        }


def _b(mass, com, box, rpy) -> Body:
    return Body(float(mass), tuple(com), tuple(box), tuple(rpy))


#: The arm of this package: ~1.6 m reach, offset shoulder, spherical wrist. Per joint: name,
#: child link, origin [m], axis, limits [rad], velocity [rad/s], effort [N·m], gear ratio, and
#: the link body (mass [kg], COM [m], box size [m], box orientation [rad]).
# fmt: off
ARM = ArmSpec(
    name="indep_arm16",
    base=_b(150.0, (0.0, 0.0, 0.2), (0.6, 0.6, 0.4), (0.0, 0.0, 0.0)),
    joints=(
        Joint("a1", "link1", (0.0, 0.0, 0.45), (0, 0, 1), -2.967, 2.967, 2.7, 2500, 160.0,
              _b(130.0, (0.08, -0.03, 0.12), (0.60, 0.50, 0.45), (0.05, -0.10, 0.25))),
        Joint("a2", "link2", (0.26, 0.0, 0.225), (0, 1, 0), -1.40, 2.20, 2.7, 4000, 160.0,
              _b(65.0, (0.03, 0.08, 0.30), (0.20, 0.24, 0.85), (0.04, 0.06, 0.10))),
        Joint("a3", "link3", (0.0, 0.0, 0.68), (0, 1, 0), -2.20, 2.60, 2.9, 2000, 120.0,
              _b(45.0, (0.07, -0.02, 0.05), (0.42, 0.28, 0.26), (0.12, -0.04, -0.08))),
        Joint("a4", "link4", (0.20, 0.0, 0.035), (1, 0, 0), -3.20, 3.20, 5.9, 400, 90.0,
              _b(26.0, (0.24, 0.012, -0.015), (0.52, 0.15, 0.15), (0.03, 0.02, 0.05))),
        Joint("a5", "link5", (0.47, 0.0, 0.0), (0, 1, 0), -2.09, 2.09, 5.9, 400, 90.0,
              _b(17.0, (0.04, -0.01, 0.02), (0.16, 0.17, 0.14), (0.20, 0.10, 0.15))),
        Joint("a6", "link6", (0.0, 0.0, 0.0), (1, 0, 0), -6.10, 6.10, 8.0, 200, 60.0,
              _b(15.0, (0.075, 0.012, -0.009), (0.10, 0.13, 0.12), (0.10, -0.05, 0.30))),
    ),
    flange_offset=(0.115, 0.0, 0.0),
)
# fmt: on

#: 6 kg at 0.1 m from the flange, off the A6 axis (so A6 feels it too).
PAYLOAD = Payload(_b(6.0, (0.08, 0.06, 0.0), (0.12, 0.10, 0.08), (0.0, 0.0, 0.3)))


def _f(v: float) -> str:
    return repr(float(v))


def _vec(v) -> str:
    return " ".join(_f(x) for x in v)


def _urdf_inertial(body: Body, indent: str) -> list[str]:
    i = body.inertia
    return [
        f"{indent}<inertial>",
        f'{indent}  <origin xyz="{_vec(body.com)}" rpy="0 0 0"/>',
        f'{indent}  <mass value="{_f(body.mass)}"/>',
        f'{indent}  <inertia ixx="{_f(i[0, 0])}" ixy="{_f(i[0, 1])}" ixz="{_f(i[0, 2])}" '
        f'iyy="{_f(i[1, 1])}" iyz="{_f(i[1, 2])}" izz="{_f(i[2, 2])}"/>',
        f"{indent}</inertial>",
    ]


def urdf(arm: ArmSpec = ARM, payload: Payload | None = None) -> str:
    """The arm as a URDF string (revolute joints with limits, full inertia tensors); with
    ``payload``, a fixed ``payload`` link on the flange carries it."""
    lines = ['<?xml version="1.0"?>', f'<robot name="{arm.name}">']
    lines += [f'  <link name="{arm.base_name}">', *_urdf_inertial(arm.base, "    "), "  </link>"]
    parent = arm.base_name
    for j in arm.joints:
        lines += [
            f'  <joint name="{j.name}" type="revolute">',
            f'    <parent link="{parent}"/>',
            f'    <child link="{j.child}"/>',
            f'    <origin xyz="{_vec(j.origin)}" rpy="0 0 0"/>',
            f'    <axis xyz="{_vec(j.axis)}"/>',
            f'    <limit lower="{_f(j.lower)}" upper="{_f(j.upper)}" effort="{_f(j.effort)}" '
            f'velocity="{_f(j.velocity)}"/>',
            "  </joint>",
            f'  <link name="{j.child}">',
            *_urdf_inertial(j.body, "    "),
            "  </link>",
        ]
        parent = j.child
    lines += [
        f'  <joint name="{arm.flange_name}_joint" type="fixed">',
        f'    <parent link="{parent}"/>',
        f'    <child link="{arm.flange_name}"/>',
        f'    <origin xyz="{_vec(arm.flange_offset)}" rpy="0 0 0"/>',
        "  </joint>",
        f'  <link name="{arm.flange_name}"/>',
    ]
    if payload is not None:
        lines += [
            f'  <joint name="{payload.name}_joint" type="fixed">',
            f'    <parent link="{arm.flange_name}"/>',
            f'    <child link="{payload.name}"/>',
            '    <origin xyz="0 0 0" rpy="0 0 0"/>',
            "  </joint>",
            f'  <link name="{payload.name}">',
            *_urdf_inertial(payload.body, "    "),
            "  </link>",
        ]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def _mjcf_inertial(body: Body) -> str:
    i = body.inertia
    full = (i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])
    return f'<inertial pos="{_vec(body.com)}" mass="{_f(body.mass)}" fullinertia="{_vec(full)}"/>'


def mjcf(arm: ArmSpec = ARM, payload: Payload | None = None) -> str:
    """The same arm as an MJCF string for MuJoCo (hinge joints, no armature, damping or joint
    friction, no limits: mj_inverse would add their constraint forces; gravity -9.81 m/s²
    along z), built from the spec, not from the URDF."""
    lines = [
        f'<mujoco model="{arm.name}">',
        '  <option gravity="0 0 -9.81" timestep="0.004"/>',
        "  <worldbody>",
    ]
    indent = "    "
    for j in arm.joints:
        lines += [
            f'{indent}<body name="{j.child}" pos="{_vec(j.origin)}">',
            f'{indent}  <joint name="{j.name}" type="hinge" axis="{_vec(j.axis)}"/>',
            f"{indent}  {_mjcf_inertial(j.body)}",
        ]
        indent += "  "
    if payload is not None:
        lines += [
            f'{indent}<body name="{payload.name}" pos="{_vec(arm.flange_offset)}">',
            f"{indent}  {_mjcf_inertial(payload.body)}",
            f"{indent}</body>",
        ]
    for _ in arm.joints:
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines += ["  </worldbody>", "</mujoco>"]
    return "\n".join(lines) + "\n"


@dataclass
class _Cache:
    models: dict[bool, object] = field(default_factory=dict)


_CACHE = _Cache()


def pin_model(payload: bool = False):
    """Pinocchio model of :data:`ARM` (with :data:`PAYLOAD` when ``payload``), built from
    :func:`urdf` and cached; gravity (0, 0, -9.81) m/s²."""
    import pinocchio as pin

    if payload not in _CACHE.models:
        _CACHE.models[payload] = pin.buildModelFromXML(urdf(ARM, PAYLOAD if payload else None))
    return _CACHE.models[payload]
