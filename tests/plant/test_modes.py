"""The modal map meets the thesis's facts (§3 "Dynamics")."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from plant_emulator.model import kinematics as kin
from plant_emulator.model import modes, period_kernel
from plant_emulator.model.calibration import APEX_RAD, BOTTOM_RAD, metrics
from tests.plant.link_matrices import link_matrices


@pytest.fixture(scope="module")
def loop() -> kin.TrajectorySamples:
    return kin.sample_trajectory(dt_s=0.005)  # 200 Hz, 5 in/s, pauses included


def test_mean_first_mode_over_the_loop(loop: kin.TrajectorySamples) -> None:
    f, _ = modes.modal_parameters(loop.theta1_rad, loop.theta2_rad, payload=False)
    fp, _ = modes.modal_parameters(loop.theta1_rad, loop.theta2_rad, payload=True)
    assert f[:, 0].mean() == pytest.approx(4.4, abs=0.2)
    assert fp[:, 0].mean() == pytest.approx(3.6, abs=0.2)
    # the payload lowers both modes everywhere on the loop
    assert np.all(fp < f)


def test_first_mode_varies_about_fifty_percent_over_the_workspace() -> None:
    g1, g2 = kin.workspace_grid(41, 111)
    f1 = modes.modal_parameters(g1, g2)[0][:, 0]
    variation = (f1.max() - f1.min()) / f1.mean()
    assert 0.35 <= variation <= 0.65
    # lowest at the stretched-out top, not on an arbitrary edge
    assert math.degrees(g2[np.argmin(f1)]) < 15.0


def test_modes_approach_and_split_near_the_top(loop: kin.TrajectorySamples) -> None:
    f_apex = modes.modal_parameters(*APEX_RAD)[0]
    f_bottom = modes.modal_parameters(*BOTTOM_RAD)[0]
    assert f_apex[1] / f_apex[0] < 1.5  # close together at the apex
    assert f_bottom[1] / f_bottom[0] > 1.8  # well apart at the bottom of the loop
    # approach: along the loop's radial first section (bottom-right corner up to
    # the apex) the gap shrinks steadily as theta2 falls towards the singularity
    first = (loop.t_s > 3.0) & (loop.t_s < 3.0 + 40.0 / 5.0)
    f, _ = modes.modal_parameters(loop.theta1_rad[first], loop.theta2_rad[first])
    ratio = f[:, 1] / f[:, 0]
    assert ratio[-1] < ratio[0] - 0.4
    n = int(0.9 * ratio.size)  # the closest approach sits within a degree of the apex
    # never rising by more than 0.5 % on the way up (with the crank 4 degrees past link 2 the
    # ratio stays flat, within 0.2 %, over the section's lower quarter), then falling steadily
    assert ratio[:n].max() < 1.005 * ratio[0]
    q = ratio.size // 4
    assert np.all(np.diff(ratio[q:n]) < 0.0)
    assert np.argmin(ratio) >= n
    # ... the closest approach on the whole loop is at its top
    fl, _ = modes.modal_parameters(loop.theta1_rad, loop.theta2_rad)
    r_all = fl[:, 1] / fl[:, 0]
    assert math.degrees(loop.theta2_rad[np.argmin(r_all)]) < 20.0
    # split: two distinct peaks (not one), each visible on both links
    assert f_apex[1] / f_apex[0] > 1.2
    shapes = modes.mode_shapes(*APEX_RAD)
    assert np.all(np.abs(shapes) > 0.1)
    # and it is a veering, not a crossing: beyond the apex (theta2 -> 10 deg)
    # the lower mode keeps falling while the upper stays near the old first mode
    f_top = modes.modal_parameters(APEX_RAD[0], math.radians(10.0))[0]
    assert f_top[0] < f_apex[0] and f_top[1] / f_top[0] > f_apex[1] / f_apex[0]


def test_first_mode_damping_is_the_thesis_value() -> None:
    _, z = modes.modal_parameters(np.radians([60, 80, 100]), np.radians([10, 60, 120]))
    assert np.allclose(z[:, 0], 0.09)
    assert np.all((z[:, 1] > 0) & (z[:, 1] < 0.2))


def test_link_matrices_are_the_models_equations() -> None:
    """The integrator's coefficients equal the mass, stiffness, input and gravity terms
    written out from the model's equations (tests/plant/link_matrices.py), to rounding."""
    g1, g2 = kin.workspace_grid(9, 12)
    for structure in (modes.DEFAULT_STRUCTURE, modes.Structure(slope_transmission=0.7, crank_offset_deg=12.0)):
        for payload in (False, True):
            co = modes.coefficients(g1, g2, payload, structure)
            for n in range(0, g1.size, 5):
                M, K, E, G = link_matrices(structure, payload, float(g1[n]), float(g2[n]))
                got = [c[n] for c in co]
                np.testing.assert_allclose(got[:3], [M[0, 0], M[0, 1], M[1, 1]], rtol=1e-12)
                np.testing.assert_allclose(got[3:6], [K[0, 0], K[0, 1], K[1, 1]], rtol=1e-12, atol=1e-9 * K[0, 0])
                np.testing.assert_allclose(got[6:10], E.ravel(), rtol=1e-12)
                np.testing.assert_allclose(got[10:], G, rtol=1e-12, atol=1e-12 * abs(G).max())


