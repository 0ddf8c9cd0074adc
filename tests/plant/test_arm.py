"""The integrated plant: equilibrium start, determinism, advance(dt), payload, truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from plant_emulator.model import GroundTruth, PlantConfig, RalfArm
from plant_emulator.model import kinematics as kin
from plant_emulator.model.arm import default_deflection_zero
from plant_emulator.model.modes import static_deflection_in


def _drive(arm: RalfArm, seconds: float, seed: int = 11) -> tuple[np.ndarray, list[GroundTruth]]:
    """A fixed pseudo-random valve sequence at 200 Hz; returns codes and truths."""
    rng = np.random.default_rng(seed)
    codes, truths = [], []
    for _ in range(int(round(seconds * 200))):
        arm.set_valve_voltages(0.3 * rng.standard_normal(2))
        arm.advance(0.005)
        codes.append(arm.sample().codes)
        truths.append(arm.truth())
    return np.array(codes), truths


def test_starts_at_rest_in_static_equilibrium() -> None:
    arm = RalfArm(PlantConfig(sensor_noise=False))
    t0 = arm.truth()
    assert t0.deflections_in == pytest.approx(t0.static_deflections_in, abs=1e-12)
    zero = default_deflection_zero(arm.cfg.structure, False)  # the sensors' zero: mid-range of the loop's sag
    # the cameras see the links' bending (a share of the tip deflection), relative to their zero
    cam = t0.camera_deflections_in
    assert 0.0 < cam[0] / t0.deflections_in[0] <= 1.0 and 0.0 < cam[1] / t0.deflections_in[1] <= 1.0
    assert t0.sensed_deflections_in == pytest.approx((cam[0] - zero[0], cam[1] - zero[1]), abs=1e-12)
    arm.advance(2.0)
    t1 = arm.truth()
    assert t1.time_s == 2.0
    assert t1.deflections_in == pytest.approx(t0.deflections_in, abs=1e-12)
    assert max(abs(x) for x in t1.deflection_rates_in_s) < 1e-12
    assert t1.theta_rad == t0.theta_rad
    r = arm.sample()
    assert r.values_in[2:] == pytest.approx(t1.sensed_deflections_in, abs=1.5e-4)  # half an LSB
    quiet = RalfArm(PlantConfig(sensor_noise=False, deflection_zero_in=t0.camera_deflections_in))
    assert np.array_equal(quiet.sample().codes[2:], [0, 0])


def test_same_seed_same_commands_bit_identical() -> None:
    a = RalfArm(PlantConfig(seed=5))
    b = RalfArm(PlantConfig(seed=5))
    ca, ta = _drive(a, 3.0)
    cb, tb = _drive(b, 3.0)
    assert np.array_equal(ca, cb)
    assert all(x == y for x, y in zip(ta, tb, strict=True))
    assert json.dumps(ta[-1].as_dict()) == json.dumps(tb[-1].as_dict())


def test_another_seed_changes_the_noise_only() -> None:
    a = RalfArm(PlantConfig(seed=5))
    c = RalfArm(PlantConfig(seed=6))
    ca, ta = _drive(a, 2.0)
    cc, tc = _drive(c, 2.0)
    assert not np.array_equal(ca, cc)
    # open loop, the noise does not feed back: the dynamics are identical
    assert ta[-1].deflections_in == tc[-1].deflections_in
    assert ta[-1].sensed_deflections_in != tc[-1].sensed_deflections_in
    # reseeding restarts the generators exactly
    d = RalfArm(PlantConfig(seed=6))
    e = RalfArm(PlantConfig(seed=99))
    e.reseed(6)
    assert np.array_equal(_drive(d, 0.5)[0], _drive(e, 0.5)[0])


def test_advance_in_pieces_equals_one_advance() -> None:
    a = RalfArm(PlantConfig(seed=1))
    b = RalfArm(PlantConfig(seed=1))
    for arm in (a, b):
        arm.set_valve_voltages(np.array([0.4, -0.25]))
    a.advance(0.1)
    for piece in (0.0003, 0.0, 0.0017, 0.004, 0.0005, 0.0935):  # 0.1 s in uneven pieces
        b.advance(piece)
    assert a.time_s == b.time_s == pytest.approx(0.1, abs=1e-12)
    assert a.truth() == b.truth()
    assert np.array_equal(a.sample().codes, b.sample().codes)
    # a remainder below one internal step is carried, not lost or rounded
    a.advance(0.0004)
    a.advance(0.0004)
    assert a.truth().time_s == pytest.approx(0.1008)
    assert a.truth().extensions_in == b.truth().extensions_in  # still on the same grid point
    a.advance(0.0002)
    b.advance(0.001)
    assert a.truth() == b.truth()


def test_advance_rejects_bad_dt() -> None:
    arm = RalfArm()
    for bad in (-0.001, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            arm.advance(bad)
    arm.advance(0.0)
    assert arm.time_s == 0.0


def test_payload_attach_is_a_discontinuous_change() -> None:
    arm = RalfArm(PlantConfig(sensor_noise=False))
    before = arm.truth()
    arm.attach_payload(True)
    after = arm.truth()
    assert after.payload_attached and not before.payload_attached
    assert all(fa < fb for fa, fb in zip(after.modal_frequencies_hz, before.modal_frequencies_hz, strict=True))
    assert after.deflections_in == before.deflections_in  # positions are continuous ...
    assert after.static_deflections_in != before.static_deflections_in  # ... the equilibrium jumps
    arm.advance(0.05)
    assert max(abs(x) for x in arm.truth().deflection_rates_in_s) > 1e-3  # and the arm rings
    arm.advance(20.0)  # 0.09 damping: settled on the new equilibrium
    t = arm.truth()
    assert t.deflections_in == pytest.approx(t.static_deflections_in, abs=1e-6)
    th = kin.home_theta()
    assert np.allclose(t.deflections_in, static_deflection_in(*th, payload=True), atol=1e-6)
    arm.attach_payload(False)
    assert arm.truth().modal_frequencies_hz == pytest.approx(before.modal_frequencies_hz)


def test_truth_is_consistent_and_plain() -> None:
    arm = RalfArm(PlantConfig(seed=2))
    arm.set_valve_voltages(np.array([0.3, 0.2]))
    arm.advance(1.0)
    t = arm.truth()
    t1, t2 = t.theta_rad
    assert t.phi_rad == pytest.approx((t1 - kin.DELTA_RAD, t2 + kin.DELTA_RAD))
    assert t.extensions_in == pytest.approx((kin.CYLINDER1.extension(t1), kin.CYLINDER2.extension(t2)), abs=1e-12)
    assert t.theta_dot_rad_s[0] == pytest.approx(t.cylinder_velocities_in_s[0] / kin.CYLINDER1.lever_in_per_rad(t1))
    # the true tip is the rigid tip moved by the deflections (small angles)
    dx, dy = t.tip_in[0] - t.rigid_tip_in[0], t.tip_in[1] - t.rigid_tip_in[1]
    assert 0.0 < math.hypot(dx, dy) < 1.0
    assert len(t.modal_frequencies_hz) == len(t.damping_ratios) == 2
    d = t.as_dict()
    json.dumps(d)
    assert set(d) >= {
        "modal_frequencies_hz",
        "damping_ratios",
        "deflections_in",
        "theta_rad",
        "phi_rad",
        "extensions_in",
        "tip_in",
        "payload_attached",
        "hard_stop_events",
        "hard_stop_count",
    }


def test_service_facing_construction() -> None:
    """The plant service builds the arm from its settings like this."""
    arm = RalfArm(PlantConfig(seed=3, payload_attached=True, valve_time_constant_s=0.01, adc_bits=16))
    r = arm.sample()
    assert r.codes.shape == (4,) and r.saturated.shape == (4,) and r.volts.shape == (4,)
    assert r.codes.dtype == np.int64 and r.saturated.dtype == np.bool_
    assert r.bits == 16 and isinstance(arm.hard_stop_count, int)
    assert arm.truth().payload_attached
    with pytest.raises(ValueError):
        PlantConfig(home_theta_rad=(0.5, 0.5))
