"""CPU time of the control process's hot path per cycle (`python -m sim_bridge.bench_loop_cli`).

Times :meth:`control.process.ControlProcess._on_state`, the zenoh callback that runs once per
controller cycle (decode the JointState → zero-moment torque → eq. (21) → encode the
JointCommand), on a stream of realistic joint states while the process is TEACHING with fresh
pressures: the path every cycle takes on the robot. Only the zenoh I/O is left out (the
publisher is a stub), so the figure is the Python work the loop adds per cycle.

Also times the message layer (``gateway/messages.py``) alone on the same data, so its share of
a cycle is visible, and with ``--profile`` prints the cProfile of the whole path.

By default the calls run back to back (warm caches) and are timed by the wall clock. With
``--period-ms 4`` each call follows a sleep of one cycle, as in the process, and is timed by the
thread's CPU clock: after the CPU idled, caches are cold and the same call can cost several
times more (3–4× on the 2-core VMs this was written on). That is the figure the process pays.

Run on an otherwise idle machine; compare figures from the same machine only.
"""

from __future__ import annotations

import cProfile
import gc
import pstats
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from control.cell_config import load_control_config
from control.process import ControlProcess
from gateway.bus import BusConfig
from gateway.errors import ConfigError
from gateway.message_factories import make_joint_command, make_joint_state
from gateway.messages import ControllerState, IoState, JointState, Lifecycle, LifecycleMsg

#: the cycle the benchmark simulates [s] (250 Hz)
CYCLE_PERIOD_S = 0.004
#: I/O state and lifecycle are refreshed this often, outside the timed calls, as the Modbus
#: driver (50 Hz) and the gateway (20 Hz) do [calls]
REFRESH_EVERY = 10


class _Payload:
    def __init__(self, data: bytes) -> None:
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


@dataclass
class _Sample:
    """Stands in for a zenoh Sample: what the callbacks read of it."""

    payload: _Payload
    key_expr: str = "lt/state/joints"


class _NullPublisher:
    """Stands in for the zenoh publisher: counts what would have been sent."""

    def __init__(self) -> None:
        self.count = 0
        self.last = b""

    def put(self, data: bytes) -> None:
        self.count += 1
        self.last = data


def joint_states(proc: ControlProcess, count: int, seed: int = 1) -> list[bytes]:
    """``count`` consecutive JointState payloads of an arm being guided by hand: a smooth random
    walk inside the soft limits at up to ~0.5 rad/s, some cycles near rest, with current and
    command echo, at :data:`CYCLE_PERIOD_S`."""
    rng = np.random.default_rng(seed)
    assert proc.ctl is not None, "a commissioned process"
    lower, upper = proc.ctl.lower, proc.ctl.upper
    n = proc.ctl.model.n
    q = 0.5 * (lower + upper)
    dq = np.zeros(n)
    out = []
    for k in range(count):
        dq = 0.995 * dq + rng.normal(0.0, 0.02, n)
        if k % 500 < 50:  # pauses: friction deadband and near-zero speeds
            dq = dq * 0.5
        dq = np.clip(dq, -0.5, 0.5)
        q = np.clip(q + dq * CYCLE_PERIOD_S, lower - 0.02, upper + 0.02)  # a few in the walls
        current = rng.normal(0.0, 5.0, n)
        q_cmd = q + rng.normal(0.0, 1e-3, n)
        st = make_joint_state(k, 1000.0 + k * CYCLE_PERIOD_S, ControllerState.EXTERNAL, 2, q,
                              dq, current, q_cmd, dq, CYCLE_PERIOD_S)  # fmt: skip
        out.append(st.to_bytes())
    return out


