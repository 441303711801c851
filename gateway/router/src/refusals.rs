//! The router's access-control decisions, counted in memory: a `tracing` subscriber for
//! zenoh's access-control events alone.
//!
//! zenoh 1.10.2 reports each decision as a `trace` event on [`ACL_TARGET`], in one of four
//! forms (src/net/routing/interceptor/access_control.rs):
//!
//! * `{zid} on {subject} is authorized to {action} ({flow}) on {key}`
//! * `{zid} on {subject} is unauthorized to {action} ({flow}) on {key}`
//! * `Using cached result: {zid} is authorized to {action} ({flow}) on {key}`
//! * `Using cached result: {zid} is unauthorized to {action} ({flow}) on {key}`
//!
//! where `{subject}` names the link, e.g. `Interface(lo)+Username(operator)+Transport(Tcp)+…`.
//! A refusal is counted per (identity, action, key); a cached refusal carries only the session
//! id, whose identity an earlier uncached decision of the same session named. The cached
//! *allowed* decisions are the bulk (a declared publisher's every message, both flows): the
//! first one of each call site turns that call site off, so from then on zenoh does not even
//! build the event.

use std::collections::{HashMap, HashSet};
use std::fmt;
use std::sync::{Mutex, MutexGuard, RwLock};

use tracing_core::callsite::Identifier;
use tracing_core::field::{Field, Visit};
use tracing_core::span;
use tracing_core::subscriber::Interest;
use tracing_core::{Event, LevelFilter, Metadata, Subscriber};

/// The `tracing` target of zenoh's access-control decisions.
pub const ACL_TARGET: &str = "zenoh::net::routing::interceptor::access_control";
/// The identity of a link that authenticated without a user name (a certificate only).
pub const UNNAMED: &str = "(no user name)";
/// Most sessions whose identity is remembered (a session that reconnects gets a new id).
const MAX_SESSIONS: usize = 4096;

/// One decision, as zenoh words it.
#[derive(Debug, PartialEq, Eq)]
pub struct Decision<'a> {
    pub allowed: bool,
    /// the deciding session's zenoh id
    pub zid: &'a str,
    /// the user name of the link (`Username(...)` in its subject), when the event names it
    pub identity: Option<&'a str>,
    /// what was decided, without its flow: "Put", "Query", "Declare Subscriber", ...
    pub action: &'a str,
    pub key: &'a str,
}

/// Read one decision from an access-control event's message (None: not a decision).
pub fn parse(message: &str) -> Option<Decision<'_>> {
    let (head, tail, allowed) = if let Some((h, t)) = message.split_once(" is unauthorized to ") {
        (h, t, false)
    } else {
        let (h, t) = message.split_once(" is authorized to ")?;
        (h, t, true)
    };
    let (what, key) = tail.split_once(" on ")?;
    let action = match what.rfind(" (") {
        Some(i) if what.ends_with(')') => &what[..i],
        _ => what,
    };
    let (zid, identity) = match head.strip_prefix("Using cached result: ") {
        Some(zid) => (zid, None),
        None => {
            let (zid, subject) = head.split_once(" on ")?;
            (zid, Some(username(subject).unwrap_or(UNNAMED)))
        }
    };
    Some(Decision {
        allowed,
        zid: zid.trim(),
        identity,
        action,
        key,
    })
}

/// The `Username(...)` of a link's subject.
fn username(subject: &str) -> Option<&str> {
    let rest = &subject[subject.find("Username(")? + "Username(".len()..];
    Some(&rest[..rest.find(')')?])
}

#[derive(Default)]
struct Counts {
    /// (identity, action, key) → refusals
    refused: HashMap<(String, String, String), u64>,
    /// session id → identity, from the decisions that named both
    names: HashMap<String, String>,
}

/// The refusals seen so far, and the call sites known to report only allowed cached decisions.
#[derive(Default)]
pub struct RefusalCounter {
    counts: Mutex<Counts>,
    quiet: RwLock<HashSet<Identifier>>,
}

