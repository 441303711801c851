"""What the stages of ``leadthrough analyze`` (:mod:`.analyze`) share.

Its settings (:class:`AnalyzeOptions`, one field per command-line option of :mod:`.cli`), the
stages in the order they end (:data:`STAGES`) with their progress bar (:func:`stage_bar`) and
the clock that times them into ``summary.json``'s ``timing_s``, and the :class:`_Run` one
stage hands the next.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from control.identification import effect_rules
from control.identification.envelope import Envelope
from control.identification.friction_law import FRICTION_MODELS
from control.identification.heldout import TestFile
from control.identification.preprocess import (
    DEFAULT_RATE_HZ,
    DEFAULT_STICK_VELOCITY_RAD_S,
    Prepared,
)
from control.identification.rigid import DEFAULT_GRAVITY_M_S2, RobotRegressor
from control.identification.terms import Context
from gateway.errors import ConfigError
from gateway.progress import ProgressBar, progress_bar
from gateway.robot.description import RobotDescription

Progress = Callable[[str], None]
#: ``--friction`` value that picks the family by held-out error on the training files.
AUTO = "auto"
#: The stages of one analysis in the order they end: (its ``timing_s`` key, what it does).
#: Each end is one :meth:`_Clock.lap` and one step of the progress bar; the effect search
#: ends twice (training files, then the guard and the test run), ``timing_s`` adds both up.
STAGES: tuple[tuple[str, str], ...] = (
    ("read", "reading the files"),
    ("cutoff", "choosing the cutoff"),
    ("preprocess", "preprocessing"),
    ("regressor", "base regressor"),
    ("fit", "fitting the friction families"),
    ("effects", "effects on the training files"),
    ("effects", "guard, effects on the test run"),
    ("validate", "plots"),
    ("report", "report"),
)


@dataclass(frozen=True)
class AnalyzeOptions:
    """Settings of one analysis; every field has its command-line option in :mod:`.cli`."""

    friction: str = AUTO
    rate_hz: float = DEFAULT_RATE_HZ
    #: None: chosen from the training files (:mod:`.cutoff`)
    position_cutoff_hz: float | None = None
    #: None: the highest cutoff candidate (:func:`.cutoff.candidates`: 0.4 × the analysis
    #: rate, at most 40 Hz), one filter for the torque and every regressor column
    torque_cutoff_hz: float | None = None
    drive_gains: tuple[float, ...] | None = None
    gear_ratios: tuple[float, ...] | None = None
    description_path: Path | None = None
    gravity_m_s2: tuple[float, float, float] = DEFAULT_GRAVITY_M_S2
    find_effects: bool = True
    #: leave out (and report) a file with no stretch long enough to filter instead of failing;
    #: `identify` sets it: cycles disturbed by holds can chop a short segment to pieces
    skip_short_files: bool = False
    compare_friction: bool = True
    plots: bool = True
    search: effect_rules.Options = field(default_factory=effect_rules.Options)
    #: joints slower than this are stuck: their rows neither fit nor score the model
    #: (:func:`.preprocess.sliding_mask`); 0 keeps every row [rad/s]
    stick_velocity_rad_s: float = DEFAULT_STICK_VELOCITY_RAD_S

    def __post_init__(self) -> None:
        if not (np.isfinite(self.stick_velocity_rad_s) and self.stick_velocity_rad_s >= 0):
            raise ConfigError(
                f"--stick-velocity: {self.stick_velocity_rad_s!r} must be a number >= 0"
            )
        if self.friction not in (AUTO, *FRICTION_MODELS):
            raise ConfigError(
                f"--friction: {self.friction!r} is not one of {[AUTO, *FRICTION_MODELS]}"
            )
        if not 0 < self.search.margin < 1:
            raise ConfigError(f"--margin: {self.search.margin!r} must be in (0, 1)")
        if self.search.folds < 2:
            raise ConfigError(f"--folds: {self.search.folds!r} must be >= 2")


def stage_bar(
    enabled: bool | None = None, before: int = 0, desc: str = "analyze"
) -> AbstractContextManager[ProgressBar]:
    """The progress bar of an analysis: :data:`STAGES` (plus ``before`` steps of the caller's
    own ahead of them), for :func:`analyze`'s ``bar`` (:func:`gateway.progress.progress_bar`:
    ``enabled`` None draws it when stderr is a terminal, False never)."""
    return progress_bar(len(STAGES) + before, desc, "stage", enabled=enabled)


class _Clock:
    def __init__(self, progress: Progress, bar: ProgressBar | None = None) -> None:
        self.start = time.perf_counter()
        self.last = self.start
        self.timing: dict[str, float] = {}
        self.progress = progress
        self.bar = bar
        self.laps = 0
        if bar is not None:
            bar.set_label(STAGES[0][1])

    def say(self, message: str) -> None:
        self.progress(f"[{time.perf_counter() - self.start:7.1f} s] {message}")

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.timing[stage] = round(self.timing.get(stage, 0.0) + now - self.last, 3)
        self.last = now
        self.laps += 1
        if self.bar is not None:
            upcoming = STAGES[self.laps][1] if self.laps < len(STAGES) else "done"
            self.bar.advance(label=upcoming)


@dataclass
class _Run:
    """What the stages of one analysis hand each other."""

    reg: RobotRegressor
    urdf: Path
    meta: dict[str, Any]
    train: Prepared
    test: Prepared
    ctx_train: Context
    ctx_test: Context
    envelope: Envelope
    clock: _Clock
    #: the described cylinders' torque columns (:mod:`.cylinders`), None without pressures
    cyl_train: dict[int, np.ndarray] | None = None
    cyl_test: dict[int, np.ndarray] | None = None
    desc: RobotDescription | None = None
    #: the raw test files the figures are scored on (:mod:`.heldout`)
    test_files: list[TestFile] = field(default_factory=list)
