"""Every output of ``ralf-hil up`` is written whole in every clock (the run
record, timing, TF and hop stamps; the plant's truth; the MCAP recording and
its CAN log; the JSON summary; the logs), and any two outputs that would name
one file are refused before anything starts, in every clock, for every pair."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import uuid
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from controller.record import load_record
from protocol.record_paths import run_record_outputs, truth_file
from workbench.cli import main as ralf_hil
from workbench.output_paths import COSIM_LOG, output_clashes, up_outputs

CLOCKS = ("cosim", "lockstep", "realtime")

Aim = Callable[[Path, str], "list[str] | None"]
"""The ``ralf-hil up`` arguments that make one output write ``target`` in a clock (None: it never can)."""


def _record_ending(ending: str) -> Aim:
    def aim(target: Path, clock: str) -> list[str] | None:
        if ending == ".hops.npz" and clock != "realtime":
            return None
        if not target.name.endswith(ending) or target.name == ending:
            return None
        return ["--set", f"controller.run_record={target.with_name(target.name[: -len(ending)])}"]

    return aim


def _truth(target: Path, clock: str) -> list[str] | None:
    return ["--set", f"plant.truth_record={target}"] if target.name.endswith(".truth.npz") else None


def _can_log(target: Path, clock: str) -> list[str] | None:
    return ["--can-log", str(target)] if target.suffix in (".blf", ".asc", ".log") else None


def _logs(target: Path, clock: str) -> list[str] | None:
    names = {COSIM_LOG} if clock == "cosim" else {"controller.log", "plant.log", "dsp.log"}
    return ["--log-dir", str(target.parent if target.name in names else target)]


KINDS: dict[str, Aim] = {
    "run record": _record_ending(".npz"),
    "run record sidecar": _record_ending(".json"),
    "timing record": _record_ending(".timing.npz"),
    "TF record": _record_ending(".tf.npz"),
    "hop stamps": _record_ending(".hops.npz"),
    "truth record": _truth,
    "MCAP recording": lambda target, clock: ["--record", str(target)],
    "CAN log": _can_log,
    "JSON summary": lambda target, clock: ["--json", str(target)],
    "logs": _logs,
}
LABEL = {
    "run record": "the run record (controller.run_record)",
    "run record sidecar": "the run record (controller.run_record)",
    "timing record": "the timing record (controller.run_record)",
    "TF record": "the TF record (controller.run_record)",
    "hop stamps": "the hop stamps (controller.run_record)",
    "truth record": "the truth record (plant.truth_record)",
    "MCAP recording": "the MCAP recording (--record)",
    "CAN log": "the CAN log (--can-log)",
    "JSON summary": "the JSON summary (--json)",
    "logs": "the logs (--log-dir)",
}
ONE_SETTING = {"run record", "run record sidecar", "timing record", "TF record", "hop stamps"}
"""Named by one setting (controller.run_record): they are one output's files, never two outputs'."""
TARGETS = ("x.npz", "x.json", "x.timing.npz", "x.tf.npz", "x.hops.npz", "x.truth.npz", "x.log", "controller.log", COSIM_LOG, "x.mcap")


def _pair_cases() -> list[tuple[str, str, str, str]]:
    cases = []
    for clock in CLOCKS:
        for a, b in itertools.combinations(KINDS, 2):
            if a in ONE_SETTING and b in ONE_SETTING:
                continue
            target = next((t for t in TARGETS if KINDS[a](Path(t), clock) is not None and KINDS[b](Path(t), clock) is not None), None)
            if target is not None:
                cases.append((clock, a, b, target))
    return cases


PAIRS = _pair_cases()


def test_every_pair_of_outputs_that_can_name_one_file_is_covered() -> None:
    """Every pair is tried, but those no plan can put on one file: the files
    of one setting, the hop stamps outside real time, and outputs whose
    names end apart (a CAN log's ``.blf``/``.asc``/``.log`` against the
    controller's ``.npz``/``.json`` and the truth's ``.truth.npz``; the truth's ``.truth.npz`` against the
    sidecar's ``.json``, ``.timing.npz``, ``.tf.npz``, ``.hops.npz``)."""
    covered = {(clock, a, b) for clock, a, b, _ in PAIRS}
    never = {frozenset((k, "CAN log")) for k in ONE_SETTING | {"truth record"}} | {frozenset(("truth record", k)) for k in ONE_SETTING - {"run record"}}
    for clock in CLOCKS:
        for a, b in itertools.combinations(KINDS, 2):
            if a in ONE_SETTING and b in ONE_SETTING or frozenset((a, b)) in never or (clock != "realtime" and "hop stamps" in (a, b)):
                assert (clock, a, b) not in covered
            else:
                assert (clock, a, b) in covered, (clock, a, b)
    assert len(PAIRS) == 3 * 22 + 3  # 22 pairs in every clock, 3 more with the hop stamps in real time


@pytest.mark.parametrize(("clock", "a", "b", "target"), PAIRS, ids=[f"{c}-{a}-{b}".replace(" ", "_") for c, a, b, _ in PAIRS])
def test_two_outputs_on_one_file_are_refused_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, clock: str, a: str, b: str, target: str
) -> None:
    for name in [n for n in os.environ if n.startswith("RALF_")]:
        monkeypatch.delenv(name)
    path = tmp_path / "out" / target
    args = ["up", "--clock", clock, "--rig-id", f"clash-{uuid.uuid4().hex[:6]}", "--duration", "1"]
    args += [*(KINDS[a](path, clock) or []), *(KINDS[b](path, clock) or [])]
    if "--can-log" in args and "--record" not in args:  # a CAN log goes with a recording
        args += ["--record", str(tmp_path / "elsewhere" / "run.mcap")]
    with pytest.raises(SystemExit) as ended:
        ralf_hil(args)
    assert ended.value.code == 2
    said = " ".join(capsys.readouterr().err.split())
    assert f"{path} would be written by both" in said and LABEL[a] in said and LABEL[b] in said, said
    assert "Traceback" not in said and said.count("ralf-hil up:") == said.count("would be")
    assert not (tmp_path / "out").exists()  # nothing written, nothing created


