"""The virtual robot keeps its secrets (issue 22): the product reads none of the plant's truth,
and the plant computes with none of the product's model code.

The import graph is walked from the source (``ast``), transitively through every module of
this repository, so a helper imported on the way counts as much as a direct import.
"""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from sim_bridge.config import load_sim_config
from sim_bridge.plant import Plant
from sim_bridge.truth import CYLINDERS, FRICTION, INERTIALS, INNER_GAINS, TORQUE_CONSTANTS, draw

REPO = Path(__file__).resolve().parents[2]
PRODUCT = ("control", "drivers", "gateway")
#: The virtual cell's modules that compute or hold the robot's physics.
PLANT_MODULES = (
    "sim_bridge.plant",
    "sim_bridge.physics",
    "sim_bridge.truth",
    "sim_bridge.effects",
    "sim_bridge.config",
    "sim_bridge.operator",
    "sim_bridge.controller",
    "sim_bridge.sim",
    "sim_bridge.sim_cli",
    "sim_bridge.cia402_cell",
)
#: Files that hold the plant's truth.
TRUTH_FILES = ("gr630st_truth.toml", "gr630st_arm.xml")


def _module_file(name: str) -> Path | None:
    base = REPO.joinpath(*name.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imports(name: str) -> set[str]:
    """Modules of this repository that module ``name`` imports (at any depth of its code)."""
    path = _module_file(name)
    assert path is not None, name
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            parts = package.split(".")
            if node.level:
                root = ".".join(parts[: len(parts) - node.level + 1])
                mod = f"{root}.{node.module}" if node.module else root
            else:
                mod = node.module or ""
            found = [mod, *(f"{mod}.{a.name}" for a in node.names)]
        else:
            continue
        out |= {f for f in found if _module_file(f) is not None}
    return out


def _closure(start: str) -> dict[str, str]:
    """Every repository module reachable from ``start``: name -> the module importing it."""
    seen = {start: ""}
    todo = [start]
    while todo:
        name = todo.pop()
        for dep in _imports(name):
            if dep not in seen:
                seen[dep] = name
                todo.append(dep)
    return seen


def _chain(seen: dict[str, str], name: str) -> str:
    chain = [name]
    while seen[chain[-1]]:
        chain.append(seen[chain[-1]])
    return " <- ".join(chain)


@pytest.mark.parametrize("module", PLANT_MODULES)
def test_the_plant_imports_nothing_of_the_product_model(module):
    seen = _closure(module)
    bad = [m for m in seen if m == "control" or m.startswith("control.")]
    assert not bad, f"{module} reaches the product's code: {_chain(seen, bad[0])}"


def test_the_walk_follows_imports_transitively():
    # The check above must be able to fail: from the control process the walk reaches the
    # friction model through the declared model, and names the chain.
    seen = _closure("control.process")
    assert "control.model.friction" in seen
    assert _chain(seen, "control.model.friction").count(" <- ") >= 1
    assert "sim_bridge.physics" in _closure("sim_bridge.plant")


def test_no_product_module_reads_the_plant_truth():
    for pkg in PRODUCT:
        for py in (REPO / pkg).rglob("*.py"):
            text = py.read_text()
            for name in TRUTH_FILES:
                assert name not in text, f"{py.relative_to(REPO)} names the plant's {name}"
            for mod in ("sim_bridge.config", "sim_bridge.truth", "sim_bridge.plant"):
                assert mod not in text, f"{py.relative_to(REPO)} imports {mod}"


def test_seed_zero_is_the_truth_as_written_and_other_seeds_draw_within_the_ranges():
    cfg = load_sim_config()
    assert cfg.plant_seed == 0 and draw(cfg) is cfg
    base = Plant(cfg)
    for seed in (1, 2, 3):
        drawn = draw(dataclasses.replace(cfg, plant_seed=seed))
        kp = np.divide(drawn.inner_loop.kp_a_s_per_rad, cfg.inner_loop.kp_a_s_per_rad)
        ki = np.divide(drawn.inner_loop.ki_a_per_rad, cfg.inner_loop.ki_a_per_rad)
        assert np.all(np.abs(np.r_[kp, ki] - 1) <= INNER_GAINS) and np.ptp(kp) > 0.1
        tc = np.divide([f.tau_c_nm for f in drawn.friction], [f.tau_c_nm for f in cfg.friction])
        assert np.all(np.abs(tc - 1) <= FRICTION) and np.ptp(tc) > 0.05
        for u, u0 in zip(drawn.cylinders.units, cfg.cylinders.units, strict=True):
            assert abs(u.ab_m / u0.ab_m - 1) <= CYLINDERS
        k = np.divide(drawn.drives.gain_nm_per_a, cfg.drives.gain_nm_per_a)
        assert np.all(np.abs(k - 1) <= TORQUE_CONSTANTS) and np.ptp(k) > 0.01
        plant = Plant(dataclasses.replace(cfg, plant_seed=seed))
        mass = plant.model.body_mass[1:] / base.model.body_mass[1:]
        assert np.all(np.abs(mass - 1) <= INERTIALS + 1e-12) and np.ptp(mass) > 0.02
        np.testing.assert_array_equal(plant.lower_rad, base.lower_rad)
    # The same seed draws the same plant.
    again = Plant(dataclasses.replace(cfg, plant_seed=2))
    np.testing.assert_array_equal(
        again.model.body_mass, Plant(dataclasses.replace(cfg, plant_seed=2)).model.body_mass
    )
    assert again.cfg.inner_loop == draw(dataclasses.replace(cfg, plant_seed=2)).inner_loop
