"""``rig.stimulus``: profiles given to the one rig API reach the services they drive,
are checked before the run, travel in a spec, and drive the one-process rig as the
co-simulation bit for bit."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from protocol.can_map import DAC12
from workbench.hil import HilRig, RigSettingError, RigSpec
from workbench.stimulus import Stimulus

DSP = {"fft_width": 256}
STEP_V = 2.3


def _run(clock: str, stim: Stimulus) -> object:
    with HilRig(clock=clock, controller={"tf_download_samples": 0}, dsp_settings=DSP, stimulus=stim) as rig:  # type: ignore[arg-type]
        return rig.run(2.0)


def _profiles() -> Stimulus:
    return Stimulus().step("valve.u1", STEP_V, at_s=0.5, for_s=0.5).step("disturbance.link1", 20.0, at_s=1.0, for_s=0.5)


def test_both_sides_reach_their_services_and_the_plant_reports_its_profile() -> None:
    rec = _run("cosim", _profiles())
    assert rec.error is None  # type: ignore[attr-defined]
    c = rec.columns  # type: ignore[attr-defined]
    window = (c["t_s"] >= 0.5 - 1e-9) & (c["t_s"] < 1.0 - 1e-9)
    assert window.sum() == 100
    assert np.all(c["u1_v"][window] == round(STEP_V / DAC12.lsb_v) * DAC12.lsb_v)
    kinds = [(e.kind, e.sim_time_s) for e in rec.events if e.kind.startswith("stimulus")]  # type: ignore[attr-defined]
    assert [k for k, _ in kinds] == ["stimulus_start", "stimulus_end"], kinds


def test_the_fixture_api_adds_profiles_after_construction() -> None:
    with HilRig(controller={"tf_download_samples": 0}, dsp_settings=DSP) as rig:
        rig.stimulus.sine("setpoint.phi1", amplitude=0.01, f_hz=1.0, at_s=0.2)
        rec = rig.run(1.0)
    assert np.any(rec.columns["stim_phi1_rad"] != 0.0)


def test_one_process_lockstep_equals_the_cosimulation_with_a_stimulus() -> None:
    a, b = _run("cosim", _profiles()), _run("lockstep", _profiles())
    for name, column in a.columns.items():  # type: ignore[attr-defined]
        assert np.array_equal(column, b.columns[name], equal_nan=True), name  # type: ignore[attr-defined]


def test_a_spec_carries_its_stimulus() -> None:
    spec = RigSpec("s", duration_s=1.0, controller={"tf_download_samples": 0}, dsp=DSP, stimulus=tuple(Stimulus().step("valve.u2", -1.0, at_s=0.2).profiles))
    spec = pickle.loads(pickle.dumps(spec))
    with HilRig.from_spec(spec) as rig:
        rec = rig.run()
    assert np.all(rec.columns["stim_u2_v"][rec.columns["t_s"] >= 0.2] == -1.0)


@pytest.mark.parametrize(
    ("stim", "says"),
    [
        (Stimulus().step("valve.u9", 1.0), "valve.u9"),
        (Stimulus().step("valve.u1", 50.0), "valve.u1"),
        (Stimulus().step("disturbance.link1", 1.0, at_s=2.0, end_s=1.0), "end_s 1 is not after at_s 2"),
    ],
)
def test_a_bad_profile_is_one_line_before_the_run(stim: Stimulus, says: str) -> None:
    rig = HilRig(stimulus=stim)
    with pytest.raises(RigSettingError) as err:
        rig.run(1.0)
    assert says in str(err.value) and "\n" not in str(err.value)
    assert not rig.started
    rig.close()
