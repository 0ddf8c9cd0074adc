"""``ralf-hil up``'s log folder: removed after a run that went well, kept
and named otherwise; none created by a refused run."""

from __future__ import annotations

import socket
import tempfile
from pathlib import Path

import pytest

from workbench.run_logs import RunLogs


@pytest.fixture
def tmpdir_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    root = tmp_path / "tmp"
    root.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(root))
    return root


def test_the_default_folder_goes_after_a_run_that_went_well(tmpdir_root: Path) -> None:
    logs = RunLogs.create(None, "bench1")
    assert logs.path.parent == tmpdir_root and logs.path.name.startswith("ralf-bench1-") and logs.path.is_dir()
    (logs.path / "dsp.log").write_text("ready\n")
    assert logs.finish(0) == ""
    assert list(tmpdir_root.iterdir()) == []


@pytest.mark.parametrize("code", [1, 2, 130])
def test_the_default_folder_stays_and_is_named_after_a_failure_or_an_interruption(tmpdir_root: Path, code: int) -> None:
    logs = RunLogs.create(None, "r")
    assert logs.finish(code) == f"service logs kept in {logs.path}" and logs.path.is_dir()


def test_keep_logs_and_a_chosen_folder_stay(tmpdir_root: Path, tmp_path: Path) -> None:
    kept = RunLogs.create(None, "r", keep=True)
    assert kept.finish(0) == f"service logs kept in {kept.path}" and kept.path.is_dir()
    chosen = RunLogs.create(str(tmp_path / "mine" / "logs"), "r")
    assert chosen.path.is_dir() and chosen.finish(0) == f"service logs kept in {tmp_path / 'mine' / 'logs'}" and chosen.path.is_dir()


def test_a_refused_live_port_creates_no_folder(tmpdir_root: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("foxglove")
    from workbench.cli import main

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["up", "--rig-id", "refused", "--live", f"127.0.0.1:{port}", "--duration", "1"]) == 2
    assert "cannot serve the live view" in capsys.readouterr().err
    assert [p.name for p in tmpdir_root.iterdir() if p.name.startswith("ralf-refused-")] == []  # only this rig id's lock file remains
