"""M̂ of the identified model for the admittance's compiled cycle, computed off the cycle.

The admittance renders a share of the arm's inertia (control/rt/src/law/admittance.rs, (A2)),
M̂(q) of the identified model at its reference, recomputed once the reference has moved
``INERTIA_STEP_RAD`` (control/zero_moment_law.py). The identified model is Python (its
regressor is pinocchio's); the cycle is not. So a thread of the control process, below the
cycle's priority, asks the compiled cycle every :data:`PERIOD_S` whether it wants M̂ again and
hands it over (:meth:`control.admittance_law.AdmittanceController.refresh_mass`); the cycle
keeps the newest it was given. M̂ then lags the reference by at most a period and one
evaluation (about a millisecond here): at 0.5 rad/s that is some 10 mrad of a joint, inside the
0.02 rad over which the law has always kept one M̂.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import numpy as np

from control.admittance_law import AdmittanceController
from gateway.realtime import below_the_cycle

log = logging.getLogger("leadthrough.control")

#: how often the thread asks the cycle whether M̂ is wanted [s]
PERIOD_S = 0.02


class MassRefresh:
    """The thread (module docs); ``pose()`` gives the arm's newest measured q, or None."""

    def __init__(self, ctl: AdmittanceController, pose: Callable[[], np.ndarray | None]) -> None:
        self.ctl, self.pose = ctl, pose
        self.stop_event = threading.Event()
        self.refreshed = 0
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name="admittance-mass", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self.stop_event.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def step(self) -> None:
        """Hand the cycle M̂ where it wants one, if it does."""
        where = self.ctl.mass_pose(self.pose())
        if where is None:
            return
        try:
            self.refreshed += self.ctl.refresh_mass(where)
        except (ValueError, ArithmeticError) as exc:  # the model undefined there: keep the last
            self.errors += 1
            if self.errors == 1 or self.errors % 1000 == 0:
                log.error("M̂ of the identified model not computed at %s: %s", where, exc)

    def _run(self) -> None:
        below_the_cycle("control (M̂ thread)")
        while not self.stop_event.wait(PERIOD_S):
            self.step()
            self.ctl.log_events()
