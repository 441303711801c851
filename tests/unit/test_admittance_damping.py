"""The admittance's own damping (``[control] admittance_damping_nm_s_per_rad``): what a hand
pushing beyond the dead zone feels; the damping where no hand pushes is the rest factor × it;
without the key, the zero-moment law's ``damping_nm_s_per_rad``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from example_cell import example_cell

from control.admittance_law import AdmittanceController
from control.cell_config import load_control_config
from control.declared_model import DeclaredModel
from gateway.errors import ConfigError

N = 6
DT = 0.004


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    base = load_control_config(example_cell(tmp_path_factory.mktemp("cell")))[0]
    return dataclasses.replace(base, strategy="admittance")


def controller(cfg, **kw) -> AdmittanceController:
    cfg = dataclasses.replace(cfg, **kw)
    return AdmittanceController(cfg, DeclaredModel.load(cfg.model))


def test_the_virtual_cell_damps_the_arm_less_than_the_wrist_and_less_than_the_zero_moment_law(cfg):
    """The shipped config: the arm's joints (J1-J3) lighter than the wrist's, each at most
    the zero-moment law's damping."""
    guided = np.array(cfg.admittance_damping_nm_s_per_rad)
    assert guided.shape == (N,)
    assert guided[:3].max() < guided[3:].min()
    assert (guided <= np.array(cfg.damping_nm_s_per_rad)).all()


def test_the_admittance_takes_its_own_damping_and_falls_back_to_the_zero_moment_laws(cfg):
    own = (4.0, 5.0, 6.0, 7.0, 8.0, 9.0)
    assert controller(cfg, admittance_damping_nm_s_per_rad=own).admittance.damping == list(own)
    fallback = controller(cfg, admittance_damping_nm_s_per_rad=())
    assert fallback.admittance.damping == list(cfg.damping_nm_s_per_rad)


def test_a_steady_push_beyond_the_band_runs_at_push_over_the_admittances_damping(cfg):
    """One joint pushed beyond its static band for long enough to settle: it runs at what
    the push exceeds the kinetic band by over the admittance's damping, the one the painter
    pays, not over the zero-moment law's."""
    own = (10.0, 4.0, 4.0, 20.0, 20.0, 10.0)
    # no Cartesian speed limit: the damping alone sets the speed
    adm = controller(cfg, admittance_damping_nm_s_per_rad=own, max_tool_speed_m_s=0.0).admittance
    adm.reset(np.zeros(N), None)
    band, kinetic = np.array(adm.band), np.array(adm.base_band)
    tau = np.zeros(N)
    tau[0] = band[0] + kinetic[0] + 3.0
    mass = np.eye(N)
    for _ in range(4000):
        adm.step(tau, np.zeros(N), mass, DT)
    assert adm.dq_r[0] == pytest.approx((tau[0] - kinetic[0]) / own[0], rel=1e-3)
    assert adm.dq_r[0] < adm.max_velocity[0]


@pytest.mark.parametrize("value", [(1.0,) * 5, (1.0, 1.0, -1.0, 1.0, 1.0, 1.0)])
def test_a_wrong_admittance_damping_is_refused_by_name(cfg, value):
    with pytest.raises(ConfigError, match="admittance_damping_nm_s_per_rad"):
        dataclasses.replace(cfg, admittance_damping_nm_s_per_rad=value)
