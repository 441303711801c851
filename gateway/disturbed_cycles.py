"""Which recorded cycles the export leaves out: those the CAN driver's answer disturbed.

Each JointState flags how the CAN driver answered the cycle before it (PROTOCOL.md §3):

- **a hold** (FLAG_PREV_HOLD): the velocity command steps to zero under a moving arm, and the
  vendor's velocity loop answers with a current transient the kinematics, sampled once a cycle,
  cannot follow. The cycle is disturbed, always.
- **a coast** (FLAG_PREV_COAST): the driver sent the last command moved on by its own velocity.
  The law would have sent its next command instead, which departs from that same continuation
  by one of the law's own cycle-to-cycle changes. So a *single* coast, followed by the law's
  command again, hands the vendor loop a command that differs from the law's by a step drawn
  from the steps the law takes every cycle: nothing the commanded cycles around it do not show
  the loop too. It is not disturbed. Over k lost cycles in a row the difference is the law's
  change over k cycles, which grows with k, and a run of coasts ends in a hold when it lasts
  (drivers/can/rt/src/lost_cycles.rs): a run of two or more, one that a hold ends, or a coast
  beside a cycle that was not recorded (the run's length unknown), is disturbed.

(The demo's teaching on an idle machine, 2026-12-04: three coasts in 2,400 cycles, all single;
the velocity step from each to the law's next command was below the 99th percentile of the
law's own steps on every joint but one, below its largest there. Each had cost the export
0.16 s, and on a CI machine (2026-12-04) disturbed cycles, of a kind its log does not name,
chopped the last 30 % of that teaching into stretches too short to analyse.)
"""

from __future__ import annotations

from gateway.messages import FLAG_PREV_COAST, FLAG_PREV_HOLD, JointState

_ANSWERED_OTHERWISE = FLAG_PREV_HOLD | FLAG_PREV_COAST


def disturbed_cycles(
    states: list[JointState], cycle_range: tuple[int, int] | None
) -> list[tuple[int, float]]:
    """(cycle, period [s]) of the cycles in ``cycle_range`` (inclusive; None: all) the CAN
    driver's answer disturbed (module doc): every hold, and every coast but a single one the
    law's command followed. ``states``: the recording's joint states."""
    answered = {st.cycle - 1: st.flags for st in states}  # how cycle c was answered
    out = []
    for st in states:
        cycle = st.cycle - 1
        if cycle_range is not None and not cycle_range[0] <= cycle <= cycle_range[1]:
            continue
        if not st.flags & _ANSWERED_OTHERWISE:
            continue
        before, after = answered.get(cycle - 1), answered.get(cycle + 1)
        single_coast = (
            st.flags & _ANSWERED_OTHERWISE == FLAG_PREV_COAST
            and before is not None  # unrecorded neighbours: the run's length is unknown
            and after is not None
            and not (before | after) & _ANSWERED_OTHERWISE
        )
        if not single_coast:
            out.append((cycle, st.cycle_period_s))
    return out
