"""A real run recorded by ``ralf-hil up --record`` (three processes, lockstep,
udp_multicast inside the loopback namespace), then read with the mcap
library, checked against its schemas and the DBC, re-identified, plotted
and its CAN side replayed."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import uuid
from collections import Counter
from pathlib import Path
from typing import Any

import can
import cantools
import numpy as np
import pytest

from tests.recording.support import CHANNELS_OF_A_RUN, read_validated
from workbench.recording import foxglove
from workbench.recording.plot import FIGURES
from workbench.recording.reader import Recording
from workbench.recording.replay import compare, play_can, recorded_can_messages

ROOT = Path(__file__).resolve().parents[2]
SIM_S = 12.0


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("recorded")
    rig_id = f"rec-{uuid.uuid4().hex[:8]}"
    mcap_path = tmp / "run.mcap"
    can_port = 46000 + uuid.uuid4().int % 4000
    proc = subprocess.run(
        [
            sys.executable, "-m", "workbench", "up", "--clock", "lockstep", "--duration", "90", "--rig-id", rig_id,
            "--record", str(mcap_path), "--can-log", str(tmp / "run.asc"), "--json", str(tmp / "summary.json"), "--log-dir", str(tmp / "logs"),
            "--can-port", str(can_port), "--set", f"controller.duration_s={SIM_S}", "--set", "fft_width=512", "--set", "controller.tf_download_samples=400",
        ],
        capture_output=True, text=True, timeout=150,
    )  # fmt: skip
    logs = "\n".join(p.read_text() for p in (tmp / "logs").glob("*.log"))
    assert proc.returncode == 0, proc.stderr + logs
    return {
        "tmp": tmp,
        "path": mcap_path,
        "rig_id": rig_id,
        "can_port": can_port,
        "stdout": proc.stdout,
        "summary": json.loads((tmp / "summary.json").read_text()),
    }


@pytest.mark.timeout(200)
def test_up_prints_the_can_port_first_and_the_summary_on_stdout(run: dict[str, Any]) -> None:
    lines = run["stdout"].splitlines()
    assert f"CAN udp_multicast port {run['can_port']}," in lines[0]  # --can-port, printed before any service starts
    assert "run summary" in run["stdout"] and "recording" in run["stdout"]
    rec = run["summary"]["recording"]
    assert rec["dropped"] == 0 and rec["undecodable"] == 0 and rec["can_socket_drops"] == 0 and rec["can_frames"] > 3 * SIM_S * 200


def test_every_message_validates_against_its_channel_schema(run: dict[str, Any]) -> None:
    from workbench.recording.doctor import check

    assert check(run["path"]) == []  # CRCs, declarations, chunk ranges, statistics
    seen = read_validated(run["path"])
    counts, meta, encodings = seen.counts, seen.metadata, dict(seen.encodings)
    root = f"/ralf/{run['rig_id']}"
    # every publisher tags its payload: JSON, or the named binary batch and TF snapshot encodings
    assert encodings.pop(f"{root}/dsp/batch") == "application/octet-stream;ralf-batch-v1"
    assert encodings.pop(f"{root}/controller/tf") == "application/octet-stream;ralf-tf-v1"
    assert set(encodings.values()) == {"application/json"}, encodings
    for suffix in (*CHANNELS_OF_A_RUN, "alive"):
        assert counts.get(f"{root}/{suffix}", 0) > 0, suffix
    assert "/_undecodable" not in counts
    assert counts[f"{root}/controller/tf"] >= 3  # a download every 400 ticks, each published on controller/tf
    assert json.loads(meta["ralf.settings.dsp"]["fft_width"]) == 512
    assert meta["ralf.run"]["rig_id"] == run["rig_id"] and meta["ralf.run"]["seed"] == "0"
    assert "eclipse-zenoh" in json.loads(meta["ralf.run"]["versions"])


def test_cantools_decodes_every_recorded_frame(run: dict[str, Any]) -> None:
    db = cantools.database.load_file(str(ROOT / "protocol" / "ralf.dbc"))
    rec = Recording.load(run["path"])
    frames = rec.can_frames()
    ticks = [f["tick"] for f in frames if f["frame"] == "sync"]
    # Lockstep: one SYNC per tick plus one per re-send of a SYNC the bus lost (a loaded host); none lost by the tap.
    retries = rec.data("health/controller")[-1]["counters"]["sync_retries"]
    assert ticks == list(range(len(ticks))) and len(ticks) == SIM_S * 200 + retries
    for f in frames:
        db.decode_message(f["arbitration_id"], bytes(f["data"]))  # raises on a frame the DBC does not describe
    # The tap's view of the controller's measurement equals what it sent the DSP: AI3/AI4 of each TPDO1.
    assert {f["direction"] for f in frames if f["frame"] == "tpdo1"} == {"plant->controller"}
    # python-can reads the .asc side log with the same frames
    asc = [m for m in can.ASCReader(str(run["tmp"] / "run.asc"))]
    # (the same frames; the MCAP is read back in log-time order, the .asc is in arrival order, and
    # frames a few microseconds apart may be stamped out of that order by the receiving thread)
    assert Counter((m.arbitration_id, bytes(m.data)) for m in asc) == Counter((f["arbitration_id"], bytes(f["data"])) for f in frames)


def test_replay_at_the_recorded_settings_is_bit_identical(run: dict[str, Any]) -> None:
    rec = Recording.load(run["path"])
    same, replayed = compare(rec)
    assert same.identical, same.mismatched[:10]
    assert len(replayed) == len(rec.interrupts()) > 50
    assert any(i.poles for i in replayed)
    assert same.replayed.median_abs_error_pct == same.recorded.median_abs_error_pct
    other, _ = compare(rec, {"fft_width": 256, "alpha": 0.3})
    assert not other.identical and other.mismatched
    assert np.isfinite(other.replayed.median_abs_error_pct) and np.isfinite(other.replayed.lag_s)


def test_replay_cli_writes_its_report(run: dict[str, Any]) -> None:
    out = run["tmp"] / "replay"
    proc = subprocess.run(
        [sys.executable, "-m", "workbench", "replay", str(run["path"]), "--require-identical", "--out", str(out)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert "**identical**" in proc.stdout
    assert json.loads((out / "replay.json").read_text())["identical_to_recorded"] is True
    assert (out / "replay_tracks.png").stat().st_size > 10_000


def test_plot_writes_the_figures(run: dict[str, Any]) -> None:
    out = run["tmp"] / "figures"
    layout = run["tmp"] / "layout.json"
    proc = subprocess.run(
        [sys.executable, "-m", "workbench", "plot", str(run["path"]), "--out", str(out), "--foxglove-layout", str(layout)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    for name in FIGURES:
        assert (out / name).stat().st_size > 20_000, name  # a figure with data, not an empty canvas
    assert json.loads(layout.read_text()) == foxglove.layout(run["rig_id"])


def _resolve(data: Any, path: str) -> Any:
    """Follow a Foxglove message path's field part (``a.b[0].c``) into a decoded message."""
    for part in path.replace("]", "").split("."):
        name, _, index = part.partition("[")
        data = data[name] if name else data
        if index:
            data = data[int(index)]
    return data


