"""Where a joint's model friction stops falling with speed: the admittance's hold speed.

Below the Stribeck velocity a joint's friction falls as it speeds up (the static level decays
to the Coulomb one), so a joint sliding there under a compliant drive sticks and slips, and
there the model's friction is what its fit knows least: on plant seed 0 the commissioned model
reads 52 N·m on J2 at 10 mrad/s where the plant slides on 25 (docs/results/teaching.md). The
admittance's estimate of the hand then carries that error along the motion, and a joint let go
of at those speeds slid on by itself. Beyond the speed where the friction is at its least, the
model's friction is its Coulomb and viscous law, which commissioning fits within about 1 N·m.
"""

from __future__ import annotations

import numpy as np

from control.declared_model import DeclaredModel

#: the speeds searched [rad/s]: from the speed an encoder's difference resolves at a cycle to
#: the fastest hold the configuration allows (control/config.py: a faster hold would stop
#: joints a painter guides at 0.02-0.2 rad/s)
SEARCH_RAD_S = np.geomspace(1e-3, 0.05, 60)


def stribeck_speeds(model: DeclaredModel, q_rad: np.ndarray, min_fall_nm: np.ndarray) -> np.ndarray:
    """Per joint, the speed [rad/s] past which the model's friction at ``q_rad`` is within
    ``min_fall_nm`` (the model's error) of its least value past its peak: where its Stribeck
    fall is over (the larger of the two directions; the smooth sign makes the friction rise
    from rest to the static level first); at most the search's last speed; 0 for a joint
    whose friction falls by no more than ``min_fall_nm`` past its peak (no Stribeck fall the
    fit could tell from its error). Raises ArithmeticError where the model's friction is not finite
    (DeclaredModel.cycle_torques_nm)."""
    n = model.n
    cylinders = [0.0] * len(model.desc.cylinders)
    speeds = np.zeros(n)
    for sign in (1.0, -1.0):
        curve = np.array([sign * np.array(model.cycle_torques_nm(q_rad, [sign * v] * n,
                                                                 cylinders)[1])
                          for v in SEARCH_RAD_S])  # fmt: skip
        for j in range(n):
            peak = int(np.argmax(curve[:, j]))
            past = curve[peak:, j]
            if past[0] - past.min() > min_fall_nm[j]:
                # the first speed past the peak within the model's error of the least friction
                settled = peak + int(np.argmax(past - past.min() <= min_fall_nm[j]))
                speeds[j] = max(speeds[j], SEARCH_RAD_S[settled])
    return speeds
