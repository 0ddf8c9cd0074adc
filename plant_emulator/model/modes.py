"""RALF's flexibility: a configuration-dependent two-mode model.

The model (docs/plant-model.md has the derivation and the calibration)
-----------------------------------------------------------------------
Each link is a rigid body on a torsional spring at its root: "lumped
flexibility".  The flexible coordinates are small rotations on top of the
rigid joint angles that the hydraulics impose:

* ``beta1``: link 1 rotating about joint 1; its tip deflects ``w1 = L1 beta1``
  perpendicular to the link;
* ``beta2``: link 2 rotating about the elbow relative to its base tangent;
  its tip deflects ``w2 = L2 beta2`` relative to that tangent.

Link 2's base tangent follows link 1's flexing by ``kappa * beta1`` (the
*slope transmission*: 0 for an ideal parallelogram that holds link 2's
absolute orientation, 1 for a link clamped to link 1's tip).

Masses: link 1 (uniform, ``m1``), the elbow hardware (``me``, a point mass at
the elbow), link 2 (uniform, ``m2``), the tip hardware (``mt``) and the
payload (15.65 lb) at the tip.  The kinetic energy of the flexing, with the
joints held, gives the configuration-dependent mass matrix

    M11 = I1 + Mt L1^2 + 2 kappa L1 S c2 + kappa^2 Ia
    M12 = L1 S c2 + kappa Ia
    M22 = Ia

with ``I1 = m1 L1^2/3``, ``Mt = me + m2 + mt``, ``S = m2 L2/2 + mt L2``
(first moment of link 2 and tip about the elbow), ``Ia = m2 L2^2/3 + mt L2^2``
and ``c2 = cos(theta2)``.  The cross terms with the rigid motion give the
input matrix ``E = M_beta,theta``: the joint accelerations drive the
flexible subsystem as base excitation, ``f = -E theta''``.

Springs.  Joint 1's chain is the cylinder's oil column (stiffness
``k_c1`` N/m) seen through the pin-triangle lever ``r1(theta1)`` in series
with link 1's root bending ``k_r1``.  Joint 2's chain is the parallel bar (axial
stiffness ``k_bar``, cylinder 2's oil column lumped in) acting on the elbow
crank of radius ``r_c``: its lever about the elbow is ``r_c sin(theta2 + beta_c)``,
which shrinks towards the parallelogram's dead point as the arm stretches
towards the top of the workspace, in series with link 2's root bending
``k_r2``::

    k1 = 1 / (1/k_r1 + 1/(k_c1 r1^2)),   k2 = 1 / (1/k_r2 + 1/(k_bar r_c^2 sin^2(theta2 + beta_c)))

Gravity loads the links (static deflection ``beta_s = K^-1 G``) and
stiffens or softens them (the second-order potential: an inverted double
pendulum when the arm points up).  Damping is modal: every mode keeps its
damping ratio (``zeta1 = 0.09`` from the thesis).

Everything here is pure and broadcasts over configurations (``theta1``,
``theta2``); each configuration is computed by the compiled integrator's own
functions (:mod:`.period_kernel`: ``link_coefficients``, ``eigenvalues``,
``mode_shape``, ``camera_fractions``) run as Python, so the model has one
implementation of its arithmetic.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field

from plant_emulator.model import period_kernel as pk
from plant_emulator.model.kinematics import A1_IN, A2_IN, CYLINDER1, INCH, PAYLOAD_LB, POUND

FloatArray = npt.NDArray[np.float64]

G_M_S2: Final[float] = 9.80665
L1_M: Final[float] = A1_IN * INCH
L2_M: Final[float] = A2_IN * INCH
N_MODES: Final[int] = 2


class Structure(BaseModel):
    """Physical parameters of the flexible structure (calibrated defaults;
    docs/plant-model.md explains each one and how it was fitted)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    link1_mass_lb: float = Field(30.0, gt=0, description="Link 1 (L-shaped aluminium beam with the parallel bar), uniform")
    elbow_mass_lb: float = Field(80.0, ge=0, description="Elbow hardware (joint 2 bearing, crank, link-2 camera) at the elbow")
    link2_mass_lb: float = Field(15.0, gt=0, description="Link 2, uniform")
    tip_mass_lb: float = Field(2.0, ge=0, description="Tip hardware (photodiode, plate mount) without the payload")
    payload_lb: float = Field(PAYLOAD_LB, ge=0, description="The thesis's steel plate at the tip")
    slope_transmission: float = Field(0.0, ge=0, le=1.5, description="kappa: how much link 2's base turns with link 1's flexing")
    link1_root_stiffness_nm_per_rad: float = Field(3.874e5, gt=0, description="k_r1: link 1's bending as a root spring")
    cylinder1_stiffness_n_per_m: float = Field(1.4e7, gt=0, description="k_c1: cylinder 1's oil column (beta A^2 (1/V_a + 1/V_b), 2 in^2, mid-stroke, 1.4 GPa)")
    link2_root_stiffness_nm_per_rad: float = Field(
        1.0e5, gt=0, description="k_r2: link 2's bending as a root spring (sets the share of link 2's deflection its camera sees)"
    )
    bar_stiffness_n_per_m: float = Field(1.794e7, gt=0, description="k_bar: parallel bar (with cylinder 2's oil) along the bar")
    crank_radius_in: float = Field(8.0, gt=0, description="r_c: elbow crank radius of the parallel bar")
    crank_offset_deg: float = Field(-4.0, ge=-9.0, le=59.0, description="beta_c: crank angle past link 2 (dead point at theta2 = -beta_c)")
    damping_ratios: tuple[float, float] = Field((0.09, 0.09), description="Modal damping ratios, mode 1 and 2 (thesis: 0.09 for the first)")
    gravity_m_s2: float = Field(G_M_S2, ge=0, description="Gravity (0 switches it off)")


