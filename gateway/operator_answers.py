"""The gateway's side of the operator's request channel (gateway/operator_request.py is the
operator's): each request that arrived since the last tick is answered on the tick's thread, a
command by the lifecycle (gateway/lifecycle.py) with the cell's status, a mark once the program's
thread has it on disk (gateway/program_thread.py).

:class:`OperatorAnswers` is mixed into :class:`gateway.supervisor.Gateway`, whose state it reads
and changes under the gateway's lock: the machine, the joint state, the children, the taught
program and the requests' channel.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future

from gateway.errors import MessageError
from gateway.guide_modes import guide_problem
from gateway.lifecycle import Observations
from gateway.messages import JointState, Lifecycle, decode_json, encode_json
from gateway.program import ProgramError, program_path
from gateway.program_thread import STALL_S

log = logging.getLogger("leadthrough.gateway")


class OperatorAnswers:
    """The operator's requests answered (module docstring); a part of
    :class:`gateway.supervisor.Gateway`."""

    def _serve_requests(self) -> None:
        """Answer the operator requests that arrived since the last tick, on the tick's thread
        (no Python runs in zenoh's threads for them); a mark is answered by a later tick, once
        the program's thread has it on disk."""
        if self._requests is None:
            return
        while (query := self._requests.try_recv()) is not None:
            try:
                reply = self._request(query.payload.to_bytes() if query.payload else b"")
            except BaseException:
                query.drop()
                raise
            if isinstance(reply, Future):
                self._waiting.append((query, reply, time.monotonic()))
                continue
            try:
                query.reply(query.key_expr, encode_json(reply))
            finally:
                query.drop()
        self._answer_marks()

    def _answer_marks(self, give_up: bool = False) -> None:
        """Answer the operator's marks that are on disk now (``give_up``: every one still
        waiting, as not confirmed; so too one waiting longer than the disk may stall)."""
        now, waiting = time.monotonic(), []
        for query, written, since_s in self._waiting:
            late = give_up or now - since_s > STALL_S + 1.0
            if not (written.done() or late):
                waiting.append((query, written, since_s))
                continue
            if written.done():
                ok, message = written.result()
            else:
                ok, message = (
                    False,
                    f"the disk has not confirmed the mark after {now - since_s:.1f} s",
                )
            try:
                query.reply(query.key_expr, encode_json(self._reply("mark", ok, message, now)))
            finally:
                query.drop()
        self._waiting = waiting

    def _request(self, data: bytes) -> dict | Future:
        """One operator request (JSON): its reply, or for a mark a future of ``(ok,
        message)`` done once it is on disk (or refused)."""
        now = time.monotonic()
        try:
            req = decode_json(data, "request")
            command = str(req.get("command", ""))
            plan = req.get("plan")
            if command in ("identify", "replay") and not (
                isinstance(plan, dict) and plan.get("plan_id")
            ):
                raise MessageError(f"{command} needs a 'plan' object with a 'plan_id'")
            name, label = req.get("program"), req.get("label", "")
            if name is not None and not isinstance(name, str):
                raise MessageError(f"'program' must be a name (string), not {name!r}")
            guide = req.get("guide")
            if guide is not None and (problem := guide_problem(guide)) is not None:
                raise MessageError(problem)
            if not isinstance(label, str):
                raise MessageError(f"'label' must be a string, not {label!r}")
        except MessageError as exc:
            log.info("operator request refused: %s", exc)
            return {"ok": False, "message": str(exc)}
        with self.lock:
            self._take_states()
            obs = self.observations(now, self._dead)
            st, state = self.joint_state, self.machine.state
            if command != "mark":
                try:
                    ok, message = self._command(command, plan, name, obs, guide)
                except ProgramError as exc:
                    ok, message = False, str(exc)
        if command == "mark":
            return self._mark(label, "cli", st, state)
        return self._reply(command, ok, message, now)

    def _reply(self, command: str, ok: bool, message: str, now: float) -> dict:
        """An operator command's reply (logged): its verdict and the cell's status."""
        log.info("operator %s → %s: %s", command, "ok" if ok else "refused", message)
        with self.lock:
            return {"ok": ok, "message": message, **self.status(now)}

    def _command(
        self,
        command: str,
        plan: dict | None,
        name: str | None,
        obs: Observations,
        guide: str | None = None,
    ) -> tuple[bool, str]:
        """One operator command but `mark` (lock held). ``guide``: the constrained guide
        `start` asks for; a start while ready or teaching changes it (the law takes its
        reference where the tool is then)."""
        m = self.machine
        if command == "start" and m.state in (Lifecycle.READY, Lifecycle.TEACHING) and guide:
            self.guide = guide
            return True, f"guide now {guide}"
        if command == "identify":
            assert plan is not None
            return m.identify(plan, obs)
        if command == "replay":
            assert plan is not None
            return m.play(Lifecycle.REPLAYING, plan, obs)
        if command == "start" and m.state in (Lifecycle.STOPPED,):
            path = program_path(self.program_dir, name)
            ok, message = m.command(command, obs)
            if ok:
                self.guide = guide
                self.teach.prepare(path)
                message += f"; teaching is recorded to {path}"
            return ok, message
        if command == "reset" and (refused := [c for c in self.children.values()
                                                if c.config_refused]):  # fmt: skip
            for child in refused:  # the operator says the file is mended: try it again
                child.config_refused = False
                self._start_child(child)
            names = ", ".join(c.name for c in refused)
            return False, f"restarted {names}; reset again once it runs"
        return m.command(command, obs)

    def _mark(self, label: str, source: str, st: JointState | None, state: Lifecycle) -> Future:
        """Mark a waypoint at joint state ``st`` (lifecycle ``state``): a future of ``(ok,
        message)``, done once the mark is on disk or refused (a disk that refused it faults
        the cell at the next tick: :meth:`~gateway.supervisor.Gateway._follow_program`). The
        tick's thread, lock not held."""
        answer: Future = Future()
        if st is None:
            answer.set_result((False, "no joint state to mark"))
            return answer
        if state not in (Lifecycle.TEACHING, Lifecycle.READY):
            answer.set_result((False, f"marks are made while teaching, not {state.name.lower()}"))
            return answer

        def written(done: Future) -> None:
            try:
                mark, path = done.result()
            except ProgramError as exc:
                answer.set_result((False, str(exc)))
            else:
                answer.set_result((True, f"mark {mark.index} recorded in {path}"))

        self.teach.mark(st.stamp_s, st.cycle, st.q_rad, label, source).add_done_callback(written)
        return answer
