"""How fast commissioning may run the virtual plant: faster than real time only where the
process has CPUs to spare for it (sim_bridge/commission.py ``commission_speedup``)."""

from __future__ import annotations

import os

from sim_bridge.commission import COMMISSION_SPEEDUP, SPEEDUP_MIN_CPUS, commission_speedup


def test_one_cpu_commissions_at_real_time_and_two_at_the_speedup():
    assert commission_speedup(1) == 1.0
    assert SPEEDUP_MIN_CPUS == 2 and COMMISSION_SPEEDUP > 1.0
    assert commission_speedup(2) == COMMISSION_SPEEDUP
    assert commission_speedup(8) == COMMISSION_SPEEDUP


def test_the_default_is_this_process_affinity_as_taskset_leaves_it(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert commission_speedup() == 1.0
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    assert commission_speedup() == COMMISSION_SPEEDUP
