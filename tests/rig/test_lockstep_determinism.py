"""Lockstep is a co-simulation master: with the same seed and settings the
run records are bit-identical between two three-process runs, with the host
loaded by one CPU burner per core during one of them, between three
processes and one (workbench.composition), and between three processes and the
direct co-simulation (workbench.cosim). The step boundary is the handshake, so
none of this depends on when messages arrive."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from controller.record import RunRecord, load_record

CONTROLLER = {"duration_s": 16.0, "oatf_mode": "adaptive", "tf_download_samples": 500}
DSP = {"fft_width": 512}
BURN_LIMIT_S = 500
"""A burner ends by itself after this long even if the test could not kill it."""


def _three_processes(tmp: Path, name: str, seed: int) -> Path:
    record = tmp / name / "run"
    record.parent.mkdir(parents=True)
    sets = [f"controller.{k}={v}" for k, v in CONTROLLER.items()] + [f"dsp.{k}={v}" for k, v in DSP.items()]
    sets += [f"controller.run_record={record}", f"plant.truth_record={record}", f"plant.seed={seed}"]
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "workbench",
            "up",
            "--clock",
            "lockstep",
            "--duration",
            "120",
            "--rig-id",
            f"det-{uuid.uuid4().hex[:6]}",
            "--log-dir",
            str(tmp / name / "logs"),
            *[arg for item in sets for arg in ("--set", item)],
        ],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert proc.returncode == 0, proc.stderr + "".join(p.read_text() for p in (tmp / name / "logs").glob("*.log"))
    return record


def _one_process(tmp: Path, name: str, seed: int, controller: dict[str, object] | None = None, common: dict[str, object] | None = None) -> Path:
    from workbench.composition import run_in_process

    record = tmp / name / "run"
    record.parent.mkdir(parents=True)
    run = run_in_process(controller=dict(controller or CONTROLLER), dsp=dict(DSP), plant={"seed": seed, "truth_record": str(record)}, common=common)
    assert run.result.error is None
    run.controller.save(str(record), run.result)
    return record


def _cosim(tmp: Path, name: str, seed: int, controller: dict[str, object] | None = None, common: dict[str, object] | None = None) -> Path:
    from workbench.cosim import run_cosim

    record = tmp / name / "run"
    record.parent.mkdir(parents=True)
    run = run_cosim(controller=dict(controller or CONTROLLER), dsp=dict(DSP), plant={"seed": seed, "truth_record": str(record)}, common=common)
    assert run.result.error is None
    run.controller.save(str(record), run.result)
    return record


@contextmanager
def _burners() -> Iterator[list[subprocess.Popen[bytes]]]:
    """One CPU-burning process per core, each bounded in time, killed by PID on exit."""
    code = f"import time\nend = time.monotonic() + {BURN_LIMIT_S}\nwhile time.monotonic() < end:\n    pass\n"
    procs = [subprocess.Popen([sys.executable, "-c", code]) for _ in range(os.cpu_count() or 2)]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait(timeout=10)


WRITTEN = {"run.npz", "run.json", "run.timing.npz", "run.timing.json", "run.tf.npz", "run.truth.npz"}
"""Every file a lockstep run leaves beside its record (a file not listed fails the comparison: nothing goes uncompared)."""
WALL_CLOCK = {"run.timing.npz": ("sync_wall_s", "tet_s")}
"""Columns that are wall-clock measurements, different in every run by nature (the rest of the file is compared)."""
PER_RUN_CONFIG = {
    *("rig_id", "zenoh_mode", "zenoh_connect", "zenoh_listen", "zenoh_user", "zenoh_password", "zenoh_credentials_file", "zenoh_acl"),
    *("zenoh_tls_ca", "zenoh_tls_certificate", "zenoh_tls_key"),  # fresh per run: the run's own certificates
    *("can_interface", "can_channel", "can_port", "run_record", "launcher_pid"),
}
"""The configuration that says where a run lives and how it is wired (keys, transports, ports, paths, credentials), not what it computes."""


def _npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def _same(a: Path, b: Path) -> None:
    """Every file of run ``a`` equals run ``b``'s: the record's columns, the TF downloads,
    the plant's ground truth, the timing record's ticks and the sidecars' contents."""
    files_a = {p.name for p in a.parent.iterdir() if p.is_file()}
    files_b = {p.name for p in b.parent.iterdir() if p.is_file()}
    assert files_a == files_b == WRITTEN, (files_a, files_b)
    first, second = load_record(a), load_record(b)
    assert len(first) == len(second) == 3200
    counters = (first.metadata["result"]["counters"], second.metadata["result"]["counters"])
    for name in WRITTEN - {"run.json", "run.timing.json"}:
        x, y = _npz(a.parent / name), _npz(b.parent / name)
        assert x.keys() == y.keys(), name
        for key in set(x) - set(WALL_CLOCK.get(name, ())):
            assert np.array_equal(x[key], y[key], equal_nan=True), (name, key, counters)
    assert _npz(a.parent / "run.tf.npz")["sim_time_s"].size >= 5
    assert _npz(a.parent / "run.truth.npz")["sim_time_s"].size >= 300
    for name in ("run.json", "run.timing.json"):
        x, y = (json.loads((r.parent / name).read_text()) for r in (a, b))
        assert {k: v for k, v in x.items() if k not in ("config", "metadata")} == {k: v for k, v in y.items() if k not in ("config", "metadata")}, name
        assert {k: v for k, v in x["config"].items() if k not in PER_RUN_CONFIG} == {k: v for k, v in y["config"].items() if k not in PER_RUN_CONFIG}, name
    result_a, result_b = first.metadata["result"], second.metadata["result"]
    assert (result_a["ticks"], result_a["sim_time_s"], result_a["error"]) == (result_b["ticks"], result_b["sim_time_s"], result_b["error"])


