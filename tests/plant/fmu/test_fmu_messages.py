"""What an FMU says reaches the user: its warnings and errors go to the
plant's log at their level, and the line that reports a Discard or an
Error/Fatal step gives the FMU's own reason, for FMI 2.0 (pythonfmu) and
FMI 3.0 (pythonfmu3) alike. A pythonfmu ``do_step`` returning False is a
Discard (the run goes on, the samples held for that step); an exception in
it is a Fatal (no further steps). A NaN in an output the mapping reads only
as truth holds the A/D samples too. The FMUs are real ones, built from
``tests/plant/fmu/scripts``."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from plant_emulator.fmu.plant import FAULT_DISCARD, FAULT_ERROR, FAULT_NON_FINITE
from plant_emulator.service import build_health
from protocol.can_map import EmcyCode
from tests.plant.fmu.test_fmu_plant_faults import Rig

SCRIPTS = Path(__file__).parent / "scripts"
ROOT = Path(__file__).resolve().parents[3]
FAULT_STEP = 30
DISCARD, RAISE, TRUTH_NAN, WARN = 1, 2, 3, 4


@pytest.fixture(scope="module", params=[2, 3], ids=["fmi2", "fmi3"])
def faulty_fmu(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Built in a process of its own (the builder imports the script; the FMU
    then runs its own copy of it in this interpreter)."""
    tool, script = ("pythonfmu", "faulty_plant_fmi2.py") if request.param == 2 else ("pythonfmu3", "faulty_plant.py")
    pytest.importorskip(tool)
    dest = tmp_path_factory.mktemp(f"faulty{request.param}")
    subprocess.run([sys.executable, "-m", tool, "build", "-f", str(SCRIPTS / script), "-d", str(dest)], check=True, capture_output=True, timeout=300)
    (fmu,) = dest.glob("*.fmu")
    return fmu


def _rig(fmu: Path, tmp_path: Path, kind: int) -> Rig:
    mapping = tmp_path / f"k{kind}.yaml"
    outputs = [{"variable": "ai1"}, {"variable": "ai2"}, {"variable": "ai1"}, {"variable": "ai2"}]
    data = {"inputs": ["u1", "u2"], "outputs": outputs, "truth": {"modal_frequencies_hz": ["f1", "f1"]}}
    mapping.write_text(yaml.safe_dump({**data, "parameters": {"fault_step": FAULT_STEP, "fault_kind": kind}}))
    return Rig(fmu, mapping)


def _fmu_lines(caplog: pytest.LogCaptureFixture, level: int) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "plant_emulator.fmu.instance" and r.levelno == level]


FATAL_PROBE = """
import json, logging, os, sys
from pathlib import Path
sys.path.append(os.getcwd())  # the checkout, for its tests package only (ralf-hil may be installed)
from plant_emulator.service import build_health
from tests.plant.fmu.test_fmu_messages import FAULT_STEP, RAISE, _rig
lines = []
handler = logging.Handler(logging.WARNING)
handler.emit = lambda record: lines.append([record.name, record.levelname, record.getMessage()])
logging.getLogger().addHandler(handler)
rig = _rig(Path(sys.argv[1]), Path(sys.argv[2]), RAISE)
syncs = [rig.sync() for _ in range(FAULT_STEP + 3)]
health = build_health(0, rig.app, rig.node, None)
out = {"codes": [c for c, _ in syncs], "emcys": [e for _, e in syncs], "failed": rig.plant.failed, "state": health.state,
       "errors": health.counters["fmu_step_errors"], "last_miss": health.last_miss,
       "events": [e.detail for e in rig.events if e.kind == "model_fault"], "log": lines}
rig.app.close()
print(json.dumps(out), flush=True)
os._exit(0)  # the interpreter's own exit is not under test here (see the module doc)
"""


