"""The virtual CiA 402 drives' commissioning parameters and monitoring limits
(:mod:`sim_bridge.cia402_drives`).

Units (the drive's own, per its parameters): position increments = q_rad · (0x608F:1 /
0x608F:2) · (0x6091:1 / 0x6091:2) / 2π on the joint side; velocity increments/s; quick stop
deceleration 0x6085 increments/s²; current 0x6078 and torque 0x6077 per mille of the rated
current 0x6075 [mA] and torque 0x6076 [mN·m, motor side]. With no torque sensor the drive's
torque is its current times its torque constant 0x6076 / 0x6075, so 0x6077 reads as 0x6078.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

from sim_bridge.cia402_profile import (
    GEAR_RATIO,
    MOTOR_RATED_CURRENT,
    MOTOR_RATED_TORQUE,
    POSITION_ENCODER_RESOLUTION,
)


@dataclass(frozen=True)
class AxisParameters:
    """One drive's commissioning parameters, as its objects report them."""

    encoder_increments: int  #: 0x608F:1, per ``encoder_motor_revolutions``
    encoder_motor_revolutions: int  #: 0x608F:2
    gear_motor_revolutions: int  #: 0x6091:1, per ``gear_shaft_revolutions``
    gear_shaft_revolutions: int  #: 0x6091:2
    rated_current_ma: int  #: 0x6075 [mA]
    rated_torque_mnm: int  #: 0x6076 [mN·m], motor side

    @classmethod
    def for_joint(
        cls,
        gear_ratio: float,
        rated_current_a: float,
        torque_constant_nm_per_a: float,
        encoder_bits: int,
    ) -> AxisParameters:
        """The parameters of a drive on a joint with gear ratio R [-], rated current [A], the
        datasheet's joint-side torque constant [N·m/A] and a 2^bits motor encoder."""
        ratio = Fraction(gear_ratio).limit_denominator(1000)
        return cls(
            encoder_increments=1 << encoder_bits,
            encoder_motor_revolutions=1,
            gear_motor_revolutions=ratio.numerator,
            gear_shaft_revolutions=ratio.denominator,
            rated_current_ma=round(rated_current_a * 1000.0),
            rated_torque_mnm=round(torque_constant_nm_per_a * rated_current_a / gear_ratio * 1e3),
        )

    @property
    def increments_per_rad(self) -> float:
        """Position increments per joint-side radian."""
        per_motor_rev = self.encoder_increments / self.encoder_motor_revolutions
        ratio = self.gear_motor_revolutions / self.gear_shaft_revolutions
        return per_motor_rev * ratio / (2.0 * math.pi)

    def increments(self, value_rad: float) -> int:
        """Joint-side radians as i32 increments (saturated)."""
        return max(-0x7FFFFFFF, min(0x7FFFFFFF, round(value_rad * self.increments_per_rad)))

    def per_mille(self, current_a: float) -> int:
        """A current [A] in per mille of the rated current, i16 (saturated)."""
        return max(-32767, min(32767, round(current_a * 1e6 / self.rated_current_ma)))

    def rad(self, increments: int) -> float:
        """Increments as joint-side radians."""
        return increments / self.increments_per_rad

    def objects(self) -> dict[tuple[int, int], int]:
        """The (index, sub-index) → value of these parameters in the object dictionary."""
        return {
            (POSITION_ENCODER_RESOLUTION, 1): self.encoder_increments,
            (POSITION_ENCODER_RESOLUTION, 2): self.encoder_motor_revolutions,
            (GEAR_RATIO, 1): self.gear_motor_revolutions,
            (GEAR_RATIO, 2): self.gear_shaft_revolutions,
            (MOTOR_RATED_CURRENT, 0): self.rated_current_ma,
            (MOTOR_RATED_TORQUE, 0): self.rated_torque_mnm,
        }


@dataclass(frozen=True)
class DriveLimits:
    """The drive's monitoring, the same for every axis."""

    #: |q_ref(t) − q| beyond this → Fault 0x8611 [rad, joint side]; 0x6065 reports it
    max_following_error_rad: float = 0.05
    #: in Operation enabled, this many communication cycle periods (0x1006) without a SYNC →
    #: Fault 0x8700 (the sync watchdog; off while 0x1006 is 0)
    sync_timeout_cycles: int = 10
