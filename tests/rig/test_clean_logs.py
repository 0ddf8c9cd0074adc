"""A healthy run's logs hold no ERROR: the rig's zenoh peers link once per
pair (no refused reverse link), zenoh's own log lines arrive as the
service's log records (no raw Rust lines, no colour codes), and a service's
connect list holding its own endpoint does not make it connect to itself."""

from __future__ import annotations

import json
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from service_kit.zenoh_log import parse_line


def test_zenoh_log_lines_become_records_without_colour_or_source_location() -> None:
    raw = (
        "\x1b[2m2026-12-03T03:55:12.688809Z\x1b[0m \x1b[31mERROR\x1b[0m net-0 ThreadId(03) "
        "\x1b[2mzenoh_transport::unicast::establishment::open\x1b[0m\x1b[2m:\x1b[0m Received a close message (reason INVALID) "
        "in response to an OpenSyn at /build/zenoh/io/zenoh-transport/src/unicast/establishment/open.rs:526."
    )
    assert parse_line(raw) == (40, "zenoh.zenoh_transport", "Received a close message (reason INVALID) in response to an OpenSyn")
    warn = "2026-12-03T04:02:07.378539Z  WARN ThreadId(01) zenoh::net::runtime::orchestrator: Link lost."
    assert parse_line(warn) == (30, "zenoh.zenoh", "Link lost.")
    routine = "2026-12-03T04:02:07.378539Z  WARN ThreadId(01) zenoh::net::runtime::orchestrator: Scouting delay elapsed before start conditions are met."
    assert parse_line(routine) == (20, "zenoh.zenoh", "Scouting delay elapsed before start conditions are met.")  # a peer started before its peers
    assert parse_line("rig 'default': CAN udp_multicast port 44001") is None  # any other line passes through unchanged


def test_own_listen_endpoint_is_not_connected_to() -> None:
    from protocol.settings import CommonSettings, load_settings
    from service_kit.transport import zenoh_config

    settings = load_settings(
        CommonSettings, {"zenoh_listen": "tcp/127.0.0.1:7451", "zenoh_connect": "tcp/127.0.0.1:7450,tcp/127.0.0.1:7451,tcp/127.0.0.1:7452"}
    )
    assert zenoh_config(settings).get_json("connect/endpoints") == '["tcp/127.0.0.1:7450","tcp/127.0.0.1:7452"]'


@pytest.mark.timeout(240)
@pytest.mark.parametrize("clock", ["realtime", "lockstep"])
def test_a_healthy_run_logs_no_error(tmp_path: Path, clock: str) -> None:
    logs = tmp_path / "logs"
    summary = tmp_path / "summary.json"
    proc = subprocess.run(
        [sys.executable, "-m", "workbench", "up", "--duration", "20", "--clock", clock, "--rig-id", f"clean-{uuid.uuid4().hex[:8]}", "--log-dir", str(logs),
         "--json", str(summary)],
        capture_output=True,
        text=True,
        timeout=220,
    )  # fmt: skip
    texts = {p.name: p.read_text() for p in logs.glob("*.log")}
    verdict = json.loads(summary.read_text())["verdict"]
    # The exit code follows the run's verdict; in real time a loaded host may miss deadlines
    # (timing FAIL, exit 1): nothing else may go wrong.
    assert proc.returncode == verdict["exit_code"], proc.stderr + "\n".join(texts.values())
    assert not verdict["by_level"]["INVALID"] and all(r.startswith("timing FAIL") for r in verdict["by_level"]["FAIL"]), verdict
    assert verdict["findings"]["log_errors"] == {"controller": 0, "plant": 0, "dsp": 0}
    assert set(texts) == {"controller.log", "plant.log", "dsp.log"}
    for name, text in {**texts, "up's stdout": proc.stdout, "up's stderr": proc.stderr}.items():
        errors = [line for line in text.splitlines() if " ERROR " in line]
        assert not errors, f"{name}: {errors[:5]}"
        assert "\x1b[" not in text and "ThreadId(" not in text, f"{name} holds raw zenoh log lines"