def test_a_file_of_one_output_is_refused_as_the_folder_of_another(tmp_path: Path) -> None:
    clashes = output_clashes({"controller": {"RALF_RUN_RECORD": str(tmp_path / "s.json" / "rec")}}, clock="cosim", json=str(tmp_path / "s.json"))
    head = f"{tmp_path / 's.json'} would be a file of the JSON summary (--json) and a folder of"
    assert clashes == [
        f"{head} the run record (controller.run_record) ({tmp_path / 's.json' / 'rec.npz'})",
        f"{head} the timing record (controller.run_record) ({tmp_path / 's.json' / 'rec.timing.npz'})",
        f"{head} the TF record (controller.run_record) ({tmp_path / 's.json' / 'rec.tf.npz'})",
    ]
    assert output_clashes({}, clock="lockstep", json=str(tmp_path / "logs" / "s.json"), log_dir=str(tmp_path / "logs")) == []  # a folder holds files


@pytest.mark.parametrize("clock", CLOCKS)
def test_outputs_on_distinct_paths_pass(tmp_path: Path, clock: str) -> None:
    sets = {"controller": {"RALF_RUN_RECORD": str(tmp_path / "rec")}, "plant": {"RALF_TRUTH_RECORD": str(tmp_path / "rec")}}
    kw = {
        "json": str(tmp_path / "rec.summary.json"),
        "record": str(tmp_path / "rec.mcap"),
        "can_log": str(tmp_path / "rec.blf"),
        "log_dir": str(tmp_path / "logs"),
    }
    assert output_clashes(sets, clock=clock, **kw) == []
    files = up_outputs(sets, clock=clock, **kw)
    assert ("the hop stamps (controller.run_record)" in files) == (clock == "realtime")
    assert set(run_record_outputs(tmp_path / "rec")) == {"run record", "timing record", "TF record", "hop stamps"}
    assert truth_file(tmp_path / "rec") == tmp_path / "rec.truth.npz"


# --- every output written, in every clock -----------------------------------------------------------


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")}
    env["COLUMNS"] = "400"
    return env


def _up_everything(tmp_path: Path, clock: str, duration_s: float, extra: list[str]) -> tuple[subprocess.CompletedProcess[str], Path]:
    out = tmp_path / "out"
    rec = out / "rec"
    args = [sys.executable, "-m", "workbench", "up", "--clock", clock, "--rig-id", f"every-{uuid.uuid4().hex[:6]}", "--duration", str(duration_s)]
    args += ["--set", f"controller.run_record={rec}", "--set", f"plant.truth_record={rec}", "--set", "dsp.fft_width=512"]
    args += ["--set", "controller.tf_download_samples=400", *extra]
    args += ["--json", str(out / "summary.json"), "--record", str(out / "run.mcap"), "--can-log", str(out / "bus.asc"), "--log-dir", str(out / "logs")]
    proc = subprocess.run(args, capture_output=True, text=True, timeout=300, env=_env(), check=False)
    return proc, out


