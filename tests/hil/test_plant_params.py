"""The plant's parameters on the shared parameter path (docs/calibration.md,
"The plant's parameters"): a scripted payload change is applied before the
first SYNC at or after its time, recorded as a ``ParamChanged`` on
``plant/param_changes`` and listed in the run record; the co-simulation, the
one-process and the three-process lockstep rigs take it at the same SYNC and
give the same bits; bad changes are one line before anything runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocol.errors import ConfigError
from workbench.hil import HilRig, RigRunError
from workbench.recording.reader import Recording

DSP = {"fft_width": 256}
TS = 0.005
CONTROLLER = {"duration_s": 1.5, "tf_download_samples": 0}
TAKEN = [{"sim_time_s": 161 * TS, "kind": "schedule", "fields": {"payload": 1.0}, "who": "schedule"}]


def _attached(rec: object) -> tuple[np.ndarray, np.ndarray]:
    truth = rec.truth  # type: ignore[attr-defined]
    return np.array([t.sim_time_s for t in truth]), np.array([t.payload_attached for t in truth])


def _rig(tmp_path: Path, **kw: object) -> HilRig:
    rig = HilRig(controller=dict(CONTROLLER), dsp_settings=dict(DSP), plant_settings={"truth_rate_hz": 200.0}, workdir=tmp_path, **kw)  # type: ignore[arg-type]
    rig.param.set("plant.payload", 1.0, at_s=0.8012)  # between SYNCs 160 and 161: from SYNC 161
    return rig


def test_a_scheduled_payload_is_taken_at_its_first_sync_and_recorded(tmp_path: Path) -> None:
    rec = _rig(tmp_path).run()
    assert rec.error is None, rec.error
    assert rec.plant_param_changes == TAKEN
    assert rec.param_changes == []  # the controller's list: the plant's changes are the plant's
    t, attached = _attached(rec)
    assert not attached[t <= 161 * TS - TS / 2].any() and attached[t >= 161 * TS + TS / 2].all()  # the step of SYNC 161 has it
    recorded = Recording.load(rec.recording, only=("plant/param_changes", "plant/events"))  # type: ignore[arg-type]
    (event,) = recorded.data("plant/param_changes")
    assert (event["tick"], event["sim_time_s"], event["kind"], event["who"], event["fields"]) == (161, 161 * TS, "schedule", "schedule", {"plant.payload": 1.0})
    assert [e["detail"] for e in recorded.data("plant/events") if e["kind"] == "payload"] == ["payload attached by the parameter schedule at 0.805 s"]
    assert rec.health["plant"].counters["param_changes_applied"] == 1


def test_a_run_without_a_plant_schedule_publishes_nothing_new(tmp_path: Path) -> None:
    rec = HilRig(controller={"duration_s": 0.3, "tf_download_samples": 0}, dsp_settings=dict(DSP), workdir=tmp_path).run()
    assert rec.plant_param_changes == []
    assert not any(k.startswith("param_") for k in rec.health["plant"].counters)
    assert "plant/param_changes" not in " ".join(Recording.load(rec.recording).topics())  # type: ignore[arg-type]


def test_the_cosimulation_and_the_one_process_lockstep_rig_give_the_same_bits(tmp_path: Path) -> None:
    co = _rig(tmp_path / "co").run()
    one = _rig(tmp_path / "one", clock="lockstep").run()
    assert one.error is None, one.error
    assert one.plant_param_changes == co.plant_param_changes == TAKEN
    for name, column in co.columns.items():
        assert np.array_equal(one.columns[name], column, equal_nan=True), name
    assert [t.model_dump(exclude={"wall_time_s", "seq"}) for t in one.truth] == [t.model_dump(exclude={"wall_time_s", "seq"}) for t in co.truth]


def test_bad_plant_changes_are_one_line_before_the_run(tmp_path: Path) -> None:
    rig = HilRig(controller={"duration_s": 0.3}, workdir=tmp_path)
    with pytest.raises(ConfigError, match=r"^plant\.payload = 2\.0 refused: outside its limits 0 \.\. 1$"):
        rig.param.set("plant.payload", 2.0)
    with pytest.raises(ConfigError, match=r"^plant\.payload = 0\.5 refused: not one of its whole steps$"):
        rig.param.set("plant.payload", 0.5)
    with pytest.raises(ConfigError, match=r"^no parameter 'plant\.mass' \(known: plant\.payload\)$"):
        rig.param.set("plant.mass", 1.0)
    assert len(rig.param) == 0
    # the plant's own setting, checked by the plant when the run starts (the same path's checks)
    bad = HilRig(controller={"duration_s": 0.3}, plant_settings={"param_schedule": '[{"name": "plant.payload", "value": 3}]'}, workdir=tmp_path)
    with pytest.raises(RigRunError, match=r"param_schedule: plant\.payload at 0 s: plant\.payload = 3 refused: outside its limits 0 \.\. 1"):
        bad.run()


@pytest.mark.rig
@pytest.mark.timeout(300)
def test_three_processes_lockstep_take_the_plant_schedule_as_the_cosimulation_does(tmp_path: Path) -> None:
    """The schedule travels in the plant's settings to its process: the same SYNC, the same bits."""
    runs = []
    for name, processes, clock in (("three", True, "lockstep"), ("co", False, "cosim")):
        rig = _rig(tmp_path, clock=clock, processes=processes, name=name, outputs=tmp_path)
        try:
            runs.append(rig.run())
        finally:
            rig.close()
    three, co = runs
    assert three.error is None, three.error
    assert three.plant_param_changes == co.plant_param_changes == TAKEN
    for name, column in co.columns.items():
        assert np.array_equal(three.columns[name], column, equal_nan=True), name


