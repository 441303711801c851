"""``[control]`` section of the cell config."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from gateway.config import require, require_count
from gateway.guide_modes import GUIDE_AXES, guide_problem

#: the lead-through laws (``[control].strategy``)
STRATEGIES = ("zero_moment", "paper", "admittance")
#: how the admittance keeps the load a resting joint's friction carries from reading as a hand
ADMITTANCE_STICKS = ("zone", "anchor")


@dataclass(frozen=True)
class ControlConfig:
    #: |q_cmd − q| never exceeds this per joint [rad] (the controller faults beyond 0.05)
    max_offset_rad: tuple[float, ...]
    #: |dq_cmd| never exceeds this per joint [rad/s]
    max_velocity_rad_s: tuple[float, ...]
    #: added viscous damping, a margin against model error [N·m·s/rad]
    damping_nm_s_per_rad: tuple[float, ...]
    #: the dynamic model the control compensates (``model.json`` of `leadthrough identify`, or
    #: a TOML model, see control/declared_model.py), relative to the config; None: the cell
    #: is not commissioned yet: it identifies but refuses to teach
    model: Path | None = None
    #: ω = 1/(K K_p) per joint [rad/s per N·m] (eq. 21): written here, or read from the
    #: ``inner_loop`` estimate (:func:`control.cell_config.load_control_config`); empty: not
    #: commissioned, like ``model``
    omega_rad_s_per_nm: tuple[float, ...] = ()
    #: Υ_I = K_I/K_p per joint [1/s] (eq. 21), like ω
    upsilon_i_per_s: tuple[float, ...] = ()
    #: fraction of the model friction that is compensated (1 = all)
    friction_compensation: float = 1.0
    #: below this joint speed no friction is compensated, so the arm rests on its own friction
    #: instead of floating on velocity quantization noise; above it the compensation uses
    #: |dq| − deadband [rad/s]
    friction_deadband_rad_s: float = 5e-4
    #: above the deadband the compensated share of the model friction grows linearly to all of
    #: it over this many times the speed the friction's torque gives the joint's effective
    #: inertia in the loop's delay (control/rt/src/law/zero_moment.rs, ``friction_ramps``; 0: all
    #: at once)
    friction_ramp_factor: float = 2.0
    #: ... but not while the arm is guided: once a positioning joint (J1-J3) slid faster than
    #: its ramp, every joint's friction is compensated in full until all three have been
    #: slower than their ramps for this long [s] (control/rt/src/law/guided_friction.rs,
    #: ``GuidedFriction``; 0: the ramp always applies)
    friction_ramp_guided_s: float = 0.3
    #: the zero-moment law's inertia compensation: the drives also give this share of
    #: M(q) q̈ (the nominal rigid body's inertia, the measured acceleration low-passed at
    #: ``inertia_compensation_hz``), so the painter accelerates only the rest of the arm's
    #: mass (control/rt/src/law/zero_moment.rs, ``inertia_torque``); 0: none
    inertia_compensation: float = 0.6
    inertia_compensation_hz: float = 10.0
    #: the stiction dither (control/rt/src/law/zero_moment.rs): each joint at rest gets a sine
    #: of this share of the model's friction level at ``stiction_dither_hz`` [Hz], so the
    #: painter breaks a joint away from its static friction with the rest of it; 0: off
    stiction_dither: float = 0.0
    stiction_dither_hz: float = 4.0
    #: ... while the arm is guided (``friction_ramp_guided_s``'s switch) and this long after
    #: [s]: over the raster's 0.5 s corner stands, not on an arm left alone
    stiction_dither_hold_s: float = 2.0
    #: soft joint limits: a virtual spring pushes back this far inside the hard range [rad]
    soft_limit_margin_rad: float = 0.05
    wall_stiffness_nm_per_rad: float = 2000.0
    #: constrained guiding (control/rt/src/law/guide.rs): the mode teaching starts in when
    #: `leadthrough start` names none (gateway/guide_modes.py ``GUIDES``), the tool axis an
    #: "axis" guide runs along (x, y or z of the tool frame), and its fixtures' springs and
    #: dampers on the tool point's deviation [N/m, N·s/m] and the tool's rotation [N·m/rad,
    #: N·m·s/rad]. The rotation's stiffness sets what a push costs in orientation:
    #: |r × F| / K with r the tool point's lever about the wrist: the hand's 80 N at 0.25 m
    #: turns the gun 0.46° (teach-bench, seed 0, orientation-locked raster: 0.51° at most;
    #: 1000 N·m/rad gave 1.17°). The springs are the zero-moment law's; the admittance holds
    #: the guide on its reference exactly (control/rt/src/law/admittance/constraint.rs)
    guide: str = "free"
    guide_axis: str = "x"
    guide_stiffness_n_per_m: float = 3000.0
    guide_damping_n_s_per_m: float = 600.0
    guide_rot_stiffness_nm_per_rad: float = 2500.0
    guide_rot_damping_nm_s_per_rad: float = 40.0
    #: ``inner_loop.json`` of `leadthrough identify` (relative to the cell config): ω and Υ_I
    #: estimated on this cell's drives, in place of the two lists above
    inner_loop: Path | None = None
    #: eq. (28): γ, how fast ω̂ follows the measured motor current [1/s]; 0: ω fixed
    #: (control/rt/src/law/outer_loop.rs)
    omega_adaptation_per_s: float = 1.0
    #: per joint: ω̂ adapts only while |τ_d| exceeds this [N·m] (the current's noise would
    #: otherwise dominate); needed when the rate is > 0
    omega_adaptation_min_torque_nm: tuple[float, ...] = ()
    #: cycles between a command and the cycle the drive follows it in (the inner-loop
    #: estimate gives it)
    command_delay_cycles: int = 0
    #: teaching engages once the arm has rested in the hold for this many states (their mean
    #: calibrates ω̂, eq. 28), holding on meanwhile; 0: at once
    engage_rest_states: int = 32
    #: ... or after this many states of waiting for rest, whatever the arm does [states]
    engage_max_wait_states: int = 125
    #: the lead-through law: "zero_moment" (the paper's eq. 21 with the model's torque, ω̂
    #: adapted by the normalised eq. 28 above), "paper" (the same with the paper's eqs. 28
    #: and 30 adapting ω̂ and Υ̂_I together, control/rt/src/law/outer_loop.rs) or "admittance"
    #: (control/rt/src/law/admittance.rs: the hand's torque from the motor current, the arm on a
    #: reference of ``admittance_mass_fraction`` of its inertia and the damping above)
    strategy: str = "zero_moment"
    #: "paper": γ of eqs. (28) and (30) [1/s]
    paper_adaptation_per_s: float = 1.0
    #: "paper": Υ̂_I(0) [1/s] on every joint (the paper: 1.2); 0: the commissioned Υ_I
    paper_upsilon_i0_per_s: float = 0.0
    #: "paper": per joint, the dead zone's floor on |τ_m - τ_d| [N·m] (3 σ of the torque
    #: noise measured in the hold widens it); empty: the noise alone
    paper_dead_zone_nm: tuple[float, ...] = ()
    admittance_mass_fraction: float = 0.3
    #: the admittance's low-pass on the hand torque estimate [Hz]: measured on the virtual
    #: cell (teach-bench, seed 0), 8 Hz is stable, 15 Hz is not, nor 8 Hz with half the damping
    admittance_filter_hz: float = 5.0
    #: its dead zone per joint: this × the model's held-out RMS, at least ``rest_hold_nm``
    admittance_band_rms_factor: float = 1.0
    #: the damping a hand pushing beyond the dead zone feels per joint [N·m·s/rad]; empty:
    #: ``damping_nm_s_per_rad``. The painter pays it at the arm's joints for as long as the
    #: tool moves, and (A2) does not need it while a hand holds the tool (the hand's own
    #: damping, about 300 N·s/m, is some 400 N·m·s/rad at J1's reach); the wrist's keeps the
    #: gun's orientation, which a painter changes on purpose (sim_cell.toml gives the values)
    admittance_damping_nm_s_per_rad: tuple[float, ...] = ()
    #: the damping while no joint is pushed beyond its dead zone, × the admittance's damping
    admittance_rest_damping_factor: float = 10.0
    #: the admittance's engagement probe (control/rt/src/law/admittance.rs, EngageProbe): every
    #: joint moves out and back to either side at this cruise speed [rad/s] (at least; each joint's
    #: is sized to break its friction away) over ``admittance_probe_s`` [s], so the residual b is
    #: measured sliding both ways, free of the load stiction carries at rest; 0: b is the residual
    #: at rest (a robot without stiction)
    admittance_probe_speed_rad_s: float = 0.008
    admittance_probe_s: float = 0.8
    #: a joint at rest has its hand torque estimate dead-zoned by this × the model's friction level
    #: (control/rt/src/law/admittance.rs, stick zone): its friction then carries any torque up to
    #: its static level, which the current cannot tell from a hand; 0: none
    admittance_stick_zone: float = 1.0
    #: how a joint at rest keeps the load its friction carries from reading as a hand: "zone"
    #: (the stick zone above, symmetric about 0: a push must exceed about twice the static
    #: level to start a joint, 47-57 N mean force on plant seeds 101-103) or "anchor"
    #: (control/rt/src/law/admittance/stick_anchor.rs: a joint settled at rest is pushed by what
    #: moved its estimate off the one it settled with while the arm is guided, and by that beyond
    #: the stick zone while the arm rests; 8-10 N there; safe with the holds below,
    #: docs/results/teaching.md)
    admittance_stick: str = "anchor"
    #: per-joint hold (control/rt/src/law/admittance.rs): once no joint's estimate exceeds its
    #: static dead zone (the hand eases or lets go), a joint whose reference is slower than
    #: this [rad/s] is held, its reference still, until one does again; 0: none. 4 mrad/s:
    #: the reference creep at which a stuck joint sticks and slips under (A2)'s coupling
    #: (~1 mrad/s seen; docs/results/teaching.md)
    admittance_hold_rad_s: float = 0.004
    #: hold each joint also below the speed where its model's friction has stopped falling
    #: with speed (control/stribeck_speed.py), where that is faster: below it the model's
    #: friction is what its fit knows least, and a joint let go of slid on carried by that
    #: error (4 of 51 let-gos after a 20 N push with the 4 mrad/s hold alone)
    admittance_hold_stribeck: bool = True
    #: the admittance's start-up dither (control/rt/src/law/admittance/startup_dither.rs): each
    #: joint whose reference rests gets a sine of this share of the model's static friction level at
    #: ``admittance_dither_hz`` [Hz] on the torque it asks of the vendor loop, so the painter's push
    #: from rest needs only the rest of the breakaway; 0: off. Half: a joint nobody pushes stays
    #: stuck even where the model's level is off by 2x or its friction holds a load share of half
    #: its level (docs/control.md, Stiction; docs/results/teaching.md: seeds 100-109)
    admittance_dither: float = 0.5
    admittance_dither_hz: float = 4.0
    #: the speed limit of hand guiding on the tool point and the flange [m/s], kept by the
    #: admittance's reference, and by the zero-moment law's velocity command (scaled down
    #: where it would exceed it, so the vendor loop brakes the arm); 0: none.
    #: ISO 10218-1 allows 250 mm/s. The arm followed a reference at 250 mm/s with up to
    #: 252 mm/s (virtual cell, a 20 N push), and with the limit at 0.24 m/s an 80 N push that
    #: broke J1's stiction away reached 252 mm/s (the burst as the stuck joint lets go
    #: outruns the scaled command), so the default keeps 12 % below it
    max_tool_speed_m_s: float = 0.22
    #: cylinder pressure set-points sent to the valves [bar]: always, or with the schedule on,
    #: during identification (they ramp back to these)
    pressure_setpoint_bar: tuple[float, float] = (6.0, 4.0)
    #: in teaching and replay, set-points scheduled from the arm's pose: each cylinder asked
    #: for ``pressure_schedule_share`` of its joint's static load, within
    #: ``pressure_schedule_range_bar``, moving at most ``pressure_schedule_rate_bar_per_s``
    #: (control/pressure_schedule.py); off until it holds up on the whole teach-bench
    #: (docs/results/teaching.md)
    pressure_schedule: bool = False
    pressure_schedule_share: float = 0.8
    pressure_schedule_range_bar: tuple[float, float] = (0.5, 8.0)
    pressure_schedule_rate_bar_per_s: float = 2.0
    #: eq. (29): while a program replays (free motion, position mode), a point mass on the
    #: last link adapts to the measured motor torque, within ``model_adaptation_max_mass_kg``
    #: at ``model_adaptation_max_reach_m`` from the flange, converging at about
    #: ``model_adaptation_rate_per_s``; the zero-moment law takes it at the next teaching.
    #: Never while teaching: the hand is indistinguishable from a payload there
    #: (control/model_adaptation.py). Needs an identified model with its held-out RMS.
    model_adaptation: bool = True
    model_adaptation_rate_per_s: float = 0.5
    model_adaptation_max_mass_kg: float = 15.0
    model_adaptation_max_reach_m: float = 0.5
    #: where the adapted mass is kept across restarts (relative to the config; None: not
    #: kept); one adapted for another model file (re-identified since) is not used
    model_adaptation_file: Path | None = None
    #: I/O older than this: no command is published (the CAN driver then holds) [s]
    io_timeout_s: float = 0.25
    lifecycle_timeout_s: float = 0.25
    #: used when the controller does not report its cycle period [s]
    default_cycle_period_s: float = 0.004
    #: static-load check before teaching (control/load_check.py): allowed difference between
    #: the held arm's motor torque and the model's static load beyond the model's breakaway
    #: friction, per joint [N·m]; empty: none beyond the friction
    load_check_margin_nm: tuple[float, ...] = ()
    #: rest hold (control/rt/src/law/rest_hold.rs): the arm sticks where it is left until pushed
    #: harder than a band per joint: ``rest_hold_rms_factor`` × the model's held-out RMS, at least
    #: ``rest_hold_nm`` [N·m] (empty: no floor; a model without a held-out RMS and no floor: no
    #: hold)
    rest_hold_nm: tuple[float, ...] = ()
    rest_hold_rms_factor: float = 2.0
    #: the hold's stiffness is band / deflection [rad]
    rest_hold_deflection_rad: float = 1e-3
    #: the drives' velocity-loop (servo) rate from their datasheet [Hz], for the online
    #: inner-loop estimate (control/rt/src/law/inner_estimate.rs); 0: fast enough to be continuous
    drive_servo_rate_hz: float = 0.0
    #: run the online inner-loop estimate while teaching (control/rt/src/law/inner_estimate.rs;
    #: telemetry): ~50-80 µs of CPU per cycle, so off unless asked for
    inner_loop_estimate: bool = False
    #: per joint, the amplitude [A] of a sinusoidal torque dither (K times it, at 4.0 + 0.4 j
    #: Hz) added to the desired torque in teaching, so the online inner-loop estimate sees K_p
    #: apart from K_I (control/rt/src/law/inner_estimate.rs); () none
    inner_loop_dither_a: tuple[float, ...] = ()

    @property
    def uncommissioned(self) -> str | None:
        """Why this config cannot teach (what commissioning must set), or None."""
        missing = [
            k for k, v in (("model", self.model), ("inner_loop", self.omega_rad_s_per_nm)) if not v
        ]
        if not missing:
            return None
        return (
            f"the cell is not commissioned: [control] {' and '.join(missing)} not set "
            "(run `leadthrough identify` on this cell and set them to its model.json and "
            "inner_loop.json)"
        )

    def __post_init__(self) -> None:
        n = len(self.max_offset_rad)
        for name in ("omega_rad_s_per_nm", "upsilon_i_per_s"):
            require(
                len(getattr(self, name)) in (0, n),
                f"[control].{name}",
                f"needs {n} values (one per [control].max_offset_rad) or none",
            )
        require(
            bool(self.omega_rad_s_per_nm) == bool(self.upsilon_i_per_s),
            "[control].omega_rad_s_per_nm and upsilon_i_per_s",
            "give both or neither",
        )
        for name in (
            "max_velocity_rad_s",
            "damping_nm_s_per_rad",
        ):
            require(len(getattr(self, name)) == n, f"[control].{name}", f"needs {n} values")
        require(all(v > 0 for v in self.omega_rad_s_per_nm), "[control].omega_rad_s_per_nm", "> 0")
        require(
            len(self.load_check_margin_nm) in (0, n)
            and all(v >= 0 for v in self.load_check_margin_nm),
            "[control].load_check_margin_nm",
            f"needs {n} values >= 0 (or none)",
        )
        require(all(v > 0 for v in self.upsilon_i_per_s), "[control].upsilon_i_per_s", "> 0")
        require(
            len(self.admittance_damping_nm_s_per_rad) in (0, n)
            and all(v >= 0 for v in self.admittance_damping_nm_s_per_rad),
            "[control].admittance_damping_nm_s_per_rad",
            f"needs {n} values >= 0 (or none)",
        )
        require(
            len(self.rest_hold_nm) in (0, n) and all(v >= 0 for v in self.rest_hold_nm),
            "[control].rest_hold_nm",
            f"needs {n} values >= 0 (or none)",
        )
        require(
            0 <= self.rest_hold_rms_factor <= 10,
            "[control].rest_hold_rms_factor",
            f"{self.rest_hold_rms_factor} not in [0, 10]",
        )
        require(
            all(0.0 <= v <= 1.0 for v in self.inner_loop_dither_a),
            "[control].inner_loop_dither_a",
            f"{self.inner_loop_dither_a}: each must be in [0, 1] A",
        )
        require(
            0 <= self.drive_servo_rate_hz <= 1e6,
            "[control].drive_servo_rate_hz",
            f"{self.drive_servo_rate_hz} not in [0, 1e6] Hz",
        )
        require(
            0 < self.rest_hold_deflection_rad <= 0.1,
            "[control].rest_hold_deflection_rad",
            f"{self.rest_hold_deflection_rad} not in (0, 0.1] rad",
        )
        require(
            self.omega_adaptation_per_s >= 0,
            "[control].omega_adaptation_per_s",
            f"{self.omega_adaptation_per_s} must be >= 0",
        )
        require(
            self.omega_adaptation_per_s == 0
            or (
                len(self.omega_adaptation_min_torque_nm) == n
                and all(v > 0 for v in self.omega_adaptation_min_torque_nm)
            ),
            "[control].omega_adaptation_min_torque_nm",
            f"needs {n} values > 0 while omega_adaptation_per_s > 0",
        )
        for name in ("engage_rest_states", "engage_max_wait_states"):
            require_count(getattr(self, name), f"[control].{name}", 10_000, "states")
        require(
            0 <= self.command_delay_cycles <= 10,
            "[control].command_delay_cycles",
            f"{self.command_delay_cycles} not in 0..10",
        )
        require(all(v > 0 for v in self.max_offset_rad), "[control].max_offset_rad", "> 0")
        require(
            self.strategy in STRATEGIES,
            "[control].strategy",
            f"{self.strategy!r} not one of {STRATEGIES}",
        )
        require(
            math.isfinite(self.paper_adaptation_per_s) and 0 <= self.paper_adaptation_per_s <= 50,
            "[control].paper_adaptation_per_s",
            f"{self.paper_adaptation_per_s} not in [0, 50] 1/s",
        )
        require(
            math.isfinite(self.paper_upsilon_i0_per_s) and 0 <= self.paper_upsilon_i0_per_s <= 1000,
            "[control].paper_upsilon_i0_per_s",
            f"{self.paper_upsilon_i0_per_s} not in [0, 1000] 1/s",
        )
        require(
            not self.paper_dead_zone_nm
            or (
                len(self.paper_dead_zone_nm) == n
                and all(math.isfinite(v) and v >= 0 for v in self.paper_dead_zone_nm)
            ),
            "[control].paper_dead_zone_nm",
            f"needs {n} values >= 0 (or none)",
        )
        require(
            self.strategy != "paper"
            or (self.paper_adaptation_per_s == 0 or len(self.omega_adaptation_min_torque_nm) == n),
            "[control].omega_adaptation_min_torque_nm",
            f"needs {n} values > 0: the paper's adaptation uses its floors",
        )
        require(
            0.0 < self.admittance_mass_fraction <= 2.0,
            "[control].admittance_mass_fraction",
            f"{self.admittance_mass_fraction} not in (0, 2]",
        )
        require(
            0.0 <= self.admittance_band_rms_factor <= 10.0,
            "[control].admittance_band_rms_factor",
            f"{self.admittance_band_rms_factor} not in [0, 10]",
        )
        require(
            0.0 <= self.admittance_probe_speed_rad_s <= 0.05,
            "[control].admittance_probe_speed_rad_s",
            f"{self.admittance_probe_speed_rad_s} not in [0, 0.05] rad/s",
        )
        require(
            0.0 <= self.admittance_stick_zone <= 3.0,
            "[control].admittance_stick_zone",
            f"{self.admittance_stick_zone} not in [0, 3]",
        )
        require(
            self.admittance_stick in ADMITTANCE_STICKS,
            "[control].admittance_stick",
            f"{self.admittance_stick!r} is not one of {', '.join(ADMITTANCE_STICKS)}",
        )
        require(
            math.isfinite(self.admittance_dither) and 0.0 <= self.admittance_dither < 1.0,
            "[control].admittance_dither",
            f"{self.admittance_dither} not in [0, 1) of the friction level",
        )
        require(
            math.isfinite(self.admittance_dither_hz) and 0.0 < self.admittance_dither_hz <= 20.0,
            "[control].admittance_dither_hz",
            f"{self.admittance_dither_hz} Hz not in (0, 20]",
        )
        require(
            0.0 <= self.admittance_hold_rad_s <= 0.05,
            "[control].admittance_hold_rad_s",
            f"{self.admittance_hold_rad_s} not in [0, 0.05]",
        )
        require(
            0.1 <= self.admittance_probe_s <= 2.0,
            "[control].admittance_probe_s",
            f"{self.admittance_probe_s} not in [0.1, 2] s",
        )
        require(
            1.0 <= self.admittance_rest_damping_factor <= 1000.0,
            "[control].admittance_rest_damping_factor",
            f"{self.admittance_rest_damping_factor} not in [1, 1000]",
        )
        require(
            0.0 <= self.max_tool_speed_m_s <= 2.0,
            "[control].max_tool_speed_m_s",
            f"{self.max_tool_speed_m_s} not in [0, 2] m/s",
        )
        require(
            0.0 < self.admittance_filter_hz <= 100.0,
            "[control].admittance_filter_hz",
            f"{self.admittance_filter_hz} not in (0, 100] Hz",
        )
        require(
            guide_problem(self.guide) is None, "[control].guide", str(guide_problem(self.guide))
        )
        require(
            self.guide_axis in GUIDE_AXES,
            "[control].guide_axis",
            f"{self.guide_axis!r} not one of {GUIDE_AXES}",
        )
        for key in (
            "guide_stiffness_n_per_m",
            "guide_damping_n_s_per_m",
            "guide_rot_stiffness_nm_per_rad",
            "guide_rot_damping_nm_s_per_rad",
        ):
            v = getattr(self, key)
            ok = math.isfinite(v) and 0.0 <= v <= 1e5
            require(ok, f"[control].{key}", f"{v} not in [0, 1e5]")
        require(
            0.0 <= self.friction_compensation <= 1.0,
            "[control].friction_compensation",
            f"{self.friction_compensation} not in [0, 1]",
        )
        require(
            self.friction_deadband_rad_s >= 0,
            "[control].friction_deadband_rad_s",
            f"{self.friction_deadband_rad_s} must be >= 0",
        )
        require(
            math.isfinite(self.stiction_dither) and 0 <= self.stiction_dither < 1,
            "[control].stiction_dither",
            f"{self.stiction_dither} not in [0, 1) of the friction level",
        )
        require(
            math.isfinite(self.stiction_dither_hold_s) and self.stiction_dither_hold_s >= 0,
            "[control].stiction_dither_hold_s",
            f"{self.stiction_dither_hold_s} s must be >= 0",
        )
        require(
            math.isfinite(self.stiction_dither_hz) and 0 < self.stiction_dither_hz <= 50,
            "[control].stiction_dither_hz",
            f"{self.stiction_dither_hz} Hz not in (0, 50]",
        )
        require(
            math.isfinite(self.inertia_compensation) and 0 <= self.inertia_compensation < 1,
            "[control].inertia_compensation",
            f"{self.inertia_compensation} not in [0, 1)",
        )
        require(
            math.isfinite(self.inertia_compensation_hz)
            and 0.5 <= self.inertia_compensation_hz <= 50,
            "[control].inertia_compensation_hz",
            f"{self.inertia_compensation_hz} not in [0.5, 50] Hz",
        )
        require(
            math.isfinite(self.friction_ramp_guided_s) and 0 <= self.friction_ramp_guided_s <= 5,
            "[control].friction_ramp_guided_s",
            f"{self.friction_ramp_guided_s} not in [0, 5] s",
        )
        require(
            math.isfinite(self.friction_ramp_factor) and self.friction_ramp_factor >= 0,
            "[control].friction_ramp_factor",
            f"{self.friction_ramp_factor} must be a number >= 0",
        )
        for key, most in (
            ("model_adaptation_rate_per_s", 10.0),
            ("model_adaptation_max_mass_kg", 100.0),
            ("model_adaptation_max_reach_m", 2.0),
        ):
            v = getattr(self, key)
            ok = math.isfinite(v) and 0.0 < v <= most
            require(ok, f"[control].{key}", f"{v} not in (0, {most}]")
        require(
            math.isfinite(self.pressure_schedule_share)
            and 0.0 <= self.pressure_schedule_share <= 1.0,
            "[control].pressure_schedule_share",
            f"{self.pressure_schedule_share} not in [0, 1]",
        )
        lo_hi = self.pressure_schedule_range_bar
        require(
            len(lo_hi) == 2 and 0.0 <= lo_hi[0] <= lo_hi[1] <= 10.0,
            "[control].pressure_schedule_range_bar",
            f"{lo_hi} is not [min, max] within 0-10 bar",
        )
        require(
            math.isfinite(self.pressure_schedule_rate_bar_per_s)
            and 0.0 < self.pressure_schedule_rate_bar_per_s <= 10.0,
            "[control].pressure_schedule_rate_bar_per_s",
            f"{self.pressure_schedule_rate_bar_per_s} not in (0, 10] bar/s",
        )
        require(
            all(0 <= p <= 10 for p in self.pressure_setpoint_bar),
            "[control].pressure_setpoint_bar",
            f"{self.pressure_setpoint_bar} outside 0..10 bar",
        )
