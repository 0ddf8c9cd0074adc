"""The engine and sweeps on a real Dask cluster: an embedded LocalCluster of two worker processes, and a
``dask scheduler`` with two ``dask worker`` processes started here on 127.0.0.1 (ended by PID).

Every rig run is the one-process lockstep rig (python-can ``virtual`` bus, an in-process
zenoh session): nothing leaves the process, so no network namespace is needed.
"""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from workbench.campaign import Engine, SweepSpec, run_sweep
from workbench.campaign.engine import current_engine, use_engine
from workbench.campaign.table import Journal

pytestmark = pytest.mark.timeout(240)

ROOT = Path(__file__).resolve().parents[2]
TIMING = {"run_s", "round_trip_s", "finished_utc", "worker", "wall_s", "realtime_factor"}


@pytest.fixture(scope="module")
def engine() -> Iterator[Engine]:
    with Engine.local(2) as eng:
        yield eng


def small_spec(**kw: object) -> SweepSpec:
    return SweepSpec(
        name="t",
        base={
            "controller.duration_s": 2.0,
            "batch_size": 20,
            "controller.tf_download_samples": 0,
            "controller.oatf_mode": "adaptive",
            "dsp.fft_width": 256,
            "plant.truth_rate_hz": 200.0,
        },
        **kw,  # type: ignore[arg-type]
    )


def test_map_keeps_order_and_reports_each_failure_without_losing_the_rest(engine: Engine) -> None:
    out = engine.map(math.sqrt, [4.0, -1.0, 9.0, 16.0], description="sqrt", show_progress=False)
    assert [o.index for o in out] == [0, 1, 2, 3]
    assert [o.value for o in out if o.ok] == [2.0, 3.0, 4.0]
    assert not out[1].ok and "ValueError" in out[1].error and "math domain error" in out[1].error
    assert all(o.worker and o.run_s >= 0 and o.round_trip_s >= o.run_s for o in out)
    assert engine.slots() == 2


def warn_like_a_monitor(n: int) -> int:
    logging.getLogger("controller.monitors").warning("stale: parameters stale at tick %d (2.00 s without a fresh estimate) (policy degrade)", n)
    return n


def test_the_rigs_warnings_in_a_worker_are_counted_by_the_caller(engine: Engine) -> None:
    from workbench.service_warnings import counted_warnings

    with counted_warnings() as tally:
        out = engine.map(warn_like_a_monitor, [1, 2, 3], description="warn", show_progress=False)
    assert [o.value for o in out] == [1, 2, 3]
    assert tally.counts == {"stale": 3}


def test_sweep_table_failure_row_resume_and_determinism(engine: Engine, tmp_path: Path) -> None:
    broken = tmp_path / "broken.json"
    broken.write_text('{"waypoints": "none"}', encoding="utf-8")  # a regular file (settings accept it), no trajectory (the run fails)
    spec = small_spec(
        grid={"plant.adc_bits": [12, 20]},
        points=[{"label": "ok"}, {"label": "broken", "controller.trajectory": str(broken)}],
        seeds=[7],
    )
    res = run_sweep(spec, tmp_path / "a", engine, show_progress=False)
    assert (res.ran, res.skipped, res.failed) == (4, 0, 2)
    table = pq.read_table(res.parquet).to_pylist()
    assert len(table) == 4 and (tmp_path / "a" / "results.csv").exists()
    good = [r for r in table if r["point"] == "ok"]
    bad = [r for r in table if r["point"] == "broken"]
    assert all(r["status"] == "ok" and r["ticks"] == 400 and r["velocity_rms_1"] > 0 and r["true_velocity_rms_1"] > 0 for r in good)
    assert all(r["status"] == "error" and "WaypointTrajectory" in r["error"] and r["ticks"] is None for r in bad), bad
    assert {r["plant.adc_bits"] for r in good} == {12, 20} and all(r["plant.seed"] == 7 for r in table)
    assert all(r["rig_id"] == f"sw-{r['key']}" for r in table)
    # every setting is a column
    assert {"controller.oatf_mode", "dsp.fft_width", "plant.sensor_noise_scale", "common.sample_rate_hz"} <= set(table[0])

    # resumed: the finished points are skipped, the failed ones tried again
    again = run_sweep(spec, tmp_path / "a", engine, show_progress=False)
    assert (again.ran, again.skipped, again.failed) == (2, 2, 2)
    assert len(Journal(tmp_path / "a" / "runs.jsonl").rows) == 4

    # the same points from scratch elsewhere: the same numbers (deterministic, seeded)
    fresh = run_sweep(small_spec(grid={"plant.adc_bits": [12, 20]}, points=[{"label": "ok"}], seeds=[7]), tmp_path / "b", engine, show_progress=False)
    first = {r["key"]: r for r in good}
    for r in pq.read_table(fresh.parquet).to_pylist():
        old = first[r["key"]]
        assert {k: v for k, v in r.items() if k not in TIMING} == {k: v for k, v in old.items() if k not in TIMING}


def test_a_different_seed_changes_the_measured_cost(engine: Engine, tmp_path: Path) -> None:
    res = run_sweep(small_spec(seeds=[1, 2]), tmp_path, engine, show_progress=False)
    a, b = res.rows
    assert a["status"] == b["status"] == "ok"
    assert a["velocity_rms_1"] != b["velocity_rms_1"]


