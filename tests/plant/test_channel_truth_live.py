"""The channels' true and faulted values on the plant's test port (``plant/channels``,
:class:`protocol.messages.ChannelTruth`) while the plant has channel faults, and nothing
new without them.

The recording is read with the ``mcap`` library's own reader and each message is
validated with ``jsonschema`` against the schema its channel carries; its values are
compared with the plant's truth file (``channel_*`` arrays, one row per conversion),
written by another path of the plant (numpy's ``savez``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from plant_emulator.service import PlantApplication
from protocol.keys import Keys
from protocol.messages import ChannelTruth
from protocol.settings import PlantSettings, load_settings
from workbench.cosim import run_cosim
from workbench.recording import mf4_channels
from workbench.recording.schemas import rig_topics

CONTROLLER = {"duration_s": 1.2, "tf_download_samples": 0, "batch_size": 20, "dither": "amplitude_v=0.5"}
DSP = {"fft_width": 256, "emulated_latency_s": 0.05}
FAULTS = [
    {"channel": "AI3", "kind": "short_supply", "start_s": 0.3, "end_s": 0.9},
    {"channel": "AI1", "kind": "offset", "offset_v": 0.7, "start_s": 0.5},
    {"channel": "AO1", "kind": "gain", "factor": 0.5, "start_s": 0.2, "end_s": 0.8},
]
TOPIC = "/" + Keys("default").channel_truth
SUFFIXES = {"/plant/channels": TOPIC, "/plant/truth": "/" + Keys("default").truth, "/plant/events": "/" + Keys("default").plant_events}


def _recorded(path: Path) -> dict[str, list[tuple[dict[str, Any], dict[str, Any]]]]:
    """Topic (the plant's under rig ``default``: a co-simulation has its own rig id) -> [(message, the schema of its channel)], in log-time order."""
    out: dict[str, list[tuple[dict[str, Any], dict[str, Any]]]] = {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            assert schema is not None
            topic = next((t for s, t in SUFFIXES.items() if channel.topic.endswith(s)), channel.topic)
            out.setdefault(topic, []).append((json.loads(message.data), json.loads(schema.data)))
    return out


def _run(tmp: Path, faults: list[dict[str, Any]] | None) -> tuple[dict[str, list[tuple[dict[str, Any], dict[str, Any]]]], dict[str, np.ndarray]]:
    scenario = json.dumps({"commands": [], "channel_faults": faults}) if faults is not None else ""
    run_cosim(controller=dict(CONTROLLER), dsp=dict(DSP), plant={"scenario": scenario, "truth_record": str(tmp / "run")}, record=str(tmp / "run.mcap"))
    with np.load(tmp / "run.truth.npz") as z:
        truth = {k: z[k] for k in z.files}
    return _recorded(tmp / "run.mcap"), truth


def test_a_faulted_cosimulation_records_the_channel_truth_of_its_truth_file(tmp_path: Path) -> None:
    topics, truth = _run(tmp_path, FAULTS)
    recorded = topics[TOPIC]
    ground = [m for m, _ in topics["/" + Keys("default").truth]]
    assert len(recorded) == len(ground) > 20  # one beside each ground truth, at the truth rate
    for message, schema in recorded:
        jsonschema.validate(message, schema)
        ChannelTruth.model_validate(message)
    assert [m["sim_time_s"] for m, _ in recorded] == [g["sim_time_s"] for g in ground]

    t_ad = truth["channel_ad_time_s"]
    da_rows = {
        (float(t), tuple(c), tuple(a))
        for t, c, a in zip(truth["channel_da_time_s"], truth["channel_da_commanded_v"].tolist(), truth["channel_da_applied_v"].tolist(), strict=True)
    }
    described = {e["detail"] for e, _ in topics["/" + Keys("default").plant_events] if e["kind"] == "channel_fault"}
    assert len(described) == 3
    compared = 0
    for m, _ in recorded:
        rows = np.flatnonzero(t_ad == m["sim_time_s"])  # the same float: the conversion of this SYNC
        assert rows.size == 1, m["sim_time_s"]
        r = int(rows[0])
        assert m["ai_true_v"] == truth["channel_ad_true_v"][r].tolist()
        assert m["ai_faulted_v"] == truth["channel_ad_faulted_v"][r].tolist()
        assert m["ai_saturated"] == truth["channel_ad_saturated"][r].tolist()
        if m["ao_time_s"] is not None:
            assert m["ao_time_s"] <= m["sim_time_s"]
            assert (m["ao_time_s"], tuple(m["ao_commanded_v"]), tuple(m["ao_applied_v"])) in da_rows
        t = m["sim_time_s"]
        acting = [f for f in FAULTS if t + 1e-9 >= f["start_s"] and ("end_s" not in f or t + 1e-9 < f["end_s"])]
        assert len(m["active_faults"]) == len(acting) and set(m["active_faults"]) <= described
        assert all(any(d.startswith(f"{f['channel']} {f['kind']}") for d in m["active_faults"]) for f in acting)
        compared += 1
    assert compared == len(recorded)

    shorted = [m for m, _ in recorded if 0.3 <= m["sim_time_s"] < 0.9 - 1e-9]
    assert shorted and all(m["ai_faulted_v"][2] == 15.0 and m["ai_saturated"][2] for m in shorted)  # the rail, beyond full scale
    assert all(m["ai_faulted_v"][2] == m["ai_true_v"][2] for m, _ in recorded if m["sim_time_s"] < 0.3 - 1e-9)
    halved = [m for m, _ in recorded if m["ao_time_s"] is not None and 0.2 + 1e-9 < m["ao_time_s"] < 0.8 - 1e-9]
    assert halved and all(m["ao_applied_v"][0] == m["ao_commanded_v"][0] * 0.5 for m in halved)
    assert any(m["ao_commanded_v"][0] != 0.0 for m in halved)  # the dither moves the valve

    groups = mf4_channels.message_groups(TOPIC, "ralf.ChannelTruth", [m for m, _ in recorded], [m["sim_time_s"] for m, _ in recorded], {})
    columns = {c.name: c for g in groups for c in g.columns}
    rows = np.searchsorted(t_ad, [m["sim_time_s"] for m, _ in recorded])
    assert np.array_equal(columns["plant.channels.ai_faulted_3"].values, truth["channel_ad_faulted_v"][rows, 2])
    assert columns["plant.channels.ai_saturated_3"].values.dtype == np.uint8


def test_without_channel_faults_nothing_new_is_published(tmp_path: Path) -> None:
    topics, truth = _run(tmp_path, None)
    assert TOPIC not in topics and "/" + Keys("default").truth in topics
    assert not [k for k in truth if k.startswith("channel_")]


def test_a_side_without_faults_is_null_and_the_live_view_offers_the_topic() -> None:
    settings = load_settings(
        PlantSettings,
        {"scenario": json.dumps({"channel_faults": [{"channel": "AO2", "kind": "open", "start_s": 0.01}]}), "clock": "lockstep"},
    )
    out: list[ChannelTruth] = []
    app = PlantApplication(settings, publish_truth=lambda _m: None, publish_channel_truth=out.append)
    app.on_sync(0)
    app.flush_side_channels()
    for _ in range(20):
        app.on_output_values(1.0, 2.0)
        app.on_sync(0)
        app.flush_side_channels()
    assert out[0].ai_true_v is None and out[0].ao_time_s is None and out[0].active_faults == ()
    assert out[-1].ai_true_v is None and out[-1].ao_commanded_v == (1.0, 2.0) and out[-1].ao_applied_v == (1.0, 0.0)
    assert out[-1].active_faults == ("AO2 open from 0.01 s",)
    titles = {topic: schema["title"] for topic, schema in rig_topics("default")}
    assert titles[TOPIC] == "ralf.ChannelTruth"


@pytest.mark.parametrize("bad", [{"ai_true_v": [1.0, 2.0]}, {"ao_applied_v": [float("inf"), 0.0]}, {"active_faults": ["x" * 2001]}])
def test_a_bad_channel_truth_is_refused(bad: dict[str, Any]) -> None:
    with pytest.raises(ValueError):
        ChannelTruth.model_validate({"seq": 0, "sim_time_s": 0.0, **bad})


@pytest.mark.timeout(300)
@pytest.mark.parametrize(("clock", "processes"), [("cosim", False), ("lockstep", False), ("lockstep", True)])
def test_the_run_record_keeps_the_channel_truth(clock: str, processes: bool, tmp_path: Path) -> None:
    """The rig's run record: from the recording (co-simulation) or the test port over zenoh
    (the lockstep rig in one process and in three, the plant service's own publisher)."""
    from workbench.hil import HilRig

    rig = HilRig(clock=clock, processes=processes, outputs=tmp_path if processes else None, controller={"tf_download_samples": 0})  # type: ignore[arg-type]
    rig.fiu.short("AI3", to="supply", at_s=0.3, for_s=0.3)
    try:
        record = rig.run(1.0)
    finally:
        rig.close()
    assert record.error is None
    detail = next(e.detail for e in record.events if e.kind == "channel_fault")
    truth_times = {t.sim_time_s for t in record.truth}
    assert len(record.channel_truth) > 10 and {m.sim_time_s for m in record.channel_truth} <= truth_times
    assert record.channel_truth[0].ao_time_s is None and record.channel_truth[0].ao_commanded_v is None  # no valve fault
    for m in record.channel_truth:
        assert m.ai_true_v is not None and m.ai_faulted_v is not None and m.ai_saturated is not None
        on = 0.3 <= m.sim_time_s + 1e-9 < 0.6
        assert m.active_faults == ((detail,) if on else ())
        assert (m.ai_faulted_v[2], m.ai_saturated[2]) == ((15.0, True) if on else (m.ai_true_v[2], False))
    assert any(0.3 <= m.sim_time_s < 0.6 for m in record.channel_truth)


def test_a_recorded_channel_fault_command_has_its_mf4_kind() -> None:
    """A fault sent to a running rig is a scenario command of kind ``channel_fault`` in its recording."""
    from protocol.channel_faults import ChannelFault
    from protocol.messages import ScenarioCommand, encode

    cmd = ScenarioCommand(seq=0, sim_time_s=0.0, kind="channel_fault", channel_fault=ChannelFault(channel="AI3", kind="short_ground"))
    row = json.loads(encode(cmd))
    (group,) = mf4_channels.message_groups("/ralf/r/plant/scenario", "ralf.ScenarioCommand", [row], [0.0], {})
    kind = next(c for c in group.columns if c.name == "plant.scenario.kind")
    assert kind.states[int(kind.values[0])] == "channel_fault"
