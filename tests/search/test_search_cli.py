"""``ralf-hil search``: exit codes, the failure bundle, and the commands that reproduce it."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import pytest
import yaml

from workbench.cli import MCAP_MAGIC, main
from workbench.search.planted import PLANT_HEARTBEAT_S, TPDO_LOSS

pytestmark = pytest.mark.slow


def _space(tmp_path: Path, data: dict) -> str:
    path = tmp_path / "space.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return str(path)


def test_a_violation_is_a_bundle_whose_commands_reproduce_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    code = main(["search", _space(tmp_path, TPDO_LOSS), "--property", "no_error()", "--budget", "8", "--shrink-budget", "40", "--seed", "2", "--out", str(out)])
    printed = capsys.readouterr().out
    assert code == 1, printed
    bundle = Path(printed.strip().splitlines()[-1].removeprefix("bundle: "))
    assert bundle.parent == out.resolve()
    info = json.loads((bundle / "bundle.json").read_text())
    assert info["seed"] == 2 and info["version"] and info["clock"] == "cosim" and info["search"]["reproduced"]
    assert (bundle / "recording.mcap").read_bytes()[: len(MCAP_MAGIC)] == MCAP_MAGIC
    (fault,) = yaml.safe_load((bundle / "faults.yaml").read_text())["faults"]
    assert fault["kinds"] == ["tpdo"] and fault["stop_s"] - fault["start_s"] > PLANT_HEARTBEAT_S
    assert json.loads((bundle / "settings.json").read_text())["controller"]["timeouts"]["plant_heartbeat_s"] == PLANT_HEARTBEAT_S
    failure = info["violated"][0].removeprefix("no_error() FAIL: rig failure: ")
    assert "TPDOs missing in a row" in failure

    replay, up = [line for line in (bundle / "reproduce.txt").read_text().splitlines() if not line.startswith("#")]
    assert main(shlex.split(replay)[1:]) == 1
    assert "violated again: no_error()" in capsys.readouterr().out
    summary = tmp_path / "up.json"
    assert main([*shlex.split(up)[1:], "--json", str(summary)]) == 1
    assert json.loads(summary.read_text())["failure"] == failure  # the same run under ralf-hil up


def test_a_spent_budget_exits_0_and_says_what_it_covered(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["search", _space(tmp_path, TPDO_LOSS), "--property", "verdict(INVALID)", "--budget", "3", "--out", str(tmp_path / "out")])
    printed = capsys.readouterr().out
    assert code == 0
    assert printed.startswith("no violation of verdict(INVALID) in 3 runs") and "covered: 3 runs, durations" in printed


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--property", "no_error()", "--budget", "0"], "at least one run"),
        (["--property", "streek(1)", "--budget", "3"], "no property named 'streek'"),
        (["--property", "within(defl9_in, 0, 1)", "--budget", "3"], "no run record holds a signal 'defl9_in'"),
        (["--budget", "3"], "no property given"),
        (["--property", "no_error()"], "give a budget"),
        (["--property", "within(counters.no_such_counter, 0, 0)", "--budget", "3"], "the record holds no signal 'counters.no_such_counter'"),
        (["--property", "valves_zero_within(events.channel_fault, -5)", "--budget", "3"], "valves_zero_within's N_MS must not be negative, got '-5'"),
        (["--property", "valves_zero_within(sensor_short, 50)", "--budget", "3"], "valves_zero_within's CAUSE is a plant event"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], says: str) -> None:
    assert main(["search", _space(tmp_path, TPDO_LOSS), *args, "--out", str(tmp_path / "out")]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("ralf-hil search: tpdo-loss, property")]  # the search's heading
    assert len(err) == 1 and says in err[0]
    assert not list((tmp_path / "out").glob("violation-*"))  # no bundle


def test_a_bad_space_file_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = {**TPDO_LOSS, "duration_s": [3.0, 1.0]}
    assert main(["search", _space(tmp_path, bad), "--property", "no_error()", "--budget", "3"]) == 2
    assert "inverted range" in capsys.readouterr().err
    assert main(["search", str(tmp_path / "missing.yaml"), "--property", "no_error()", "--budget", "3"]) == 2
    assert "cannot read search space" in capsys.readouterr().err
    assert main(["search", "--replay", str(tmp_path)]) == 2
    assert "not a failure bundle" in capsys.readouterr().err
