"""The controller's plausibility monitors on its A/D inputs
(controller/input_monitors.py): each fires on the channel fault it is meant
to catch (co-simulated, the fault from the plant's scenario), none fires on
a clean lap of the thesis trajectory, they are off by default, and under
``stop`` the faulted sample never reaches the valves."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from controller.input_monitors import InputMonitorChecks
from controller.monitors import INPUT_MONITORS, Monitors
from protocol.setting_groups import InputMonitors, Policies
from protocol.static_sag import static_sag_in
from workbench.cosim import run_cosim

ALL_ON = "range=true,stuck=true,rate=true,disagree=true"
COUNT = ",".join(f"{name}=count" for name in INPUT_MONITORS)
TS = 0.005


def _run(faults: list[dict[str, Any]], duration_s: float = 4.0, policies: str = COUNT) -> Any:
    return run_cosim(
        controller={"duration_s": duration_s, "input_monitors": ALL_ON, "policies": policies, "tf_download_samples": 0},
        plant={"scenario": {"channel_faults": faults}},
    )


def _first(run: Any, monitor: str) -> int | None:
    inputs = run.controller.inputs
    assert inputs is not None
    return inputs.first_tick(monitor)


def _sample_time(tick: int) -> float:
    """The plant's simulated time of tick ``tick``'s sample (the arm steps, then samples)."""
    return (tick + 1) * TS


def test_the_static_sag_is_the_plant_models_within_a_thousandth_of_an_inch() -> None:
    from plant_emulator.model.arm import default_deflection_zero
    from plant_emulator.model.modes import DEFAULT_STRUCTURE, static_deflection_in

    t1, t2 = np.meshgrid(np.linspace(0.97, 1.73, 23), np.linspace(0.17, 1.32, 23))
    zero = np.array(default_deflection_zero(DEFAULT_STRUCTURE, False, True))
    model = static_deflection_in(t1.ravel(), t2.ravel(), False, DEFAULT_STRUCTURE, bending_only=True) - zero
    ours = np.array([static_sag_in(a, b) for a, b in zip(t1.ravel(), t2.ravel(), strict=True)])
    assert np.ptp(model[:, 0]) > 0.1  # the sag changes along the workspace: the comparison compares something
    assert np.abs(ours - model).max() < 1e-3


def test_off_by_default_and_nothing_counted() -> None:
    assert not InputMonitors().any
    monitors = Monitors(Policies().as_dict())
    assert set(monitors.episodes) == {"deadline", "stale", "dsp_lost", "overrun", "can_conflict"}
    run = run_cosim(
        controller={"duration_s": 0.5, "tf_download_samples": 0},
        plant={"scenario": {"channel_faults": [{"channel": "AI3", "kind": "short_ground", "start_s": 0.1}]}},
    )
    assert run.controller.inputs is None
    assert not any(key.startswith("episodes_input") for key in run.health["controller"].counters)


@pytest.mark.parametrize(
    ("monitor", "fault"),
    [
        ("input_range", {"channel": "AI3", "kind": "short_supply", "start_s": 2.0}),
        ("input_stuck", {"channel": "AI1", "kind": "stuck", "start_s": 2.0}),
        ("input_rate", {"channel": "AI3", "kind": "short_ground", "start_s": 2.0}),
        ("input_disagree", {"channel": "AI4", "kind": "offset", "offset_v": 7.0, "start_s": 2.0}),
    ],
)
def test_each_monitor_fires_on_its_fault_after_the_insertion(monitor: str, fault: dict[str, Any]) -> None:
    run = _run([fault])
    assert run.result.error is None
    inputs = run.controller.inputs
    tick = _first(run, monitor)
    assert tick is not None, inputs.events
    assert _sample_time(tick) >= fault["start_s"] - 1e-9  # nothing before the fault
    assert all(_sample_time(t) >= fault["start_s"] - 1e-9 for t, _, _ in inputs.events)
    assert run.health["controller"].counters[f"episodes_{monitor}"] >= 1
    entry = next(e for e in inputs.events if e[1] == monitor)
    assert entry[2].startswith(f"tick {tick}:") and fault["channel"] in entry[2]


def test_stuck_counts_only_ticks_in_which_the_set_point_moves() -> None:
    monitors = Monitors({"input_stuck": "count"})
    checks = InputMonitorChecks(InputMonitors(stuck=True, stuck_samples=3), monitors, TS)
    row = [0.0] * 25
    for tick in range(10):  # the set-point still: a held code is no fault
        checks.check(tick, row)
    assert not checks.events
    for tick in range(10, 14):
        row[1] = tick * 1e-3  # phi_ref1 moves, the words do not
        checks.check(tick, list(row))
    assert [e[0] for e in checks.events] == [12]  # moved at ticks 10, 11, 12
    assert monitors.episodes["input_stuck"] == 1


@pytest.mark.timeout(300)
def test_no_monitor_fires_on_a_clean_lap_of_the_thesis_trajectory() -> None:
    run = run_cosim(controller={"repeats": 1, "input_monitors": ALL_ON, "policies": COUNT})
    assert run.result.error is None
    assert run.result.ticks > 8000  # the whole lap
    assert run.controller.inputs.events == []
    assert all(run.health["controller"].counters[f"episodes_{name}"] == 0 for name in INPUT_MONITORS)


def test_stop_ends_the_run_before_the_faulted_sample_reaches_the_valves(tmp_path) -> None:
    run = _run([{"channel": "AI3", "kind": "short_ground", "start_s": 2.0}], policies="input_rate=stop")
    assert run.result.error is not None and "input_rate" in run.result.error
    tick = _first(run, "input_rate")
    assert tick is not None
    assert run.result.ticks == tick  # the tick that fired sent no command
    assert run.result.counters["valves_zeroed"] == 1
    columns = run.controller.record.to_columns()
    assert len(columns["t_s"]) == tick
    run.controller.save(str(tmp_path / "run"), run.result)
    import json

    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["metadata"]["input_monitor_events"][0]["tick"] == tick