def test_an_exception_in_do_step_is_a_fatal_whose_reason_reaches_the_fault_line_and_the_log(faulty_fmu: Path, tmp_path: Path) -> None:
    """In a process of its own: after a Fatal from a pythonfmu FMU, freed and
    unloaded, that process may crash at its exit (in the garbage collector)."""
    probe = subprocess.run(
        [sys.executable, "-c", FATAL_PROBE, str(faulty_fmu), str(tmp_path)], capture_output=True, text=True, timeout=300, cwd=ROOT, check=False
    )
    assert probe.returncode == 0, probe.stderr
    out = json.loads(probe.stdout.strip().splitlines()[-1])
    codes, emcys = out["codes"], out["emcys"]
    assert not any(emcys[: FAULT_STEP - 1]) and [(c, cause) for c, _, cause in emcys[FAULT_STEP - 1]] == [(int(EmcyCode.PLANT_MODEL_FAULT), FAULT_ERROR)]
    assert all(c == codes[FAULT_STEP - 2] for c in codes[FAULT_STEP - 1 :])  # held from the last good step on
    assert out["failed"] and out["state"] == "degraded" and out["errors"] == 1
    reason = f"RuntimeError('valve model diverged at step {FAULT_STEP}')"
    assert "returned fatal" in out["last_miss"] and reason in out["last_miss"]  # the FMU's own reason in the fault line
    assert out["events"] == [out["last_miss"]]
    fmu_lines = [message for name, level, message in out["log"] if name == "plant_emulator.fmu.instance" and level == "ERROR"]
    assert len(fmu_lines) == 1 and " fatal: " in fmu_lines[0] and reason in fmu_lines[0]
    assert [m for name, level, m in out["log"] if name == "plant_emulator.fmu.plant"] == [out["last_miss"]]


def test_do_step_returning_false_is_a_discard_with_the_fmus_words(faulty_fmu: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    rig = _rig(faulty_fmu, tmp_path, DISCARD)
    caplog.set_level(logging.WARNING)
    try:
        last = [rig.sync() for _ in range(FAULT_STEP - 1)][-1][0]
        codes, emcys = rig.sync()
        assert [(c, cause) for c, _, cause in emcys] == [(int(EmcyCode.PLANT_MODEL_FAULT), FAULT_DISCARD)]
        assert codes == last  # held for the discarded step
        fresh, cleared = rig.sync()
        assert [c for c, _, _ in cleared] == [0] and not rig.plant.failed
        health = build_health(0, rig.app, rig.node, None)
        assert health.counters["fmu_step_discards"] == 1 and health.state == "running"
        assert f"returned discard (step {FAULT_STEP}: cannot take this step)" in (health.last_miss or "")
        assert _fmu_lines(caplog, logging.WARNING) == [f"FMU {faulty_fmu.name} [logStatusWarning] warning: step {FAULT_STEP}: cannot take this step"]
    finally:
        rig.app.close()


def test_a_nan_in_a_truth_only_output_holds_the_ad_samples(faulty_fmu: Path, tmp_path: Path) -> None:
    rig = _rig(faulty_fmu, tmp_path, TRUTH_NAN)
    try:
        last = [rig.sync() for _ in range(FAULT_STEP - 1)][-1][0]
        codes, emcys = rig.sync()  # the mapped A/D outputs are finite; only the truth's f1 is NaN
        assert [(c, cause) for c, _, cause in emcys] == [(int(EmcyCode.PLANT_MODEL_FAULT), FAULT_NON_FINITE)]
        assert codes == last
        _, cleared = rig.sync()
        assert [c for c, _, _ in cleared] == [0]
        assert build_health(0, rig.app, rig.node, None).counters["fmu_non_finite_outputs"] == 1
    finally:
        rig.app.close()


def test_an_fmus_warning_reaches_the_plants_log_and_the_run_goes_on(faulty_fmu: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    rig = _rig(faulty_fmu, tmp_path, WARN)
    caplog.set_level(logging.WARNING)
    try:
        for _ in range(FAULT_STEP + 5):
            assert rig.sync()[1] == []  # a warning is no fault
        assert _fmu_lines(caplog, logging.WARNING) == [f"FMU {faulty_fmu.name} [logStatusWarning] warning: step {FAULT_STEP}: a warning of the plant's own"]
        assert rig.plant.instance.n_messages == 1 and rig.plant.instance.last_message.endswith("a warning of the plant's own")
    finally:
        rig.app.close()