def _assert_every_output(out: Path, clock: str) -> None:
    logs = [COSIM_LOG] if clock == "cosim" else ["controller.log", "plant.log", "dsp.log"]
    expected = {"rec.npz", "rec.json", "rec.timing.npz", "rec.timing.json", "rec.tf.npz", "rec.truth.npz", "summary.json", "run.mcap", "bus.asc", "logs"}
    expected |= {"rec.hops.npz"} if clock == "realtime" else set()
    assert {p.name for p in out.iterdir()} == expected  # no parts folder or temporary file left behind
    assert {p.name for p in (out / "logs").iterdir()} == set(logs) and all((out / "logs" / name).stat().st_size > 0 for name in logs)
    record = load_record(out / "rec")
    ticks = record.metadata["result"]["ticks"]
    assert ticks > 0 and len(record) == ticks and len(load_record(out / "rec.timing")) == ticks  # the last partial chunk too
    assert np.array_equal(record["tick"], np.arange(ticks))
    with np.load(out / "rec.truth.npz", allow_pickle=False) as truth:
        assert truth["sim_time_s"].size > 0
    with np.load(out / "rec.tf.npz", allow_pickle=False) as tf:
        assert tf["sim_time_s"].size >= 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["controller"]["ticks"] > 0
    assert (out / "run.mcap").read_bytes()[:8] == b"\x89MCAP0\r\n" and (out / "bus.asc").stat().st_size > 0


def test_a_cosimulation_writes_every_output_whole(tmp_path: Path) -> None:
    """21 simulated s at 200 Hz: 4,200 rows, one full 4,096-row chunk and a partial one."""
    proc, out = _up_everything(tmp_path, "cosim", 21.0, [])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    _assert_every_output(out, "cosim")
    assert len(load_record(out / "rec")) == 4200


@pytest.mark.rig
@pytest.mark.timeout(400)
@pytest.mark.parametrize("clock", ["lockstep", "realtime"])
def test_a_three_process_rig_writes_every_output_whole(tmp_path: Path, clock: str) -> None:
    proc, out = _up_everything(tmp_path, clock, 4.0, [])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    _assert_every_output(out, clock)


# --- a JUnit file on a report's own files ---------------------------------------------------------------

SCENARIO = Path(__file__).resolve().parents[2] / "docs" / "scenarios" / "zenoh-interrupt-loss.yaml"
JUNIT_CASES = [
    ("timing-test", "report.json"),
    ("timing-test", "report.md"),
    ("timing-test", "hist_tet.png"),
    ("timing-test", "."),
    ("experiment", "report.md"),
    ("experiment", "results.json"),
    ("experiment", "."),
    ("experiment all", "index.md"),
    ("experiment all", "verify/report.md"),
    ("sweep", "results.csv"),
    ("sweep", "runs.jsonl"),
    ("sweep", "."),
]


def _junit_args(command: str, out: Path, junit: Path, spec: Path) -> list[str]:
    head = {
        "timing-test": ["timing-test", str(SCENARIO)],
        "experiment": ["experiment", "verify"],
        "experiment all": ["experiment", "all"],
        "sweep": ["sweep", str(spec)],
    }
    return [*head[command], "--out", str(out), "--junit", str(junit)]


@pytest.mark.parametrize(("command", "name"), JUNIT_CASES, ids=[f"{c}-{n}".replace(" ", "_") for c, n in JUNIT_CASES])
def test_a_junit_file_on_a_reports_own_file_is_refused_before_the_run(tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, name: str) -> None:
    spec = tmp_path / "spec.toml"
    spec.write_text('name = "clash"\n[base]\ncontroller.duration_s = 1\n[grid]\nplant.seed = [1, 2]\n')
    out = tmp_path / "out"
    junit = out if name == "." else out / name
    assert ralf_hil(_junit_args(command, out, junit, spec)) == 2
    said = " ".join(capsys.readouterr().err.split())
    both = (
        "would be both the report folder (--out) and the JUnit XML (--junit)"
        if name == "."
        else "would be written by both the report (--out) and the JUnit XML (--junit)"
    )
    assert f"{junit} {both}" in said and "Traceback" not in said, said
    assert not out.exists()


@pytest.mark.parametrize("command", sorted({c for c, _ in JUNIT_CASES}))
def test_a_junit_file_beside_or_apart_from_the_report_passes(tmp_path: Path, command: str) -> None:
    from workbench.output_paths import junit_clash

    out = tmp_path / "out"
    for junit in (tmp_path / "junit.xml", out / "junit.xml"):
        assert junit_clash(str(junit), out, command) is None
    assert junit_clash(None, out, command) is None
