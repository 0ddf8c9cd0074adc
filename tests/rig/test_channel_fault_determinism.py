"""A fault schedule keeps lockstep a co-simulation master: two co-simulations
and the one-process lockstep rig (plant, controller and DSP as threads over a
virtual CAN bus and zenoh) with the same channel faults give bit-identical
run records, the input monitors' firings included."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller.record import load_record

FAULTS = [
    {"channel": "AI3", "kind": "short_ground", "start_s": 1.0, "end_s": 1.5},
    {"channel": "AI4", "kind": "noise", "sigma_v": 0.2, "seed": 7, "start_s": 2.0, "end_s": 3.0},
    {"channel": "AI1", "kind": "drift", "rate_v_s": 0.5, "start_s": 2.5},
    {"channel": "AO2", "kind": "delay", "samples": 3, "start_s": 0.5},
]
CONTROLLER = {
    "duration_s": 4.0,
    "tf_download_samples": 0,
    "input_monitors": "range=true,stuck=true,rate=true,disagree=true",
    "policies": "input_range=count,input_stuck=count,input_rate=count,input_disagree=count",
}
PLANT = {"scenario": {"channel_faults": FAULTS}}


def _save(run: Any, path: Path) -> tuple[Path, list[tuple[int, str, str]]]:
    assert run.result.error is None
    path.parent.mkdir(parents=True, exist_ok=True)
    run.controller.save(str(path), run.result)
    return path, list(run.controller.inputs.events)


def _same(a: Path, b: Path) -> None:
    first, second = load_record(a), load_record(b)
    assert len(first) == len(second) == 800
    for name in first.columns:
        assert np.array_equal(first[name], second[name], equal_nan=True), name


@pytest.mark.timeout(300)
def test_a_fault_schedule_gives_the_same_bits_in_cosim_run_to_run_and_in_the_lockstep_rig(tmp_path: Path) -> None:
    from workbench.composition import run_in_process
    from workbench.cosim import run_cosim

    a, events_a = _save(run_cosim(controller=dict(CONTROLLER), plant=dict(PLANT)), tmp_path / "a" / "run")
    b, events_b = _save(run_cosim(controller=dict(CONTROLLER), plant=dict(PLANT)), tmp_path / "b" / "run")
    c, events_c = _save(run_in_process(controller=dict(CONTROLLER), plant=dict(PLANT)), tmp_path / "lockstep" / "run")
    _same(a, b)
    _same(a, c)
    assert events_a == events_b == events_c
    assert "input_rate" in {m for _, m, _ in events_a}  # the faults acted: the runs did work that could differ
    clean = load_record(_save(run_cosim(controller=dict(CONTROLLER)), tmp_path / "clean" / "run")[0])
    assert not np.array_equal(load_record(a)["ai3_word"], clean["ai3_word"])