impl RefusalCounter {
    fn lock(&self) -> MutexGuard<'_, Counts> {
        self.counts.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Take in one access-control event's message, from `callsite`.
    pub fn observe(&self, callsite: Identifier, message: &str) {
        let Some(d) = parse(message) else { return };
        if d.allowed && d.identity.is_none() {
            // a cached allowed decision: nothing to count or learn, ever, from this call site
            self.quiet
                .write()
                .unwrap_or_else(|p| p.into_inner())
                .insert(callsite);
            return;
        }
        let mut counts = self.lock();
        if let Some(identity) = d.identity {
            if !counts.names.contains_key(d.zid) && counts.names.len() < MAX_SESSIONS {
                counts.names.insert(d.zid.to_owned(), identity.to_owned());
            }
        }
        if !d.allowed {
            let who = match d.identity {
                Some(i) => i.to_owned(),
                None => counts
                    .names
                    .get(d.zid)
                    .cloned()
                    .unwrap_or_else(|| format!("(session {})", d.zid)),
            };
            *counts
                .refused
                .entry((who, d.action.to_owned(), d.key.to_owned()))
                .or_default() += 1;
        }
    }

    /// Whether events from `callsite` still matter.
    pub fn wanted(&self, callsite: &Identifier) -> bool {
        !self
            .quiet
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .contains(callsite)
    }

    /// Every (identity, action, key) refused so far with its count, sorted.
    pub fn snapshot(&self) -> Vec<(String, String, String, u64)> {
        let mut out: Vec<_> = self
            .lock()
            .refused
            .iter()
            .map(|((i, a, k), n)| (i.clone(), a.clone(), k.clone(), *n))
            .collect();
        out.sort();
        out
    }
}

/// The `message` field of an event, formatted.
struct MessageText(String);

impl Visit for MessageText {
    fn record_debug(&mut self, field: &Field, value: &dyn fmt::Debug) {
        if field.name() == "message" {
            use fmt::Write;
            let _ = write!(self.0, "{value:?}");
        }
    }
}

/// A `tracing` subscriber that takes zenoh's access-control events into a [`RefusalCounter`]
/// and nothing else: every other call site is off.
pub struct AclSubscriber {
    pub counter: std::sync::Arc<RefusalCounter>,
}

fn acl_event(meta: &Metadata<'_>) -> bool {
    meta.is_event() && meta.target() == ACL_TARGET
}

impl Subscriber for AclSubscriber {
    fn register_callsite(&self, meta: &'static Metadata<'static>) -> Interest {
        if acl_event(meta) {
            Interest::sometimes() // until the call site shows what it reports
        } else {
            Interest::never()
        }
    }

    fn max_level_hint(&self) -> Option<LevelFilter> {
        Some(LevelFilter::TRACE)
    }

    fn enabled(&self, meta: &Metadata<'_>) -> bool {
        acl_event(meta) && self.counter.wanted(&meta.callsite())
    }

    fn new_span(&self, _: &span::Attributes<'_>) -> span::Id {
        span::Id::from_u64(1) // no span is ever enabled
    }

