"""``rig.fiu`` (workbench/fiu.py): faults checked at once in one line, joined
to the plant's scenario before a run, published on the test port during a
one-process run and applied by the plant; a bad one on a running rig is
refused and counted, the rig unaffected."""

from __future__ import annotations

import json

import pytest

from protocol.messages import ScenarioCommand, decode, encode
from workbench.fiu import FaultError, build_fault, channel_fault_command, merge_scenario
from workbench.hil import HilRig


@pytest.mark.parametrize(
    ("call", "expected"),
    [
        (lambda f: f.short("AI9", to="ground"), "short_ground on AI9: channel: Input should be 'AI1'"),
        (lambda f: f.noise("AO1", sigma_v=0.1), "noise on AO1: 'noise' is not a fault of a D/A output (AO1); allowed: open, stuck"),
        (lambda f: f.offset("AI2", offset_v=99.0), "offset on AI2: offset_v: Input should be less than or equal to 20 (got 99.0)"),
        (lambda f: f.short("AI3", to="chassis"), "short on AI3: to='chassis'; allowed: ground, supply or another input"),
        (lambda f: f.short_between("AI3", "AI3"), "short_channels on AI3: short_channels needs another channel than AI3"),
        (lambda f: f.stuck("AI1", at_s=1.0, for_s=0.0), "stuck on AI1: for_s 0.0 must be positive"),
    ],
)
def test_a_bad_fault_is_one_line_naming_channel_kind_and_what_is_allowed(call, expected: str) -> None:
    rig = HilRig()
    with pytest.raises(FaultError) as err:
        call(rig.fiu)
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(expected), text
    assert rig.fiu.faults == []


def test_faults_given_before_the_run_join_the_plants_scenario_sections() -> None:
    rig = HilRig(plant_settings={"scenario": json.dumps([{"kind": "payload", "at_sim_time_s": 3, "payload_attached": True}])})
    rig.fiu.short("AI3", to="ground", at_s=5.0, for_s=2.0)
    rig.fiu.saturate("AO1", limit_v=2.0, at_s=1.0)
    merged = json.loads(rig.fiu.merge(rig.plant_settings)["scenario"])
    assert merged["commands"] == [{"kind": "payload", "at_sim_time_s": 3, "payload_attached": True}]
    assert merged["channel_faults"] == [
        {"channel": "AI3", "kind": "short_ground", "start_s": 5.0, "end_s": 7.0},
        {"channel": "AO1", "kind": "saturate", "start_s": 1.0, "limit_v": 2.0},
    ]
    assert merge_scenario({"channel_faults": [{"channel": "AI1", "kind": "stuck"}]}, [build_fault("AI2", "stuck")])["channel_faults"][0]["channel"] == "AI1"
    assert HilRig().fiu.merge({"seed": 3}) == {"seed": 3}  # no fault: the plant's settings unchanged


def test_a_channel_fault_command_round_trips_the_wire() -> None:
    cmd = channel_fault_command(build_fault("AI4", "noise", at_s=2.0, sigma_v=0.05, seed=3))
    back = decode(ScenarioCommand, encode(cmd))
    assert back.channel_fault == cmd.channel_fault and back.kind == "channel_fault"


def test_a_fault_given_before_a_cosim_run_reaches_the_plant_and_its_event() -> None:
    rig = HilRig(controller={"tf_download_samples": 0})
    rig.fiu.short("AI3", to="ground", at_s=0.5, for_s=0.25)
    record = rig.run(1.0)
    kinds = [(e.kind, e.detail) for e in record.events if e.kind.startswith("channel_fault")]
    assert kinds == [("channel_fault", "AI3 short_ground from 0.5 s until 0.75 s"), ("channel_fault_cleared", "AI3 short_ground from 0.5 s until 0.75 s")]
    words = record.columns["ai3_word"]
    assert (words[100:148] == 0).all() and (words[:99] != 0).any()  # samples at 0.505 .. 0.74 s read ground


@pytest.mark.timeout(300)
def test_during_a_lockstep_run_faults_go_out_on_the_test_port_and_bad_ones_are_refused() -> None:
    rig = HilRig(clock="lockstep", controller={"tf_download_samples": 0})
    rig.start(6.0)
    from protocol.keys import Keys

    rig._session.put(Keys(rig.rig_id).scenario, encode(channel_fault_command(build_fault("AI1", "stuck"))).replace(b'"AI1"', b'"AI7"'))
    rig.fiu.lost_bits("AI2", bits=11, at_s=0.0)  # valid for a 12-bit A/D ...
    rig.fiu.lost_bits("AI2", bits=15, at_s=0.0)  # ... this one only for a 16- or 20-bit one: the plant refuses it
    rig.fiu.offset("AI4", offset_v=1.0, at_s=5.0, for_s=0.5)
    record = rig.wait(240)
    assert record.error is None and record.ticks == 1200  # the rig unaffected
    events = [(e.kind, e.detail) for e in record.events if e.kind.startswith("channel_fault")]
    assert ("channel_fault", "AI4 offset offset_v=1.0 from 5 s until 5.5 s") in events
    assert ("channel_fault_cleared", "AI4 offset offset_v=1.0 from 5 s until 5.5 s") in events
    assert ("channel_fault", "AI2 lost_bits bits=11 from 0 s") in events
    counters = record.health["plant"].counters
    assert counters["in_scenario_undecodable"] == 1  # the bad channel, refused at the port
    assert counters["channel_faults_refused"] == 1
    assert ("channel_fault_refused", "AI2 lost_bits bits=15 from 0 s: lost_bits 15 leaves no bit of the 12-bit A/D") in events
    assert [f.kind for f in rig.fiu.sent] == ["lost_bits", "lost_bits", "offset"]
