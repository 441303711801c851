"""Constrained guiding's modes (issue 47): what the operator may ask ``leadthrough start
--guide`` for, what ``[control] guide`` may say, and what the gateway passes the control
process in its lifecycle message. The fixtures themselves are the control law's
(control/rt/src/law/guide.rs)."""

from __future__ import annotations

#: free; the tool's orientation held; and, with it, the tool point kept in the plane normal to
#: the tool's approach axis, or on a line along one of the tool's axes (``[control] guide_axis``)
GUIDES = ("free", "orientation-locked", "plane", "axis")
#: the tool frame's axis an ``axis`` guide runs along
GUIDE_AXES = ("x", "y", "z")


def guide_problem(value: object) -> str | None:
    """Why ``value`` is not a guide mode, or None if it is one."""
    if isinstance(value, str) and value in GUIDES:
        return None
    return f"guide {value!r} is not one of {', '.join(GUIDES)}"
