"""The same failure insertion with your own plant as an FMU.

The example two-mode plant (examples/fmu/two_mode_plant, compiled here with
gcc against FMPy's FMI headers) stands behind the node's I/O through its
mapping (examples/fmu/two_mode_plant.yaml, docs/fmu-plant.md). At 4 s of
simulated time its link-1 deflection input (AI3) is shorted to the sensors'
+15 V supply: the converter clips, and the controller's ``range`` monitor
(policy ``stop``) must end the run on the first faulted sample, with no
firing before it. The ``disagree`` check is the built-in arm's gravity sag
(protocol/static_sag.py) and stays off for another plant.
"""

from __future__ import annotations

import shutil

import pytest

pytest.importorskip("fmpy")
if shutil.which("gcc") is None:
    pytest.skip("the example FMU is compiled with gcc", allow_module_level=True)

from plant_emulator.fmu.build import EXAMPLE_MAPPING, EXAMPLE_SOURCE, build_c_fmu  # noqa: E402

SHORT_AT_S = 4.0
TS = 0.005


@pytest.fixture(scope="module")
def example_fmu(tmp_path_factory):
    return build_c_fmu(EXAMPLE_SOURCE, tmp_path_factory.mktemp("fmu") / "two_mode_plant.fmu")


@pytest.mark.rig_settings(controller={"input_monitors": "range=true,rate=true,stuck=true", "policies": "input_range=stop,input_rate=warn,input_stuck=warn"})
def test_fmu_plant_sensor_short_to_supply_is_caught_on_the_first_sample(rig, example_fmu):
    rig.set("plant", model=f"fmu:{example_fmu}", fmu_mapping=str(EXAMPLE_MAPPING))
    rig.fiu.short("AI3", to="supply", at_s=SHORT_AT_S)
    record = rig.run(duration_s=SHORT_AT_S + 1.0)

    assert record.error is not None and "input_range" in record.error and "AI3 at the converter's clip" in record.error
    assert (record.ticks + 1) * TS == pytest.approx(SHORT_AT_S)  # the first sample that carried the short
    counters = record.health["controller"].counters
    assert counters["episodes_input_rate"] == counters["episodes_input_stuck"] == 0  # no firing before the short
    assert [e.kind for e in record.events if e.kind.startswith("channel_fault")] == ["channel_fault"]
