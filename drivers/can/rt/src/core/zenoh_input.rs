//! The core's inputs from zenoh (core.rs): the gateway's lifecycle, the Modbus driver's I/O,
//! and the control process's JointCommand, forwarded, refused, or refused with its cycle held.

use super::command_checks::Problem;
use super::notes::WARNING;
use super::{Answer, CommandOutcome, CommandStamps, HostCore, IoIn, LastForward, LifecycleIn};
use crate::adapter::MAX_JOINTS;
use crate::frame::Frame;
use crate::lifecycle::LifecycleMsg;
use crate::messages::{IoState, JointCommand, Lifecycle};

impl HostCore {
    /// A Lifecycle payload (JSON) from the gateway. A bad one is counted (`bad_inputs`); an
    /// older or conflicting one is dropped (`lifecycle_order`); FAULT → STOPPED is the
    /// operator's reset, sent to a faulted controller on the next tick.
    pub fn on_lifecycle(&mut self, payload: &[u8], now: f64) {
        self.last_now = now;
        let msg = match LifecycleMsg::from_bytes(payload) {
            Ok(msg) => msg,
            Err(exc) => {
                self.bad_inputs += 1;
                self.notes.note(WARNING, "lifecycle", now, || {
                    format!("bad lifecycle message: {exc}")
                });
                return;
            }
        };
        let previous = self.lifecycle;
        let incoming = LifecycleIn {
            state: msg.state,
            seq: msg.seq,
            stamp_s: msg.stamp_s,
        };
        if let Some(dropped) = self.lifecycle_order.admit(&msg) {
            let key = match dropped {
                "out_of_order" => "lifecycle_out_of_order",
                "conflicting" => "lifecycle_conflicting",
                _ => "lifecycle_dropped",
            };
            self.notes.note(WARNING, key, now, || {
                let (seq, state) = match previous {
                    Some(p) => (p.seq.to_string(), p.state.name()),
                    None => ("-".to_string(), "-"),
                };
                format!(
                    "lifecycle message dropped ({dropped}): seq {} {} after seq {seq} {state}",
                    incoming.seq,
                    incoming.state.name()
                )
            });
            return;
        }
        if let Some(p) = previous {
            if p.state == Lifecycle::Fault && incoming.state == Lifecycle::Stopped {
                self.reset_wanted = true; // the operator's reset reached the gateway
            }
        }
        self.lifecycle = Some(incoming);
        self.lifecycle_rx_s = now;
    }

    /// An IoState payload from the Modbus driver (a bad one is counted in `bad_inputs`).
    pub fn on_io(&mut self, payload: &[u8], now: f64) {
        self.last_now = now;
        match IoState::from_bytes(payload) {
            Ok(msg) => {
                self.io = Some(IoIn {
                    stamp_s: msg.stamp_s,
                    enabling: msg.enabling,
                    estop_ok: msg.estop_ok,
                });
                self.io_rx_s = now;
            }
            Err(exc) => {
                self.bad_inputs += 1;
                self.notes
                    .note(WARNING, "io", now, || format!("bad IoState message: {exc}"));
            }
        }
    }

    /// Decide on one JointCommand: forward it, hold the cycle it was for, or neither. The
    /// frames to send (the forwarded command, or the hold/ramp answering its cycle) are
    /// appended to `out`.
    pub fn on_command(&mut self, payload: &[u8], now: f64, out: &mut Vec<Frame>) -> CommandOutcome {
        self.last_now = now;
        let cmd = match JointCommand::from_bytes(payload) {
            Ok(cmd) => cmd,
            Err(exc) => {
                self.reject_with("bad_message", now, || exc.to_string());
                return CommandOutcome {
                    answer: Answer::None,
                    command: None,
                };
            }
        };
        let cmd_cycle = cmd.cycle;
        let stamps = CommandStamps {
            cycle: cmd_cycle,
            state_stamp_s: cmd.state_stamp_s,
            sent_stamp_s: cmd.sent_stamp_s,
            state_rx_stamp_s: cmd.state_rx_stamp_s,
        };
        let (q_cmd, dq_cmd) = (cmd.q_cmd_rad(), cmd.dq_cmd_rad_s());
        let mut problem = self.check_command(cmd_cycle, cmd.state_stamp_s, q_cmd, dq_cmd, now);
        if problem.is_none() {
            if let Some(pending) = self.pending {
                let mark = out.len();
                if let Err(exc) =
                    self.adapter
                        .command_frames(pending.counter, q_cmd, dq_cmd, false, out)
                {
                    out.truncate(mark);
                    problem = Some(Problem::Frame(exc));
                }
            }
        }
        if let Some(problem) = problem {
            let reason = problem.reason();
            self.reject(&problem, now);
            if let Some(pending) = self.pending {
                let mine = cmd_cycle == (pending.cycle & 0xFFFF_FFFF);
                if mine && !pending.answered() && (reason == "stale" || reason == "out_of_range") {
                    self.hold(now, out); // no better answer comes
                    self.record_lost(now);
                    let answer = match self.pending_answer() {
                        Answer::None => Answer::Hold,
                        answer => answer,
                    };
                    return CommandOutcome {
                        answer,
                        command: Some(stamps),
                    };
                }
            }
            return CommandOutcome {
                answer: Answer::None,
                command: Some(stamps),
            };
        }
        let Some(pending) = self.pending.as_mut() else {
            return CommandOutcome {
                answer: Answer::None,
                command: Some(stamps),
            }; // unreachable
        };
        pending.answer = Answer::Command;
        let (cycle, stamp_s) = (pending.cycle, pending.stamp_s);
        self.forwarded += 1;
        self.lost.record(false, now);
        let n = self.n;
        let mut q = [0.0; MAX_JOINTS];
        let mut dq = [0.0; MAX_JOINTS];
        q[..n].copy_from_slice(q_cmd);
        dq[..n].copy_from_slice(dq_cmd);
        self.last_sent_q = Some(q);
        self.last_sent_dq = Some(dq);
        self.last_forwarded_q = Some(q);
        let period_s = self.feedback.map_or(0.0, |fb| fb.period_s);
        self.path.push(cycle, &q[..n]);
        self.last_forward = Some(LastForward {
            stamp_s: cmd.state_stamp_s.min(stamp_s),
            cycle,
            q,
            dq,
            period_s,
        });
        self.holding = false;
        self.ramp = None;
        CommandOutcome {
            answer: Answer::Command,
            command: Some(stamps),
        }
    }
}