def _worth_comparing(record: RunRecord) -> None:
    # identification and adaptation happened: the runs did something that could differ
    assert np.isfinite(record["f_id_hz"]).any()
    assert np.nanstd(record["oatf_hz"]) > 0


@pytest.mark.timeout(600)
def test_lockstep_records_are_bit_identical_across_runs_load_and_compositions(tmp_path: Path) -> None:
    reference = _three_processes(tmp_path, "a", seed=7)
    _worth_comparing(load_record(reference))
    with _burners() as burners:
        loaded = _three_processes(tmp_path, "loaded", seed=7)
        assert all(p.poll() is None for p in burners)  # the host was loaded for the whole run
    _same(reference, loaded)
    _same(reference, _one_process(tmp_path, "one", seed=7))
    _same(reference, _cosim(tmp_path, "cosim", seed=7))
    # and the seed matters: another seed gives another record
    other = load_record(_cosim(tmp_path, "seed8", seed=8))
    assert not np.array_equal(load_record(reference)["defl1_in"], other["defl1_in"])


@pytest.mark.timeout(600)
def test_a_dithered_cosim_equals_the_dithered_one_process_lockstep_run(tmp_path: Path) -> None:
    """The valve dither (controller/excitation.py) on, with an adaptive inner OATF: the co-simulation and the
    one-process lockstep rig keep the same records bit for bit, and the dither reached the D/A."""
    dithered = {**CONTROLLER, "oatf": "location=inner", "dither": "amplitude_v=0.02"}
    a = _cosim(tmp_path, "cosim", 3, dithered)
    b = _one_process(tmp_path, "one", 3, dithered)
    _same(a, b)
    record = load_record(a)
    _worth_comparing(record)
    plain = load_record(_cosim(tmp_path, "plain", 3, {**CONTROLLER, "oatf": "location=inner"}))
    assert not np.array_equal(record["u1_v"], plain["u1_v"])


@pytest.mark.timeout(600)
def test_on_the_simulated_can_wire_cosim_equals_the_one_process_lockstep_run(tmp_path: Path) -> None:
    """500 kbit/s beside the 50 % restbus of docs/results/can-bus-load.md: the co-simulation and the
    one-process lockstep rig (the wire between two threads, workbench/lockstep_wire.py) keep the same
    records, truth and TF downloads bit for bit, and the wire changed the run (the D/A acts a sub-step later)."""
    root = Path(__file__).resolve().parents[2]
    wire = {"can_bitrate": 500_000, "can_restbus": str(root / "examples" / "restbus" / "vehicle-50pct-500k.dbc")}
    a = _cosim(tmp_path, "cosim", 4, common=wire)
    b = _one_process(tmp_path, "one", 4, common=wire)
    _same(a, b)
    record = load_record(a)
    _worth_comparing(record)
    plain = load_record(_cosim(tmp_path, "plain", 4))
    assert not np.array_equal(record["defl1_in"], plain["defl1_in"])


@pytest.mark.timeout(600)
def test_with_error_frames_on_the_simulated_can_wire_cosim_equals_the_one_process_lockstep_run(tmp_path: Path) -> None:
    """The same wire with a fault scenario's can_errors (docs/can-errors.md): random errors on every node's
    frames, the restbus's included, and the plant's TPDO1 destroyed until the plant goes bus off and
    recovers; every written file of the two rigs the same bit for bit, and the errors changed the run."""
    root = Path(__file__).resolve().parents[2]
    wire = {"can_bitrate": 500_000, "can_restbus": str(root / "examples" / "restbus" / "vehicle-50pct-500k.dbc")}
    scenario = {
        "seed": 11,
        "can_errors": [
            {"identifier": "all", "probability": 0.05, "from_s": 2.0, "to_s": 6.0, "echo_bits": 3},
            {"identifier": 0x181, "from_s": 8.0, "to_s": 8.02},
        ],
    }
    errored = {**CONTROLLER, "fault_scenario": json.dumps(scenario)}
    a = _cosim(tmp_path, "cosim", 4, errored, common=wire)
    b = _one_process(tmp_path, "one", 4, errored, common=wire)
    _same(a, b)
    record = load_record(a)
    _worth_comparing(record)
    counters = record.metadata["result"]["counters"]
    assert counters["plant_can_error_passive"] >= 1 and counters["plant_can_bus_off_recoveries"] == 1
    plain = load_record(_cosim(tmp_path, "plain", 4, common=wire))
    assert not np.array_equal(record["defl1_in"], plain["defl1_in"])
