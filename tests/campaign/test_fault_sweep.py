"""A channel fault's kind, channel or size as a sweep's axis
(workbench/campaign/spec.py ``fault``): each run gets its fault in the
plant's scenario, checked as the plant checks it, and with the input
monitors on the row says when each fired."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from controller.monitors import INPUT_MONITORS
from workbench.campaign import Engine, SweepSpec, run_sweep
from workbench.campaign.spec import SpecError, expand

pytestmark = pytest.mark.timeout(240)

BASE = {
    "controller.duration_s": 2.0,
    "controller.tf_download_samples": 0,
    "controller.input_monitors": "range=true,rate=true",
    "controller.policies": ",".join(f"{m}=count" for m in INPUT_MONITORS),
    "fault": {"channel": "AI3", "start_s": 1.0},
}


@pytest.fixture(scope="module")
def engine() -> Iterator[Engine]:
    with Engine.local(1) as eng:
        yield eng


def test_fault_fields_merge_into_the_plants_scenario_and_the_run_key() -> None:
    runs = expand(SweepSpec(base={**BASE, "plant.scenario": json.dumps([{"kind": "seed", "seed": 3}])}, grid={"fault.kind": ["short_ground", "stuck"]}))
    assert [r.axes for r in runs] == [{"fault.kind": "short_ground"}, {"fault.kind": "stuck"}]
    scenarios = [json.loads(r.settings["plant"]["scenario"]) for r in runs]
    assert scenarios[0] == {"commands": [{"kind": "seed", "seed": 3}], "channel_faults": [{"channel": "AI3", "kind": "short_ground", "start_s": 1.0}]}
    assert scenarios[1]["channel_faults"][0]["kind"] == "stuck"
    assert runs[0].key != runs[1].key
    bundles = expand(SweepSpec(base=BASE, grid={"fault": [{"kind": "offset", "offset_v": 1.0, "label": "offset 1 V"}, {"kind": "gain", "factor": 2.0}]}))
    assert [r.axes["fault"] for r in bundles] == ["offset 1 V", '{"factor": 2.0, "kind": "gain"}']
    assert json.loads(bundles[0].settings["plant"]["scenario"])["channel_faults"] == [{"channel": "AI3", "kind": "offset", "start_s": 1.0, "offset_v": 1.0}]


@pytest.mark.parametrize(
    ("grid", "expected"),
    [
        ({"fault.kind": ["noise"], "fault.channel": ["AO1"]}, "fault: noise on AO1: 'noise' is not a fault of a D/A output (AO1)"),
        ({"fault.kind": ["offset"]}, "fault: offset on AI3: a fault of kind 'offset' needs offset_v"),
        ({"fault.end_s": [0.5], "fault.kind": ["stuck"]}, "fault: stuck on AI3: end_s 0.5 is not after start_s 1.0"),
        ({"fault.start_s": [2.0]}, "fault {'channel': 'AI3', 'start_s': 2.0}: needs channel and kind"),
    ],
)
def test_a_bad_fault_fails_the_spec_in_one_line(grid: dict[str, list[object]], expected: str) -> None:
    with pytest.raises(SpecError) as err:
        expand(SweepSpec(base=BASE, grid=grid))
    assert str(err.value).startswith(expected) and "\n" not in str(err.value)


def test_a_fault_kind_sweep_says_when_each_monitor_fired(engine: Engine, tmp_path: Path) -> None:
    res = run_sweep(SweepSpec(name="faults", base=BASE, grid={"fault.kind": ["short_ground", "short_supply"]}), tmp_path, engine, show_progress=False)
    rows = {r["fault.kind"]: r for r in res.rows}
    assert all(r["status"] == "ok" for r in rows.values())
    ground, supply = rows["short_ground"], rows["short_supply"]
    assert supply["input_range_first_s"] == pytest.approx(1.0) and supply["input_range_episodes"] == 1
    assert math.isnan(ground["input_range_first_s"]) and ground["input_range_episodes"] == 0  # 0 V is inside the sensor's range
    assert ground["input_rate_first_s"] == pytest.approx(1.0)
    assert math.isnan(ground["input_disagree_first_s"])  # off in this sweep