    fn record(&self, _: &span::Id, _: &span::Record<'_>) {}

    fn record_follows_from(&self, _: &span::Id, _: &span::Id) {}

    fn event(&self, event: &Event<'_>) {
        let mut text = MessageText(String::with_capacity(192));
        event.record(&mut text);
        self.counter.observe(event.metadata().callsite(), &text.0);
    }

    fn enter(&self, _: &span::Id) {}

    fn exit(&self, _: &span::Id) {}
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    const ZID: &str = "94bd50868f0f281995fa9eca926fef7c";

    fn named(verdict: &str, user: &str, what: &str, key: &str) -> String {
        format!(
            "{ZID} on Interface(lo)+Username({user})+Transport(Tcp)+{ZID} is {verdict} to {what} on {key}"
        )
    }

    #[test]
    fn each_form_of_decision_is_read() {
        let m = named("unauthorized", "operator", "Put (ingress)", "lt/cmd/joints");
        assert_eq!(
            parse(&m),
            Some(Decision {
                allowed: false,
                zid: ZID,
                identity: Some("operator"),
                action: "Put",
                key: "lt/cmd/joints",
            })
        );
        let m =
            format!("Using cached result: {ZID} is authorized to Put (egress) on lt/state/joints");
        let d = parse(&m).unwrap();
        assert!(d.allowed && d.identity.is_none() && d.key == "lt/state/joints");
        let m = named(
            "authorized",
            "control",
            "Declare Subscriber (egress)",
            "lt/cmd/joints",
        );
        assert_eq!(parse(&m).unwrap().action, "Declare Subscriber");
        let m = format!("{ZID} on Interface(lo)+Transport(Tls)+{ZID} is unauthorized to Query (ingress) on lt/req");
        assert_eq!(parse(&m).unwrap().identity, Some(UNNAMED));
        assert_eq!(parse("Access control is enabled"), None);
        assert_eq!(parse(""), None);
    }

    #[test]
    fn refusals_are_counted_by_identity_action_and_key_and_cached_ones_by_session() {
        let c = RefusalCounter::default();
        let site = || Identifier(&DUMMY);
        c.observe(
            site(),
            &named("unauthorized", "observer", "Put (ingress)", "lt/cmd/joints"),
        );
        c.observe(
            site(),
            &named("unauthorized", "observer", "Put (ingress)", "lt/cmd/joints"),
        );
        c.observe(
            site(),
            &format!("Using cached result: {ZID} is unauthorized to Put (ingress) on lt/state/io"),
        );
        c.observe(
            site(),
            "Using cached result: ffff is unauthorized to Put (ingress) on lt/state/io",
        );
        let snap = c.snapshot();
        assert_eq!(
            snap,
            vec![
                (
                    "(session ffff)".into(),
                    "Put".into(),
                    "lt/state/io".into(),
                    1
                ),
                ("observer".into(), "Put".into(), "lt/cmd/joints".into(), 2),
                ("observer".into(), "Put".into(), "lt/state/io".into(), 1),
            ]
        );
    }

    /// zenoh's call sites, as the real ones are declared: `tracing::trace!` on its target.
    fn emit(verdict_cached_allowed: bool, message: &str) {
        if verdict_cached_allowed {
            tracing::trace!(target: "zenoh::net::routing::interceptor::access_control", "{}", message);
        } else {
            tracing::trace!(target: "zenoh::net::routing::interceptor::access_control", "{}", message);
        }
    }

    #[test]
    fn a_subscriber_counts_refusals_and_turns_off_the_allowed_cached_call_site() {
        let counter = Arc::new(RefusalCounter::default());
        let sub = AclSubscriber {
            counter: counter.clone(),
        };
        tracing::subscriber::with_default(sub, || {
            let allowed = format!(
                "Using cached result: {ZID} is authorized to Put (egress) on lt/state/joints"
            );
            for _ in 0..3 {
                emit(true, &allowed);
            }
            emit(
                false,
                &named("unauthorized", "operator", "Put (ingress)", "lt/cmd/joints"),
            );
            tracing::trace!(target: "zenoh::net::routing::other", "is unauthorized to Put (x) on y");
            tracing::info!("{ZID} on Username(a) is unauthorized to Put (ingress) on z");
        });
        assert_eq!(
            counter.snapshot(),
            vec![("operator".into(), "Put".into(), "lt/cmd/joints".into(), 1)]
        );
        assert_eq!(counter.quiet.read().unwrap().len(), 1);
    }

    struct Dummy;
    impl tracing_core::callsite::Callsite for Dummy {
        fn set_interest(&self, _: Interest) {}
        fn metadata(&self) -> &Metadata<'_> {
            unimplemented!()
        }
    }
    static DUMMY: Dummy = Dummy;
}
