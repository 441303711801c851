"""The admittance's start-up dither (``[control] admittance_dither``): the painter's first push
from rest breaks a joint's static friction with help (issue 47, item 2). Compiled, on the
admittance's cycle: control/rt/src/law/admittance/startup_dither.rs says why and how.

``StartupDither(share, hz, rest_rad_s, delay_cycles)``: ``reset(friction_level_nm)``,
``step(dq_r, dt_s)`` → the dither of a command, ``drove()`` → the dither of the command that
drove the state now in (lists) [N·m].
"""

from __future__ import annotations

from control._rt import STARTUP_DITHER_FADE_S as FADE_S
from control._rt import StartupDither

__all__ = ["FADE_S", "StartupDither"]
