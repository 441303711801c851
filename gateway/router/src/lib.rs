//! The locked bus's router, compiled (issue 45: nothing long on the cycle).
//!
//! On a locked bus every product process is a client of the gateway's router, so the cycle's
//! joint states and commands pass through it. zenoh decides each message against the
//! access-control list and reports the decision only as a `trace` event (zenoh 1.10.2; the
//! Python wheel is built without the `stats` feature). The Python wheel could count refusals
//! only by writing every decision, allowed ones included, as a formatted line to the process's
//! standard output and parsing it back in a Python thread: about two lines per message on the
//! cycle, which went on into the journal, and a router that blocked on the pipe whenever that
//! thread was late (a locked-bus stack test faulted on "no fresh joint state" in CI).
//!
//! Here the router is this crate's own zenoh session and the decisions go to an in-memory
//! counter ([`refusals::RefusalCounter`]): no line is formatted for an allowed message after
//! the first of its kind, nothing is written anywhere, and the gateway reads the counts.

pub mod refusals;

#[cfg(feature = "python")]
mod py;
