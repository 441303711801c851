"""Eq. (29) in the control process (control/model_adaptation.py): the payload's mass learnt
from the replay's states, handed to the law (and the static-load check) only while the arm is
neither taught nor replayed, and kept across restarts in ``model_adaptation_file``, written off
the slow loop.

:class:`ProcessAdaptation` is mixed into :class:`control.process.ControlProcess`, whose law,
config, lock and lifecycle it uses.
"""

from __future__ import annotations

import logging
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from control.declared_model import IdentifiedControlModel
from control.model_adaptation import (
    AdaptationSettings,
    PayloadAdaptation,
    load_state,
    model_sha256,
    state_document,
    write_state,
)
from gateway.messages import Lifecycle

log = logging.getLogger("leadthrough.control")


class ProcessAdaptation:
    """The control process's eq. (29) (module docstring); a part of
    :class:`control.process.ControlProcess`."""

    def _init_adaptation(self) -> None:
        """The adaptation's state, and the adaptation itself when the config asks for it and
        the law's model is an identified one (the end of the process's start)."""
        cfg = self.cfg
        #: eq. (29) in replay (control/model_adaptation.py), and the version of it the law
        #: compensates
        self.adaptation: PayloadAdaptation | None = None
        self._adaptation_applied = 0
        self._model_sha256 = ""
        #: why the kept adapted mass could not be used (None: no problem)
        self.adaptation_problem: str | None = None
        #: the adaptation's version last judged for the law (:meth:`_adapt_model`)
        self._adaptation_judged = -1
        #: the mass was kept from before this start (``model_adaptation_file``)
        self._adaptation_restored = False
        #: writes the adapted mass to disk off the slow loop (an fsync waits for the disk:
        #: 0.5 s beside a writer here, longer than the gateway waits for control's health),
        #: one write at a time; the write under way, checked by the slow loop
        self._saver = ThreadPoolExecutor(max_workers=1, thread_name_prefix="adaptation-save")
        self._saving: Future | None = None
        model = None if self.ctl is None else self.ctl.model
        if cfg.model_adaptation and isinstance(model, IdentifiedControlModel):
            if model.heldout_rms_nm is None:
                log.warning("model adaptation off: %s has no held-out RMS", cfg.model)
            else:
                self.adaptation = PayloadAdaptation(
                    model.identified,
                    model.desc,
                    model.heldout_rms_nm,
                    AdaptationSettings(
                        rate_per_s=cfg.model_adaptation_rate_per_s,
                        max_mass_kg=cfg.model_adaptation_max_mass_kg,
                        max_reach_m=cfg.model_adaptation_max_reach_m,
                    ),
                )
                self._restore_adaptation()

    def _restore_adaptation(self) -> None:
        """Start from the mass adapted before this start, if it was kept for this model."""
        adapt, ctl, path = self.adaptation, self.ctl, self.cfg.model_adaptation_file
        if adapt is None or ctl is None or path is None or self.cfg.model is None:
            return
        self._model_sha256 = model_sha256(self.cfg.model)
        try:
            kept = load_state(path, self._model_sha256)
        except ValueError as exc:  # the commissioned model, as if never adapted
            self.adaptation_problem = str(exc)
            log.error("adapted payload not used: %s", exc)
            return
        if kept is None:
            if path.exists():
                log.info("%s was adapted for another model (re-identified since): not used", path)
            return
        adapt.restore(*kept)
        self._apply_adaptation(save=False)
        self._adaptation_restored = True

    def _take_loop_samples(self) -> None:
        """The replay's states the compiled loop kept for eq. (29) (it plays the replay:
        control/rt/src/py_cycle_loop.rs), into the adaptation's batch."""
        loop, adapt = self._loop, self.adaptation
        if loop is None or adapt is None:
            return
        for cycle, stamp_s, q, dq, tau, p_bar in loop.take_samples():
            adapt.add(cycle, stamp_s, np.array(q), np.array(dq), tau, p_bar)

    def _adapt_model(self, now: float) -> None:
        """Eq. (29) on the replay's states collected since the last call; the law takes the
        adapted model once the arm is neither taught nor replayed (a model never changes
        under the operator's hand or mid-program)."""
        adapt, ctl = self.adaptation, self.ctl
        if adapt is None or ctl is None:
            return
        self._check_saved()
        self._take_loop_samples()
        adapt.process()
        if adapt.version == self._adaptation_applied or ctl.engaged:
            return
        with self._lock:
            state = self._fresh_state(now)
        if state in (Lifecycle.TEACHING, Lifecycle.REPLAYING):
            return
        if adapt.version == self._adaptation_judged:
            return
        self._adaptation_judged = adapt.version
        why = adapt.verdict()
        if why is not None:  # the law keeps the model it has; the estimate goes on
            before, after = adapt.residual_rms_nm()
            log.warning("adapted mass %+.2f kg not taken (eq. 29): %s; motor torque RMS as "
                        "identified %s, as adapted %s N·m", adapt.mass_kg, why, before,
                        after)  # fmt: skip
            return
        self._apply_adaptation(save=True)

    def _apply_adaptation(self, save: bool) -> None:
        """The law (and the load check) compensate the adapted model from now on; ``save``:
        keep it across restarts (``model_adaptation_file``)."""
        adapt, ctl = self.adaptation, self.ctl
        assert adapt is not None and ctl is not None
        model = ctl.model
        assert isinstance(model, IdentifiedControlModel)
        ctl.model = IdentifiedControlModel(adapt.adapted(), model.desc)
        self._adaptation_applied = adapt.version
        before, after = adapt.residual_rms_nm()
        log.info(
            "model %s (eq. 29): %+.2f kg at %s m on the flange; motor torque RMS over %d "
            "windows of this run, as identified %s, as adapted %s N·m",
            "adapted in replay" if save else "restored as adapted before",
            adapt.mass_kg, adapt.com_m, adapt.windows_used, before, after,
        )  # fmt: skip
        path = self.cfg.model_adaptation_file
        if save and path is not None and self._model_sha256:
            doc = state_document(adapt, self._model_sha256)
            self._saving = self._saver.submit(write_state, path, doc)

    def _check_saved(self) -> None:
        """The outcome of the last write of the adapted mass, once it has ended."""
        saving, path = self._saving, self.cfg.model_adaptation_file
        if saving is None or not saving.done():
            return
        self._saving = None
        exc = saving.exception()
        if exc is None:
            self.adaptation_problem = None
        elif isinstance(exc, OSError):
            self.adaptation_problem = f"adapted payload not kept: {path}: {exc}"
            log.error("%s", self.adaptation_problem)
        else:
            raise exc

    def _adaptation_report(self) -> dict | None:
        """Eq. (29) for the health (the operator's status) and the telemetry: the mass the
        law compensates, and the model's error on this run's replays (data it was not
        fitted to)."""
        adapt = self.adaptation
        if adapt is None:
            return None
        return {
            **adapt.report(),
            "applied": self._adaptation_applied == adapt.version,
            "restored": self._adaptation_restored,
            "problem": self.adaptation_problem,
        }