def test_closed_form_eigen_solution_matches_scipy() -> None:
    g1, g2 = kin.workspace_grid(9, 12)
    for payload in (False, True):
        f, _ = modes.modal_parameters(g1, g2, payload)
        k = modes.consts(modes.DEFAULT_STRUCTURE, payload)
        for n in range(0, g1.size, 7):
            M, K, _, _ = link_matrices(modes.DEFAULT_STRUCTURE, payload, float(g1[n]), float(g2[n]))
            ref = scipy.linalg.eigh(K, M, eigvals_only=True)
            np.testing.assert_allclose(f[n], np.sqrt(ref) / (2.0 * np.pi), rtol=1e-10)
            w2, phi = modes.eig2(M[0, 0], M[0, 1], M[1, 1], K[0, 0], K[0, 1], K[1, 1])
            assert np.allclose(w2, ref, rtol=1e-10)
            assert np.allclose(phi.T @ M @ phi, np.eye(2), atol=1e-10)
            assert np.allclose(K @ phi, M @ phi * w2, rtol=1e-8, atol=1e-6)
            # the period kernel's modal data: the same eigenvalues, M-orthonormal mode shapes
            r = period_kernel.modal_step(float(g1[n]), float(g2[n]), *modes.modal_arguments(k, 1e-3))
            assert (r[16], r[20]) == pytest.approx(tuple(ref), rel=1e-10)
            shapes = np.array([[r[12], r[14]], [r[13], r[15]]])
            assert np.allclose(shapes.T @ M @ shapes, np.eye(2), atol=1e-10)
            assert np.allclose(K @ shapes, M @ shapes * ref, rtol=1e-8, atol=1e-6)


def test_static_deflection_is_a_few_millimetres(loop: kin.TrajectorySamples) -> None:
    mm = np.abs(modes.static_deflection_in(loop.theta1_rad, loop.theta2_rad)) * 25.4
    larger = mm.max(axis=1)
    assert larger.min() > 1.0 and larger.max() < 10.0
    assert 2.0 < np.median(larger) < 8.0
    g1, g2 = kin.workspace_grid(21, 56)
    ws = np.abs(modes.static_deflection_in(g1, g2)).max(axis=1) * 25.4
    # off the loop, at the stretched top corners (theta2 -> 10 deg, near the bar's dead point
    # at theta2 = 4 deg) the sag grows to ~18 mm
    assert ws.min() > 1.0 and ws.max() < 20.0
    # with the payload it sags more; relative to the sensors' default zero
    # (the middle of the loop's static range) it stays well inside their
    # ranges (+-0.575 in, +-0.555 in), even when the payload comes or goes
    # after the zero was set
    from plant_emulator.model.arm import default_deflection_zero

    mp = modes.static_deflection_in(loop.theta1_rad, loop.theta2_rad, payload=True)
    assert np.all(np.abs(mp).max(axis=1) > larger / 25.4)
    for zero_payload in (False, True):
        zero = np.array(default_deflection_zero(modes.DEFAULT_STRUCTURE, zero_payload))
        for p in (False, True):
            rel = np.abs(modes.static_deflection_in(loop.theta1_rad, loop.theta2_rad, payload=p) - zero)
            margin = 0.25 if p == zero_payload else 0.1
            assert np.all(rel[:, 0] < 0.575 - margin) and np.all(rel[:, 1] < 0.555 - margin)