def test_noise_vs_lag_quick(engine: Engine, tmp_path: Path) -> None:
    from workbench.experiments import run_experiment

    with use_engine(engine):
        assert current_engine() is engine
        outcome = run_experiment("noise-vs-lag", tmp_path, quick=True, show_progress=False, raise_errors=True)
    assert outcome.status == "ok", outcome.results().get("checks")
    res = outcome.results()["results"]
    assert res["runs"] == 6 and res["failed"] == 0
    assert (tmp_path / "heatmaps_true.png").stat().st_size > 10_000 and (tmp_path / "heatmaps_measured.png").exists()
    cells = res["cells"]
    for lab in ("b", "e N=1024 α=0.05"):
        for bits in ("12", "20"):
            c = cells[lab][bits]["1"]
            assert 0 < c["true_velocity_rms_1_pct"] < 100 and 0 < c["velocity_rms_2_pct"] < 100
    assert len(pq.read_table(tmp_path / "sweep" / "results.parquet")) == 6


# --------------------------------------------------------------------------- a real scheduler and two workers


def _start(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=ROOT, stdout=log.open("wb"), stderr=subprocess.STDOUT, start_new_session=True)


def _end(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=5)


def test_sweep_on_a_dask_scheduler_with_two_workers(tmp_path: Path) -> None:
    sched_file = tmp_path / "scheduler.json"
    procs = [_start(["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--scheduler-file", str(sched_file)], tmp_path / "scheduler.log")]
    try:
        deadline = time.monotonic() + 60
        while not sched_file.exists() or not sched_file.read_text().strip():
            assert procs[0].poll() is None, (tmp_path / "scheduler.log").read_text()
            assert time.monotonic() < deadline, "the scheduler did not start within 60 s"
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for i in range(2):
            procs.append(
                _start(
                    [
                        "worker",
                        address,
                        "--no-nanny",
                        "--nthreads",
                        "1",
                        "--host",
                        "127.0.0.1",
                        "--no-dashboard",
                        "--name",
                        f"w{i}",
                        "--local-directory",
                        str(tmp_path / f"w{i}"),
                    ],
                    tmp_path / f"worker{i}.log",
                )
            )
        with Engine.connect(address, wait_for_workers=2, timeout_s=90) as eng:
            assert len(eng.workers()) == 2
        # the command line, as documented: ralf-hil sweep SPEC --scheduler ADDRESS
        spec = tmp_path / "spec.yaml"
        spec.write_text(
            "name: cluster\nbase:\n  controller.duration_s: 2\n  batch_size: 20\n  controller.tf_download_samples: 0\n  dsp.fft_width: 256\n"
            "grid:\n  plant.adc_bits: [12, 16, 20]\nseeds: [3]\n",
            encoding="utf-8",
        )
        from workbench.cli import main

        assert main(["sweep", str(spec), "--scheduler", address, "--out", str(tmp_path / "out"), "--no-progress"]) == 0
        rows = pq.read_table(tmp_path / "out" / "results.parquet").to_pylist()
        assert len(rows) == 3 and all(r["status"] == "ok" and r["ticks"] == 400 for r in rows)
        worker_pids = {str(p.pid) for p in procs[1:]}
        assert {r["worker"].rsplit(":", 1)[1] for r in rows} <= worker_pids
    finally:
        for p in reversed(procs):
            _end(p)


def test_cli_dry_run_and_bad_specs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from workbench.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text('name = "t"\n[base]\ncontroller.duration_s = 1\n[grid]\nplant.adc_bits = [12, 16]\nmode = ["lockstep", "onrig"]\n', encoding="utf-8")
    assert main(["sweep", str(spec), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "4 run(s)" in out and "onrig" in out
    spec.write_text("[base]\ncontroller.duration_s = 1\nplant.adc_bitz = 12\n", encoding="utf-8")
    assert main(["sweep", str(spec), "--dry-run"]) == 2
    assert "adc_bits" in capsys.readouterr().err
    assert main(["sweep", str(tmp_path / "none.yaml")]) == 2


def test_a_sweep_past_the_limit_asks_for_yes_and_its_dry_run_answers_at_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 10^6-point sweep's --dry-run resolved every point before printing (a minute of
    silence): past the limit it is counted, not resolved, and running it needs --yes."""
    from workbench.campaign.cli import LARGE_SWEEP
    from workbench.cli import main

    spec = tmp_path / "huge.toml"
    axis = ", ".join(str(i) for i in range(1000))
    spec.write_text(f'name = "huge"\n[base]\ncontroller.duration_s = 1\n[grid]\nplant.seed = [{axis}]\ncontroller.dither.seed = [{axis}]\n')
    assert main(["sweep", str(spec), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert f"1000000 run(s) planned, more than {LARGE_SWEEP}: not listed" in out
    assert main(["sweep", str(spec), "--out", str(tmp_path / "out")]) == 2
    assert "add --yes" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.rig
def test_onrig_mode_runs_the_three_process_rig(tmp_path: Path) -> None:
    """One point in the three-process mode (udp_multicast CAN: run inside the loopback namespace, as CI does)."""
    from workbench.campaign.modes import run_point
    from workbench.campaign.spec import expand

    point = expand(
        SweepSpec(mode="onrig", base={"controller.duration_s": 2.0, "batch_size": 20, "controller.tf_download_samples": 0, "dsp.fft_width": 256, "seed": 5})
    )[0]
    row = run_point(point)
    assert row["ticks"] == 400 and row["batches_sent"] == 20 and row["velocity_rms_1"] > 0


def test_overhead_measurement_reports_every_figure(engine: Engine) -> None:
    from workbench.campaign.measure import overheads

    o = overheads(engine, n=4)
    assert set(o) == {"task_round_trip_overhead_s", "burst_wall_per_task_s", "result_1mb_extra_s", "result_8mb_extra_s"}
    assert o["task_round_trip_overhead_s"] > 0 and o["burst_wall_per_task_s"] > 0