DEFAULT_STRUCTURE: Final[Structure] = Structure()


@dataclass(frozen=True)
class _Consts:
    """SI constants derived from a :class:`Structure` (payload in or out)."""

    I1: float
    Mt: float
    S: float
    Ia: float
    A1: float
    kappa: float
    kr1: float
    kc1: float
    kr2: float
    kbar_r2: float
    beta_c: float
    g: float
    z1: float
    z2: float


def consts(structure: Structure, payload: bool) -> _Consts:
    m1 = structure.link1_mass_lb * POUND
    me = structure.elbow_mass_lb * POUND
    m2 = structure.link2_mass_lb * POUND
    mt = (structure.tip_mass_lb + (structure.payload_lb if payload else 0.0)) * POUND
    Mt = me + m2 + mt
    return _Consts(
        I1=m1 * L1_M**2 / 3.0,
        Mt=Mt,
        S=m2 * L2_M / 2.0 + mt * L2_M,
        Ia=m2 * L2_M**2 / 3.0 + mt * L2_M**2,
        A1=m1 * L1_M / 2.0 + Mt * L1_M,
        kappa=structure.slope_transmission,
        kr1=structure.link1_root_stiffness_nm_per_rad,
        kc1=structure.cylinder1_stiffness_n_per_m,
        kr2=structure.link2_root_stiffness_nm_per_rad,
        kbar_r2=structure.bar_stiffness_n_per_m * (structure.crank_radius_in * INCH) ** 2,
        beta_c=math.radians(structure.crank_offset_deg),
        g=structure.gravity_m_s2,
        z1=structure.damping_ratios[0],
        z2=structure.damping_ratios[1],
    )


# --- the matrices: the compiled kernel's functions, one configuration at a time ----------


def modal_arguments(k: _Consts, h: float) -> tuple[float, ...]:
    """:func:`~.period_kernel.modal_step`'s 20 constant arguments (after the two
    angles; ``period_kernel.MA_*``) for the structure constants ``k`` and the step ``h``."""
    cyl = CYLINDER1
    pin = (cyl.offset_rad, cyl.p_in * cyl.q_in, cyl.p_in**2 + cyl.q_in**2)
    return (k.I1, k.Mt, k.S, k.Ia, k.A1, k.kappa, k.kr1, k.kc1, k.kr2, k.kbar_r2, k.beta_c, k.g, k.z1, k.z2, h, *pin, INCH, L1_M)


def link_arguments(k: _Consts) -> tuple[float, ...]:
    """:func:`~.period_kernel.link_coefficients`' 17 constant arguments (after the two angles)."""
    ma = modal_arguments(k, 0.0)
    return ma[:12] + ma[15:]


def _on_grid(fn: Callable[[float, float], tuple[float, ...]], theta1: npt.ArrayLike, theta2: npt.ArrayLike) -> list[FloatArray]:
    """``fn(theta1, theta2)`` at every configuration of the broadcast angles: one array per output."""
    t1, t2 = np.broadcast_arrays(np.asarray(theta1, dtype=float), np.asarray(theta2, dtype=float))
    rows = [fn(a, b) for a, b in zip(t1.ravel().tolist(), t2.ravel().tolist(), strict=True)]
    table = np.array(rows, dtype=float).reshape(t1.size, -1)
    return [table[:, i].reshape(t1.shape) for i in range(table.shape[1])]


