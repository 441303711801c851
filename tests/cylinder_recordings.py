"""GR630ST recordings with assist cylinders for the analysis tests (test_ident_fit,
test_ident_cylinders): multi-sine train and test runs, pressures wandering ±15 % around the
nominal ones, the cylinders' torque taken out of the motor torque as the recorded arm's own."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from control.identification.datafile import write_measurements
from control.identification.rigid import RobotRegressor
from control.identification.synthetic import (
    GR630ST_MAX_SPEED_RAD_S,
    GR630ST_NOISE_NM,
    MultiSine,
    default_friction,
    synthesize,
)
from gateway.robot.description import RobotDescription
from gateway.robot.urdf import to_urdf

RATE_HZ = 1000.0


def write_recordings(
    root: Path, desc: RobotDescription, arm: RobotDescription
) -> tuple[Path, dict[str, Path]]:
    """``root/gr630st.urdf`` (of ``desc``) and the CSVs ``{"train", "test"}`` of the arm whose
    cylinders are ``arm``'s (``desc`` itself for the described ones), at :data:`RATE_HZ`."""
    urdf = root / "gr630st.urdf"
    urdf.write_text(to_urdf(desc))
    reg = RobotRegressor(urdf.read_text())
    friction = default_friction(
        desc.gear_ratios, (300, 1500, 600, 30, 10, 5), np.random.default_rng(1)
    )
    nominal = desc.nominal_pressures_bar
    paths = {}
    for name, seed, seconds, base_hz in (("train", 1, 40.0, 0.05), ("test", 2, 25.0, 0.07)):
        rng = np.random.default_rng(seed)
        traj = MultiSine.random(
            desc.lower_rad, desc.upper_rad, rng, GR630ST_MAX_SPEED_RAD_S, base_hz=base_hz
        )
        t = np.arange(round(seconds * RATE_HZ)) / RATE_HZ
        p = nominal * (1 + 0.15 * np.sin(2 * np.pi * 0.03 * t[:, None] + np.array([0.0, 1.0])))
        m = synthesize(
            reg, traj, t, friction, GR630ST_NOISE_NM, rng, desc=arm, pressures_bar=p,
            with_dq=(name == "test"),
        )  # fmt: skip
        paths[name] = root / f"{name}.csv"
        write_measurements(paths[name], m)
    return urdf, paths
