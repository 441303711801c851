"""The admittance's stick anchor (``[control] admittance_stick = "anchor"``): what a resting
joint's friction carries is taken off its hand torque estimate, and nothing more. Compiled, on
the admittance's cycle: control/rt/src/law/admittance/stick_anchor.rs says why and how.

``StickAnchor(n, filter_hz)``: ``reset()``, ``anchor``, ``hand(tau_h, resting, band, dt_s)``
→ ``(τ̂ − anchor, settled)`` per joint (lists).
"""

from __future__ import annotations

from control._rt import STICK_ANCHOR_FOLLOW_S as FOLLOW_S
from control._rt import STICK_ANCHOR_SETTLE_S as SETTLE_S
from control._rt import StickAnchor

__all__ = ["FOLLOW_S", "SETTLE_S", "StickAnchor"]
