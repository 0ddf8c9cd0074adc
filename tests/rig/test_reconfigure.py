"""Run-time commands: the batch size changes at the controller, the FFT width
at the DSP (history zeroed), while the rig runs."""

from __future__ import annotations

import json
import threading

import zenoh

from protocol.keys import Keys
from protocol.messages import ConfigChange, encode
from workbench.composition import InProcessRun, run_in_process


def test_batch_size_and_fft_width_change_while_running() -> None:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([]))
    session = zenoh.open(config)
    rig_id = "reconf-test"
    command = encode(ConfigChange(seq=0, sim_time_s=0.0, batch_size=40, fft_width=256))
    try:  # sent in the loop before tick 200 (same session: delivered before the put returns)
        run = run_in_process(
            controller={"duration_s": 12.0, "tf_download_samples": 0},
            common={"rig_id": rig_id},
            session=session,
            at_tick=(200, lambda: session.put(Keys(rig_id).controller_command, command)),
        )
    finally:
        session.close()
    assert run.result.counters["reconfigurations"] == 1
    assert run.controller.link.batch_size == 40
    assert run.dsp.identifier.fft_width == 256
    assert run.dsp.block.counters.config_changes == 2  # the run-start reset, then the command
    assert run.result.counters["samples_dropped"] == 0 and run.dsp.block.counters.samples_missing == 0


def test_reconfigure_tool_gets_the_dsp_acknowledgement_or_its_refusal() -> None:
    from workbench.cli import wait_for_ack

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([]))
    session = zenoh.open(config)
    rig_id = "reconf-ack"
    acks: list[object] = []

    def tool() -> None:
        acks.append(wait_for_ack(session, Keys(rig_id), ConfigChange(seq=0, sim_time_s=0.0, fft_width=256, request_id="t1"), 8.0))

    sent = threading.Event()
    seen = session.declare_subscriber(Keys(rig_id).controller_command, lambda _sample: sent.set())
    thread = threading.Thread(target=tool, name="reconfigure-tool")

    def start_tool() -> None:
        """Before tick 200: the tool starts and the loop waits until its command is in."""
        thread.start()
        assert sent.wait(30.0), "the tool sent nothing"

    try:
        run_in_process(
            controller={"duration_s": 12.0, "tf_download_samples": 0},
            dsp={"search_band_hz": (0.5, 40.0)},
            common={"rig_id": rig_id},
            session=session,
            at_tick=(200, start_tool),
        )
    finally:
        if thread.is_alive() or thread.ident is not None:
            thread.join(30.0)
        seen.undeclare()
        session.close()
    (ok,) = acks
    assert ok is not None and ok.accepted and ok.request_id == "t1" and ok.fft_width == 256


def _run_with_commands(rig_id: str, *commands: tuple[str, ConfigChange]) -> InProcessRun:
    """A lockstep run with ``commands`` (key suffix, change) put before tick 200 from a session without access rules."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([]))
    session = zenoh.open(config)
    keys = Keys(rig_id)

    def send() -> None:
        for suffix, change in commands:
            session.put(f"{keys.root}/{suffix}", encode(change))

    try:
        return run_in_process(controller={"duration_s": 4.0, "tf_download_samples": 0}, common={"rig_id": rig_id}, session=session, at_tick=(200, send))
    finally:
        session.close()


def test_a_test_knob_on_the_tools_command_key_changes_nothing() -> None:
    """The emulated latency is a test knob: on ``controller/command`` (the
    key ``ralf-hil reconfigure`` and every tool use) the whole command is
    refused and counted, and the DSP keeps its latency."""
    run = _run_with_commands("reconf-knob", ("controller/command", ConfigChange(seq=0, sim_time_s=0.0, emulated_latency_s=10.0, batch_size=40)))
    counters = run.result.counters
    assert counters["in_command_refused"] == 1 and counters["reconfigurations"] == 0 and counters["test_knob_changes"] == 0
    assert run.dsp.emulated_latency_s != 10.0 and run.controller.link.batch_size != 40
    assert run.result.config_changes == []
    assert run.health["controller"].counters["in_command_refused"] == 1
    from workbench.cli import config_changes_line

    assert config_changes_line(run.health["controller"].model_dump()) == "0 command(s) taken, 0 of them test knobs; 1 refused (a field their key does not take)"
    assert config_changes_line({"counters": {}}) is None


def test_the_testers_key_takes_the_knob_and_the_run_lists_the_change() -> None:
    run = _run_with_commands(
        "reconf-tester",
        ("controller/test_command", ConfigChange(seq=0, sim_time_s=0.0, emulated_latency_s=0.02)),
        ("controller/test_command", ConfigChange(seq=1, sim_time_s=0.0, reset=True)),
    )
    counters = run.result.counters
    assert counters["reconfigurations"] == 1 and counters["test_knob_changes"] == 1 and counters["in_test_command_refused"] == 1
    assert run.dsp.emulated_latency_s == 0.02
    (taken,) = run.result.config_changes
    assert taken.kind == "test_command" and taken.fields == {"emulated_latency_s": 0.02} and taken.sim_time_s > 0
    assert run.health["controller"].counters["test_knob_changes"] == 1
    from workbench.cli import config_changes_line

    line = config_changes_line(run.health["controller"].model_dump())  # the row of up's summary
    assert line == "1 command(s) taken, 1 of them test knobs; 1 refused (a field their key does not take)"