def test_ralf_hil_param_changes_the_payload_of_a_running_rig(tmp_path: Path) -> None:
    """``ralf-hil param``'s functions on the plant's own keys (the rig's in-process session): the
    table, a tester's change taken at a SYNC and in the record, refusals answered with nothing changed."""
    from protocol.keys import Keys, param_keys
    from workbench.param_cli import query_table, send_set

    rig = HilRig(
        clock="lockstep",
        controller={"duration_s": 3600.0, "tf_download_samples": 0},
        plant_settings={"param_commands": True, "param_write_roles": "tester", "truth_rate_hz": 200.0},
        dsp_settings=dict(DSP),
        workdir=tmp_path,
    )
    rig.start()
    try:
        session, keys = rig._session, param_keys(Keys(rig.rig_id), "plant")  # noqa: SLF001 - the rig's own session
        table = query_table(session, keys, 20.0)
        assert table is not None and [(p.name, p.lower, p.upper, p.value) for p in table.params] == [("plant.payload", 0.0, 1.0, 0.0)]
        assert table.write_roles == ("tester",)
        refused = send_set(session, keys, "tool", "plant.payload", 1.0, 20.0)
        assert refused is not None and not refused.accepted and "the tool role may not change parameters" in refused.reason
        refused = send_set(session, keys, "tester", "plant.payload", 2.0, 20.0)
        assert refused is not None and not refused.accepted and refused.reason == "plant.payload = 2 refused: outside its limits 0 .. 1"
        unknown = send_set(session, keys, "tester", "controller.kp1", 1.0, 20.0)  # the controller's parameter on the plant's key
        assert unknown is not None and not unknown.accepted and "no parameter 'controller.kp1'" in unknown.reason
        taken = send_set(session, keys, "tester", "plant.payload", 1.0, 20.0)
        assert taken is not None and taken.accepted and taken.name == "plant.payload" and taken.value == 1.0
        table = query_table(session, keys, 20.0)
        assert table is not None and table.params[0].value == 1.0
    finally:
        rig.close()
    rec = rig.wait(60)
    assert [(c["kind"], c["who"], c["fields"]) for c in rec.plant_param_changes] == [("param", "tester", {"payload": 1.0})]
    assert rec.plant_param_changes[0]["sim_time_s"] == taken.sim_time_s
    counters = rec.health["plant"].counters
    assert counters["param_sets_refused"] == 3 and counters["param_changes_applied"] == 1
    t, attached = _attached(rec)
    assert not attached[t < taken.sim_time_s].any() and attached[t >= taken.sim_time_s + TS].all()


def test_an_xcp_write_takes_the_same_path(tmp_path: Path) -> None:
    """A pyxcp master writes the plant's payload: applied before the next SYNC's step, listed in the
    run record and published as a ``ParamChanged`` (kind ``xcp``) on ``plant/param_changes`` (the rig's test port
    hears it; a one-process run is not recorded, the co-simulation's recording is checked above)."""
    import socket

    from plant_emulator.xcp_table import plant_layout
    from tests.xcp.rig_client import free_port, master, wait_for

    port = free_port(socket.SOCK_DGRAM)
    a2l = tmp_path / "plant.a2l"
    rig = HilRig(
        clock="lockstep",
        controller={"duration_s": 3600.0, "tf_download_samples": 0},
        plant_settings={"xcp_udp_port": port, "xcp_a2l": str(a2l), "truth_rate_hz": 200.0},
        dsp_settings=dict(DSP),
        workdir=tmp_path,
    )
    rig.start()
    try:
        assert wait_for(a2l.exists, 120), "the plant did not come up"
        with master(port, "UDP") as x:
            x.shortDownload(plant_layout().by_name["payload"].address, 0, b"\x01")
        assert wait_for(lambda: any(t.payload_attached for t in rig.plant.truth), 60)
    finally:
        rig.close()
    rec = rig.wait(60)
    ((change),) = rec.plant_param_changes
    assert (change["kind"], change["who"], change["fields"]) == ("xcp", "xcp master", {"payload": 1.0})
    (event,) = rig.plant.param_changes  # heard on plant/param_changes
    assert (event.kind, event.who, event.fields, event.sim_time_s) == ("xcp", "xcp master", {"plant.payload": 1.0}, change["sim_time_s"])
    assert event.tick * TS == change["sim_time_s"]
    t, attached = _attached(rec)
    assert not attached[t < change["sim_time_s"]].any() and attached[t >= change["sim_time_s"] + TS].all()
    assert rec.health["plant"].counters["xcp_payload_writes_applied"] == 1
