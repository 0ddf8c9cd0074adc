"""The co-simulation's floor (the models alone, replayed) and the runs-per-second
item: they run, measure something non-empty, and the replay takes each model
through the run's own states (no timed assertions)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from workbench.bench.entries import BenchContext, new_result
from workbench.bench.model_floor import CallLog, Recorded, floor_report, fmpy_inputs, record_run
from workbench.bench.run_rate import one_run


@pytest.fixture(scope="module")
def recorded() -> Recorded:
    return record_run({"duration_s": 2.0})


def test_the_record_holds_every_tick_of_every_model(recorded: Recorded) -> None:
    rec = recorded
    ticks = rec.ticks
    assert ticks == 400
    assert rec.plant.count("advance") == ticks  # one sample period a SYNC
    assert rec.law.count("tick_compiled") == ticks
    assert rec.dsp.count("process") > 0


def test_the_replayed_plant_ends_where_the_run_did(recorded: Recorded) -> None:
    """A fresh model fed the recorded calls returns the A/D codes the run's controller recorded, tick by tick."""
    from plant_emulator.plant_factory import build_plant_model
    from workbench.cosim import run_cosim

    rec = recorded
    model = build_plant_model(rec.settings[1])
    codes = []
    try:
        for name, args, kwargs in rec.plant.calls:
            out = getattr(model, name)(*args, **kwargs)
            if name == "sample_codes":
                codes.append(list(out[0]))
    finally:
        model.close()
    run = run_cosim(controller={"duration_s": 2.0})
    record: Any = run.controller.record
    words = np.column_stack([record.column(f"ai{i}_word") for i in (1, 2, 3, 4)]).astype(np.int64)
    np.testing.assert_array_equal(np.array(codes, dtype=np.int64) << 4, words)


def test_a_nested_call_is_recorded_once() -> None:
    class Thing:
        def outer(self, x: int) -> int:
            return self.inner(x) + 1

        def inner(self, x: int) -> int:
            return x * 2

    log = CallLog()
    thing = log.wrap(Thing(), ("outer", "inner"))
    assert thing.outer(3) == 7 and thing.inner(1) == 2
    assert [name for name, _, _ in log.calls] == ["outer", "inner"]


def test_the_floor_report_computes_its_ratio_over_a_measurement() -> None:
    out = floor_report({"duration_s": 1.0}, rounds=1)
    assert out["ticks"] == 200 and out["calls"]["plant"] > 0 and out["calls"]["law"] > 0
    for key in ("cosim_us", "plant_us", "law_us", "dsp_us"):
        assert out[key] > 0 and len(out["rounds"][key]) == 1
    assert math.isclose(out["models_us"], out["plant_us"] + out["law_us"] + out["dsp_us"])
    assert math.isclose(out["ratio"], out["cosim_us"] / out["models_us"])


def test_the_input_table_holds_the_valves_as_fmpy_reads_it(recorded: Recorded) -> None:
    table, stop = fmpy_inputs(recorded)
    assert table.dtype.names == ("time", "u1", "u2")
    assert math.isclose(stop, 2.0)
    assert (np.diff(table["time"]) >= 0).all() and len(table) > 10  # steps: each change a repeated time
    assert np.abs(table["u1"]).max() > 0.0


def test_one_run_reports_its_times() -> None:
    out = one_run(3, 0.5)
    assert out["ticks"] == 100 and out["failed"] == 0.0
    assert out["wall_s"] >= out["loop_s"] > 0


def test_the_cosim_item_carries_the_floor(monkeypatch: pytest.MonkeyPatch) -> None:
    """bench_cosim with tiny runs: the floor's measurement is present and has its ratio."""
    from workbench.bench import cosim_parts, items, model_floor

    real_floor, real_parts = model_floor.floor_report, cosim_parts.cosim_parts
    monkeypatch.setattr(model_floor, "floor_report", lambda controller, rounds=1: real_floor({"duration_s": 0.5}, rounds=1))
    monkeypatch.setattr(cosim_parts, "cosim_parts", lambda sim_s=1.0, controller=None: real_parts(0.5, controller))
    result = new_result()
    ctx = BenchContext(quick=True)
    items._cosim_floor(ctx, result["measurements"], 0.5)
    entry = result["measurements"]["cosim per tick vs the models alone"]
    assert entry["floor_value"] > 0 and entry["ratio"] == pytest.approx(entry["value"] / entry["floor_value"])


def test_compare_refuses_a_folder_without_sources(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from workbench.cli import build_parser

    args = build_parser().parse_args(["measure", "cosim-parts", "--compare", str(tmp_path)])
    assert args.func(args) == 2
    err = capsys.readouterr().err
    assert "holds no ralf-hil source tree" in err and "Traceback" not in err


def test_the_table_lists_every_part_of_both_trees() -> None:
    """markdown() over two measured parts runs: a row per part, the totals and the calls."""
    from workbench.bench.cosim_parts import _median_parts, cosim_parts, markdown

    runs = []
    for _ in range(2):
        out = cosim_parts(0.5)
        out["calls_per_tick"] = 100.0
        runs.append(out)
    result = {
        "date": "d",
        "machine": {"cpu_model": "cpu", "cpus": 2},
        "load_before": (1.0, 1.0, 1.0),
        "load_after": (1.0, 1.0, 1.0),
        "sim_s": 0.5,
        "rounds": 1,
        "before": _median_parts(runs[:1]),
        "after": _median_parts(runs[1:]),
        "after_profile": [["f", 1.0, 2.0]],
    }
    text = markdown(result, "cmd")
    for name in runs[1]["parts_us_per_tick"]:
        assert f"| {name} |" in text
    assert "| Python function calls per tick | 100.0 | 100.0 | 1.00 |" in text and "| `f` | 1.0 | 2.00 |" in text
