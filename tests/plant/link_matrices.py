"""The flexible links' matrices written out from the model's equations
(docs/plant-model.md; thesis Ch. 3) with numpy, for the plant tests to hold
the integrator's compiled arithmetic against: lumped root springs, the
configuration-dependent mass matrix, gravity's load and stiffness."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from plant_emulator.model.kinematics import A1_IN, A2_IN, CYLINDER1, INCH, POUND
from plant_emulator.model.modes import Structure

FloatArray = npt.NDArray[np.float64]


def link_matrices(structure: Structure, payload: bool, theta1: float, theta2: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(M, K, E, G) at one configuration, SI: ``M beta'' + K beta = G - E theta''``."""
    l1, l2 = A1_IN * INCH, A2_IN * INCH
    m1 = structure.link1_mass_lb * POUND
    m2 = structure.link2_mass_lb * POUND
    mt = (structure.tip_mass_lb + (structure.payload_lb if payload else 0.0)) * POUND
    me = structure.elbow_mass_lb * POUND
    big_mt = me + m2 + mt  # everything beyond link 1, at its tip
    first = m2 * l2 / 2.0 + mt * l2  # link 2's first moment about the elbow
    ia = m2 * l2**2 / 3.0 + mt * l2**2  # link 2's inertia about the elbow
    i1 = m1 * l1**2 / 3.0
    a1 = m1 * l1 / 2.0 + big_mt * l1  # gravity's moment arm sum for link 1
    kap = structure.slope_transmission
    c2 = math.cos(theta2)
    base = i1 + big_mt * l1**2
    M = np.array([[base + 2 * kap * l1 * first * c2 + kap**2 * ia, l1 * first * c2 + kap * ia], [l1 * first * c2 + kap * ia, ia]])
    E = np.array([[base + (1 + kap) * l1 * first * c2 + kap * ia, l1 * first * c2 + kap * ia], [l1 * first * c2 + ia, ia]])
    lever1 = float(CYLINDER1.lever_in_per_rad(theta1)) * INCH  # m of cylinder-1 stroke per rad
    arm2 = structure.crank_radius_in * INCH * math.sin(theta2 + math.radians(structure.crank_offset_deg))
    k1 = 1.0 / (1.0 / structure.link1_root_stiffness_nm_per_rad + 1.0 / (structure.cylinder1_stiffness_n_per_m * lever1**2))
    k2 = 1.0 / (1.0 / structure.link2_root_stiffness_nm_per_rad + 1.0 / (structure.bar_stiffness_n_per_m * arm2**2))
    g = structure.gravity_m_s2
    s1, s12 = math.sin(theta1), math.sin(theta1 + theta2)
    c1, c12 = math.cos(theta1), math.cos(theta1 + theta2)
    K = np.array([[k1 - g * a1 * s1 - kap**2 * g * first * s12, -kap * g * first * s12], [-kap * g * first * s12, k2 - g * first * s12]])
    G = np.array([-g * (a1 * c1 + kap * first * c12), -g * first * c12])
    return M, K, E, G