def coefficients(theta1, theta2, payload=False, structure: Structure = DEFAULT_STRUCTURE):
    """Mass, stiffness (elastic + gravity), input and gravity-load terms at joint angles (rad), broadcast.

    Returns ``(M11, M12, M22, K11, K12, K22, E11, E12, E21, E22, G1, G2)``
    in SI (kg m^2, N m/rad, N m); ``E`` maps joint accelerations (rad/s^2)
    to generalised inertial loads (``f = -E theta''``). Each configuration is
    :func:`~.period_kernel.link_coefficients`, the integrator's own."""
    args = link_arguments(consts(structure, bool(payload)))
    return tuple(_on_grid(lambda a, b: pk.link_coefficients(a, b, *args), theta1, theta2))


def bending_fractions(theta1, theta2, payload=False, structure: Structure = DEFAULT_STRUCTURE) -> FloatArray:
    """Share of each joint chain's rotation that is the link's own bending,
    ``k_i / k_ri``, at joint angles (rad), shape (..., 2).

    The chain of joint ``i`` is the link's root bending ``k_ri`` in series with
    the actuator (cylinder 1's oil column through its lever; the parallel bar
    through the crank); the massless node between them carries the same
    torque, so the link bends by ``k_i beta_i / k_ri`` and the rest is the
    whole link, camera included, turning on the actuator's compliance. Each
    configuration is :func:`~.period_kernel.camera_fractions`, the integrator's own."""
    ma = modal_arguments(consts(structure, bool(payload)), 0.0)
    f1, f2 = _on_grid(lambda a, b: pk.camera_fractions(ma, INCH, a, b), theta1, theta2)
    return np.stack([f1, f2], axis=-1)


def natural_frequencies(args: tuple[float, ...], theta1: float, theta2: float) -> tuple[float, float]:
    """The two modes' natural frequencies (Hz) at one configuration, ascending
    (``args``: :func:`link_arguments`): the ground truth's per-period call."""
    M11, M12, M22, K11, K12, K22 = pk.link_coefficients(theta1, theta2, *args)[:6]
    lam1, lam2 = pk.eigenvalues(M11, M12, M22, K11, K12, K22)
    two_pi = 2.0 * math.pi
    return math.sqrt(lam1 if lam1 > 0.0 else 0.0) / two_pi, math.sqrt(lam2 if lam2 > 0.0 else 0.0) / two_pi


def eig2(M11, M12, M22, K11, K12, K22):
    """Solve ``K phi = w^2 M phi`` for every configuration (arrays):
    :func:`~.period_kernel.eigenvalues` and :func:`~.period_kernel.mode_shape` element by element.

    Returns ``(w2, phi)``: ``w2`` shape (..., 2) ascending, ``phi`` shape
    (..., 2, 2) with mass-normalised columns (``phi^T M phi = I``)."""
    m = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (M11, M12, M22, K11, K12, K22)))
    shape = m[0].shape
    rows = []
    for c in zip(*(x.ravel().tolist() for x in m), strict=True):
        lam1, lam2 = pk.eigenvalues(*c)
        rows.append((lam1, lam2, *pk.mode_shape(lam1, 0, *c), *pk.mode_shape(lam2, 1, *c)))
    t = np.array(rows, dtype=float).reshape(-1, 6)
    w2 = t[:, :2].reshape(*shape, 2)
    phi = np.stack([t[:, [2, 4]], t[:, [3, 5]]], axis=-2).reshape(*shape, 2, 2)  # columns: modes
    return w2, phi


# --- public, vectorised views -------------------------------------------------------------


def modal_parameters(
    theta1: float | npt.ArrayLike,
    theta2: float | npt.ArrayLike,
    payload: bool = False,
    structure: Structure = DEFAULT_STRUCTURE,
) -> tuple[FloatArray, FloatArray]:
    """True natural frequencies (Hz) and damping ratios of the two modes.

    Broadcasts over ``theta1``/``theta2`` (rad); returns arrays of shape
    ``(..., 2)``, modes in ascending frequency."""
    args = link_arguments(consts(structure, bool(payload)))
    f1, f2 = _on_grid(lambda a, b: natural_frequencies(args, a, b), theta1, theta2)
    freqs = np.stack([f1, f2], axis=-1)
    zetas = np.broadcast_to(np.asarray(structure.damping_ratios, dtype=float), freqs.shape).copy()
    return freqs, zetas