def test_gravity_stiffness_is_physical_but_small() -> None:
    """An upright link is an inverted pendulum on its spring: gravity lowers
    the frequencies, a little (a 4 Hz structure, g/L ~ (0.3 Hz)^2)."""
    t = (math.radians(90.0), math.radians(10.0))
    f = modes.modal_parameters(*t)[0]
    f0 = modes.modal_parameters(*t, structure=modes.DEFAULT_STRUCTURE.model_copy(update={"gravity_m_s2": 0.0}))[0]
    assert np.all(f < f0) and np.all(f > 0.97 * f0)


def test_frequency_response_peaks_at_the_modes() -> None:
    th = (math.radians(85.0), math.radians(25.0))
    f_modes = modes.modal_parameters(*th)[0]
    fr = np.linspace(1.0, 12.0, 4401)
    H = modes.frequency_response(*th, fr)
    assert H.shape == (fr.size, 2, 2)
    assert np.all(np.abs(H).max(axis=0) > 0.05 * np.abs(H).max())  # a true 2x2 plant
    mag = np.abs(H[:, 0, 0])
    peaks = [i for i in range(1, fr.size - 1) if mag[i] > mag[i - 1] and mag[i] > mag[i + 1]]
    assert fr[peaks[0]] == pytest.approx(f_modes[0], rel=0.02)
    mag2 = np.abs(H[:, 1, 1])
    assert fr[np.argmax(mag2)] == pytest.approx(f_modes[1], rel=0.02)


def test_calibration_report_is_consistent() -> None:
    m = metrics(dt_s=0.05)
    assert m.mean_f1_hz == pytest.approx(4.4, abs=0.05)
    assert m.mean_f1_payload_hz == pytest.approx(3.6, abs=0.05)
    assert m.apex_ratio < m.bottom_ratio


def test_free_vibration_shows_the_modal_frequency_and_damping() -> None:
    """Ring the arm (a short valve pulse, no noise) and fit the decay of the
    link-1 deflection: frequency and damping of the true first mode."""
    import scipy.optimize

    from plant_emulator.model import PlantConfig, RalfArm

    arm = RalfArm(PlantConfig(sensor_noise=False, home_theta_rad=BOTTOM_RAD))
    f_true, z_true = arm.truth().modal_frequencies_hz, arm.truth().damping_ratios
    arm.set_valve_voltages(np.array([2.0, 0.0]))
    arm.advance(0.02)
    arm.set_valve_voltages(np.array([0.0, 0.0]))
    arm.advance(0.2)
    t, w = [], []
    for _ in range(400):
        arm.advance(0.005)
        tr = arm.truth()
        t.append(tr.time_s)
        w.append(tr.deflections_in[0] - tr.static_deflections_in[0])
    ta, wa = np.array(t) - t[0], np.array(w)

    def model(tt, *p):  # type: ignore[no-untyped-def]
        out = np.zeros_like(tt)
        for k in range(2):
            a, b, f, z = p[4 * k : 4 * k + 4]
            wn = 2 * np.pi * f
            wd = wn * np.sqrt(1 - z * z)
            out += np.exp(-z * wn * tt) * (a * np.cos(wd * tt) + b * np.sin(wd * tt))
        return out

    p0 = [wa[0], 0.0, f_true[0] * 1.05, 0.07, 0.0, 0.0, f_true[1] * 0.95, 0.07]
    p, _ = scipy.optimize.curve_fit(model, ta, wa, p0=p0, maxfev=20000)
    assert p[2] == pytest.approx(f_true[0], rel=0.01)
    assert p[3] == pytest.approx(z_true[0], rel=0.05)
    assert p[3] == pytest.approx(0.09, abs=0.01)
