"""The deflection the deflection sensors read at rest in a configuration.

At rest the links' tip deflections are the gravity sag ``K^-1 G`` of the
thesis's lumped model (plant_emulator/model/modes.py,
``static_deflection_in``). The gravity torques on link 1 and link 2 are
their weights times the horizontal arms of their centres of mass, i.e.
linear in ``cos`` and ``sin`` of the links' absolute angles ``theta1`` and
``theta1 + theta2`` (thesis §3.1.1, ``G1``, ``G2``). So the sag each
camera sees is, to a fraction of an LSB, the gravity basis

    w_j(theta1, theta2) = c0 + c1 cos t1 + c2 sin t1 + c3 cos(t1 + t2) + c4 sin(t1 + t2)

with coefficients fitted by least squares to the plant model's sensed sag
(the bending a camera on the link's root sees, minus the sensors' default
zero) of the default arm without payload, over the inspection loop's joint
ranges widened by 0.1 rad. ``tests/controller/test_input_monitors.py``
refits them against the plant model and checks the fit within 1e-3 in
(link 1: 2e-5 in, link 2: 9e-4 in; an LSB is 2.8e-4 in).

The controller may not import the plant, so the shared expectation lives
here: :mod:`controller.input_monitors` compares it with the measured
deflections (the ``disagree`` monitor).
"""

from __future__ import annotations

import math
from typing import Final

__all__ = ["SAG_COEFFICIENTS", "static_sag_in"]

SAG_COEFFICIENTS: Final[tuple[tuple[float, float, float, float, float], tuple[float, float, float, float, float]]] = (
    (0.10155713524106162, -0.4734697297778247, -0.001285820551394579, 0.0, 0.0),
    (-0.07864487002071793, -0.00037512573396242255, -0.0006251601116302053, -0.15518702324657094, 0.0009051100684139836),
)
"""Per link: c0 (in), then the weights of cos t1, sin t1, cos(t1 + t2), sin(t1 + t2) (in)."""


def static_sag_in(theta1: float, theta2: float) -> tuple[float, float]:
    """The two deflection sensors' readings (in) at rest at ``(theta1, theta2)`` (rad)."""
    c1, s1 = math.cos(theta1), math.sin(theta1)
    c12, s12 = math.cos(theta1 + theta2), math.sin(theta1 + theta2)
    a, b = SAG_COEFFICIENTS
    return (
        a[0] + a[1] * c1 + a[2] * s1 + a[3] * c12 + a[4] * s12,
        b[0] + b[1] * c1 + b[2] * s1 + b[3] * c12 + b[4] * s12,
    )