def mode_shapes(theta1, theta2, payload: bool = False, structure: Structure = DEFAULT_STRUCTURE) -> FloatArray:
    """Mode shapes as tip deflections (in) per unit modal coordinate, shape
    (..., 2 links, 2 modes), each column scaled to unit largest entry."""
    co = coefficients(theta1, theta2, payload, structure)
    _, phi = eig2(*co[:6])
    defl = phi * np.array([L1_M, L2_M])[:, None] / INCH
    scale = np.max(np.abs(defl), axis=-2, keepdims=True)
    return defl / scale


def static_deflection_in(theta1, theta2, payload: bool = False, structure: Structure = DEFAULT_STRUCTURE, bending_only: bool = False) -> FloatArray:
    """Tip deflections (in) of the two links at rest under gravity, (..., 2);
    ``bending_only``: the part a camera on the link's root sees (:func:`bending_fractions`)."""
    M11, M12, M22, K11, K12, K22, *_, G1, G2 = coefficients(theta1, theta2, payload, structure)
    det = K11 * K22 - K12 * K12
    b1 = (K22 * G1 - K12 * G2) / det
    b2 = (K11 * G2 - K12 * G1) / det
    w = np.stack(np.broadcast_arrays(b1 * L1_M / INCH, b2 * L2_M / INCH), axis=-1)
    return w * bending_fractions(theta1, theta2, payload, structure) if bending_only else w


def frequency_response(
    theta1: float,
    theta2: float,
    freqs_hz: npt.ArrayLike,
    payload: bool = False,
    structure: Structure = DEFAULT_STRUCTURE,
    valve_gain_in_s_per_v: tuple[float, float] = (15.0, 7.0),
    valve_time_constant_s: float = 0.01,
    camera_on_link: bool = True,
) -> npt.NDArray[np.complex128]:
    """Linearised transfer functions from valve volts to the deflections the
    cameras see (in; ``camera_on_link=False``: the whole tip deflections) at one
    configuration, shape (n_freqs, 2 inputs, 2 outputs): ``H[:, i, j]``
    is the thesis's ``H_ij`` (valve ``i`` to the deflection of link ``j``).

    Chain: valve -> lag -> cylinder velocity -> joint rate (``1/lever``) ->
    joint acceleration (``s``) -> flexible links -> deflection (-> bending share)."""
    from plant_emulator.model.kinematics import CYLINDER2

    co = coefficients(theta1, theta2, payload, structure)
    M = np.array([[co[0], co[1]], [co[1], co[2]]], dtype=float)
    K = np.array([[co[3], co[4]], [co[4], co[5]]], dtype=float)
    E = np.array([[co[6], co[7]], [co[8], co[9]]], dtype=float)
    D = damping_matrix(M, K, structure.damping_ratios)
    levers = np.array([float(CYLINDER1.lever_in_per_rad(theta1)), float(CYLINDER2.lever_in_per_rad(theta2))])
    rate_gain = np.asarray(valve_gain_in_s_per_v, dtype=float) / levers  # rad/s per V
    seen = bending_fractions(theta1, theta2, payload, structure) if camera_on_link else np.ones(2)
    out = np.diag([L1_M / INCH * float(seen[0]), L2_M / INCH * float(seen[1])])
    s = 2j * np.pi * np.asarray(freqs_hz, dtype=float)
    H = np.empty((s.size, 2, 2), dtype=complex)
    for n, sn in enumerate(s):
        Z = M * sn * sn + D * sn + K
        # theta'' per volt = s * rate_gain / (tau s + 1)
        acc = np.diag(sn * rate_gain / (valve_time_constant_s * sn + 1.0))
        Hn = out @ np.linalg.solve(Z, -E @ acc)  # rows: link j, columns: valve i
        H[n] = Hn.T
    return H


def damping_matrix(M: FloatArray, K: FloatArray, zetas: tuple[float, float]) -> FloatArray:
    """Modal damping: ``D = M Phi diag(2 zeta w) Phi^T M``."""
    w2, phi = eig2(M[0, 0], M[0, 1], M[1, 1], K[0, 0], K[0, 1], K[1, 1])
    w = np.sqrt(np.maximum(w2, 0.0))
    Z = np.diag(2.0 * np.asarray(zetas) * w)
    return M @ phi @ Z @ phi.T @ M
