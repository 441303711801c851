"""The shared real Panda recording (Gaz et al., RA-L 2019) as a case of the table.

The data stay in ``../shared/datasets/panda_gaz2019`` (GPL-3.0; read at run time, never copied
into the repository): this module converts them, the first 70 % of the run for training and
the last 30 % for testing as the dataset's README does for its plain-fit figures, into the
measurement CSV of :func:`.generator.write_csv`, and writes a URDF from the README's modified-DH
table (no inertial values: identification needs only the kinematics).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

#: Where the recording is looked for when ``LEADTHROUGH_PANDA_DIR`` does not say.
SHARED_PATH = Path("shared") / "datasets" / "panda_gaz2019"


def data_dir() -> Path:
    """The recording's directory: ``$LEADTHROUGH_PANDA_DIR`` if set, else ``shared/datasets/
    panda_gaz2019`` beside the repository or beside any directory above it (a clone made
    elsewhere names it with the variable)."""
    env = os.environ.get("LEADTHROUGH_PANDA_DIR")
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[2]
    for parent in repo.parents:
        if (parent / SHARED_PATH).is_dir():
            return parent / SHARED_PATH
    return repo.parent / SHARED_PATH


DATA = data_dir()
#: README: plain regressor + QR base parameters + viscous/Coulomb/offset OLS, trained on the
#: first 70 %, tested on the last 30 % of the run [N·m].
README_PLAIN_FIT_RMS_NM = np.array([0.38, 0.56, 0.41, 0.50, 0.12, 0.14, 0.07])
TRAIN_FRACTION = 0.7
#: (a [m], d [m], alpha [rad]) per joint and the flange, modified DH, from the README.
DH = (
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -np.pi / 2),
    (0.0, 0.316, np.pi / 2),
    (0.0825, 0.0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0.0, 0.0, np.pi / 2),
    (0.088, 0.0, np.pi / 2),
    (0.0, 0.107, 0.0),
)


def available() -> bool:
    return DATA.is_dir()


def urdf() -> str:
    """URDF of the Panda's kinematics (modified DH: Rx(alpha) Tx(a) Rz(q) Tz(d) per joint)."""
    lines = ['<?xml version="1.0"?>', '<robot name="panda_dh">', '  <link name="base"/>']
    parent = "base"
    for i, (a, d, alpha) in enumerate(DH, start=1):
        child = f"link{i}" if i <= 7 else "flange"
        xyz = f"{a:.6g} {-np.sin(alpha) * d:.6g} {np.cos(alpha) * d:.6g}"
        kind = "revolute" if i <= 7 else "fixed"
        lines.append(f'  <link name="{child}">')
        if i <= 7:
            lines += [
                '    <inertial><origin xyz="0 0 0"/><mass value="1"/>',
                '      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>',
                "    </inertial>",
            ]
        lines.append("  </link>")
        lines.append(f'  <joint name="{"j" + str(i) if i <= 7 else "flange"}" type="{kind}">')
        lines.append(f'    <parent link="{parent}"/><child link="{child}"/>')
        lines.append(f'    <origin xyz="{xyz}" rpy="{alpha:.12g} 0 0"/>')
        if i <= 7:
            lines.append('    <axis xyz="0 0 1"/>')
            lines.append('    <limit lower="-3" upper="3" effort="100" velocity="3"/>')
        lines.append("  </joint>")
        parent = child
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def _load(name: str) -> np.ndarray:
    return np.loadtxt(DATA / name)


def runs() -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(train, test) as dicts of ``t`` (T,), ``q``, ``dq``, ``tau`` (T, 7)."""
    t = _load("exciting_traj_time.txt")
    arrays = {
        "q": _load("exciting_traj_positions.txt").reshape(-1, 7),
        "dq": _load("exciting_traj_velocity.txt").reshape(-1, 7),
        "tau": _load("exciting_traj_torques.txt").reshape(-1, 7),
    }
    k = int(TRAIN_FRACTION * t.size)
    out = []
    for part in (slice(0, k), slice(k, None)):
        out.append({"t": t[part], **{name: v[part] for name, v in arrays.items()}})
    return out[0], out[1]


def write(directory: Path) -> dict[str, Path]:
    """``train.csv``, ``test.csv`` and ``robot.urdf`` in ``directory``; their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = {k: directory / f for k, f in (("train", "train.csv"), ("test", "test.csv"))}
    for key, run in zip(("train", "test"), runs(), strict=True):
        table = np.column_stack([run["t"], run["q"], run["dq"], run["tau"]])
        header = ["t", *(f"{c}{i}" for c in ("q", "dq", "tau") for i in range(1, 8))]
        with open(paths[key], "w", encoding="ascii", newline="\n") as fh:
            fh.write(",".join(header) + "\n")
            np.savetxt(fh, table, fmt="%.12g", delimiter=",")
    paths["urdf"] = directory / "robot.urdf"
    paths["urdf"].write_text(urdf(), encoding="ascii")
    return paths