def test_the_foxglove_layout_plots_fields_the_recording_has(run: dict[str, Any]) -> None:
    rec = Recording.load(run["path"])
    for path in foxglove.message_paths(run["rig_id"]):
        topic, _, fields = path.partition(".")
        values = []
        for m in rec.messages:
            if m.topic == topic:
                try:
                    values.append(_resolve(m.data, fields))
                except (KeyError, IndexError):
                    continue
        assert values and all(isinstance(v, (int, float)) for v in values), path
    shipped = json.loads((ROOT / "docs" / "foxglove-layout.json").read_text())
    assert shipped == foxglove.layout("default")


def test_can_replay_onto_a_bus_is_bounded_and_faithful(run: dict[str, Any]) -> None:
    rec = Recording.load(run["path"])
    messages = recorded_can_messages(rec, direction="controller->plant")
    channel = f"replay-{uuid.uuid4().hex[:6]}"
    got: list[can.Message] = []
    with can.Bus(interface="virtual", channel=channel) as rx, can.Bus(interface="virtual", channel=channel) as tx:
        done = threading.Event()

        def receive() -> None:
            while not done.is_set() or len(got) < 300:
                msg = rx.recv(timeout=0.5)
                if msg is None:
                    return
                got.append(msg)

        thread = threading.Thread(target=receive)
        thread.start()
        sent = play_can(messages, tx, ignore_timestamps=True, gap_s=0.0, limit=300, max_wall_s=20.0)
        done.set()
        thread.join(timeout=10)
    assert sent == 300
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(m.arbitration_id, bytes(m.data)) for m in messages[:300]]


def test_replay_cli_plays_the_can_side_onto_udp_multicast(run: dict[str, Any]) -> None:
    """``ralf-hil replay --can``: another tool on the bus (here a python-can bus) sees the recorded frames."""
    port = 42000 + uuid.uuid4().int % 1000
    frames = [f for f in Recording.load(run["path"]).can_frames() if f["direction"] == "plant->controller"][:100]
    with can.Bus(interface="udp_multicast", channel="239.74.163.2", port=port, receive_own_messages=False) as rx:
        proc = subprocess.run(
            [sys.executable, "-m", "workbench", "replay", str(run["path"]), "--can", "--port", str(port), "--direction", "plant->controller", "--ignore-timestamps", "--gap", "0.001", "--limit", "100", "--max-wall", "30"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        assert "100 of" in proc.stderr
        got = []
        while (msg := rx.recv(timeout=1.0)) is not None:
            got.append((msg.arbitration_id, bytes(msg.data)))
    assert got == [(f["arbitration_id"], bytes(f["data"])) for f in frames]