def make_process(cell: Path) -> tuple[ControlProcess, _NullPublisher]:
    """A ControlProcess on the commissioned cell config ``cell``, TEACHING, with a stub
    publisher."""
    cfg, _ = load_control_config(cell)
    if cfg.uncommissioned:
        raise ConfigError(f"{cell}: {cfg.uncommissioned}")
    proc = ControlProcess(cfg, BusConfig())
    pub = _NullPublisher()
    proc._pub_cmd = pub
    _refresh(proc)
    return proc, pub


def _refresh(proc: ControlProcess) -> None:
    now = proc.clock()
    proc.io = IoState(now, 6.0, 4.0, 6.0, 4.0, True, True)
    proc.lifecycle = LifecycleMsg(Lifecycle.TEACHING, 1, now)
    proc.lifecycle_rx_s = now


def _stats_us(ns: np.ndarray) -> dict[str, float]:
    us = ns / 1e3
    return {
        "median_us": round(float(np.median(us)), 2),
        "p99_us": round(float(np.percentile(us, 99)), 2),
        "mean_us": round(float(np.mean(us)), 2),
        "max_us": round(float(np.max(us)), 1),
    }


def _clock(period_s: float):
    """Back to back: the wall clock; one cycle apart: this thread's CPU clock (the sleeps and
    any preemption are not the call's cost)."""
    return time.thread_time_ns if period_s > 0 else time.perf_counter_ns


def time_on_state(proc: ControlProcess, payloads: list[bytes], period_s: float = 0.0) -> np.ndarray:
    """Per-call time [ns] of ``_on_state`` over ``payloads`` (one call each, ``period_s`` apart)."""
    samples = [_Sample(_Payload(p)) for p in payloads]
    out = np.empty(len(samples), dtype=np.int64)
    clock = _clock(period_s)
    on_state = proc._on_state
    for i, sample in enumerate(samples):
        if i % REFRESH_EVERY == 0:
            _refresh(proc)
        if period_s > 0:
            time.sleep(period_s)
        t0 = clock()
        on_state(sample)
        out[i] = clock() - t0
    return out


def time_messages(payloads: list[bytes], period_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per-call time [ns] of JointState.from_bytes, and of make_joint_command(...).to_bytes()."""
    clock = _clock(period_s)
    dec = np.empty(len(payloads), dtype=np.int64)
    enc = np.empty(len(payloads), dtype=np.int64)
    for i, p in enumerate(payloads):
        if period_s > 0:
            time.sleep(period_s)
        t0 = clock()
        st = JointState.from_bytes(p)
        dec[i] = clock() - t0
        q, dq = st.q_cmd_rad.tolist(), st.dq_rad_s.tolist()  # as the process passes them
        t0 = clock()
        make_joint_command(st.cycle, st.stamp_s, 1.0, q, dq).to_bytes()
        enc[i] = clock() - t0
    return dec, enc


def run(cell: Path, calls: int, warmup: int, profile: bool = False, period_s: float = 0.0) -> dict:
    """Time ``calls`` cycles of the process of ``cell`` (a commissioned cell config) after
    ``warmup`` untimed ones; figures in µs per call."""
    proc, pub = make_process(cell)
    payloads = joint_states(proc, warmup + calls)
    if profile:
        prof = cProfile.Profile()
        prof.enable()
        time_on_state(proc, payloads)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)
        proc, pub = make_process(cell)
    time_on_state(proc, payloads[:warmup])
    pub.count = 0
    gc.collect()
    cycle_ns = time_on_state(proc, payloads[warmup:], period_s)
    if pub.count != calls or proc.stats["bad_messages"] or proc.stats["io_stale"]:
        raise RuntimeError(f"not every call produced a command: {pub.count}/{calls}, {proc.stats}")
    dec, enc = time_messages(payloads[warmup:], period_s)
    return {
        "calls": calls,
        "period_s": period_s,
        "clock": "thread CPU" if period_s > 0 else "wall",
        "on_state": _stats_us(cycle_ns),
        "JointState.from_bytes": _stats_us(dec),
        "make_joint_command.to_bytes": _stats_us(enc),
    }
