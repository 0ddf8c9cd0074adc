"""``--record`` reaches the services through the launcher's entry point
(``ralf_hil.service_recorder``), never through an import of the launcher."""

from __future__ import annotations

import pytest

from protocol.settings import DspSettings
from service_kit import runtime
from workbench.recording.attach import attach_recorder


def test_the_installed_hook_is_the_launchers_recorder() -> None:
    assert runtime.installed_recorder_hook() is attach_recorder


def test_record_arg_is_split_from_the_settings() -> None:
    assert runtime.split_record_arg(["--set", "seed=3", "--record", "a.mcap"]) == ("a.mcap", ["--set", "seed=3"])
    assert runtime.split_record_arg(["--record=b.mcap", "--set", "seed=3"]) == ("b.mcap", ["--set", "seed=3"])
    assert runtime.split_record_arg(["--set", "seed=3"]) == (None, ["--set", "seed=3"])


def test_record_without_a_launcher_is_refused_in_one_line(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """A service image carries no launcher: no hook loads, ``--record`` exits 2 before any session opens."""
    monkeypatch.setattr(runtime, "entry_points", lambda group: [])

    def body(*_args: object) -> int:
        raise AssertionError("the service must not start")

    assert runtime.run_service("ralf-dsp", "test", DspSettings, body, ["--record", "x.mcap"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--record needs the launcher's recorder" in err[0]
