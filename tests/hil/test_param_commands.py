"""``ralf-hil param`` against a running one-process lockstep rig (its
in-process zenoh session, as the command's own functions use a session):
the table listed with units, limits and values; a tester's change taken at
a tick and in the record from it; refusals (a role the run does not let
write, a value outside its limits, the OATF's guards) answered in one line
with nothing changed, and counted. The command line's own answers: bad
arguments exit 2, a rig that answers nothing exits 1 saying why."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator

import numpy as np
import pytest

from protocol.keys import Keys
from workbench.hil import HilRig
from workbench.param_cli import query_table, send_set

DSP = {"fft_width": 256}


@pytest.fixture(scope="module")
def running() -> Iterator[HilRig]:
    rig = HilRig(
        clock="lockstep",
        controller={"duration_s": 3600.0, "tf_download_samples": 0, "oatf_mode": "fixed", "param_commands": True, "param_write_roles": "tester"},
        dsp_settings=dict(DSP),
    )
    rig.start()
    try:
        yield rig
    finally:
        rig.close()


def _keys(rig: HilRig) -> Keys:
    return Keys(rig.rig_id)


def test_the_table_lists_every_parameter_with_its_limits_and_value(running: HilRig) -> None:
    table = query_table(running._session, _keys(running), 20.0)  # noqa: SLF001 - the rig's own session
    assert table is not None
    by_name = {p.name: p for p in table.params}
    assert list(by_name) == [f"controller.{n}" for n in ("kp1", "kp2", "ki1", "ki2", "oatf_frequency_hz", "oatf_zeta", "dither_amplitude_v")] + [
        f"controller.input_{n}" for n in ("extension_lo_in", "extension_hi_in", "stuck_samples", "extension_rate_v_s", "deflection_rate_v_s", "disagree_in")
    ]
    # a run without a dither or input monitors lists their parameters without a value
    assert [n for n, p in by_name.items() if p.value is None] == list(by_name)[6:]
    kp1 = by_name["controller.kp1"]
    assert (kp1.unit, kp1.lower, kp1.upper) == ("mV/rad", 0.0, 1e6)
    assert kp1.value is not None and kp1.value > 0
    assert by_name["controller.oatf_frequency_hz"].value == 4.4
    assert table.write_roles == ("tester",)


def test_a_testers_change_is_taken_at_a_tick_and_refusals_change_nothing(running: HilRig) -> None:
    session, keys = running._session, _keys(running)  # noqa: SLF001
    # a tool's change in a run that takes the tester's only
    refused = send_set(session, keys, "tool", "controller.kp1", 15000.0, 20.0)
    assert refused is not None and not refused.accepted
    assert refused.reason == "the tool role may not change parameters in this run (param_write_roles: tester)"
    # out of limits: the limit named
    refused = send_set(session, keys, "tester", "controller.kp1", 2e6, 20.0)
    assert refused is not None and not refused.accepted
    assert refused.reason == "controller.kp1 = 2e+06 mV/rad refused: outside its limits 0 .. 1e+06 mV/rad"
    # the OATF's guards: 0.5 Hz with the stage's kept delay
    refused = send_set(session, keys, "tester", "controller.oatf_frequency_hz", 0.5, 20.0)
    assert refused is not None and not refused.accepted and refused.reason.startswith("OATF design refused")
    unknown = send_set(session, keys, "tester", "controller.kp9", 1.0, 20.0)
    assert unknown is not None and not unknown.accepted and unknown.reason.startswith("no parameter 'controller.kp9' (known: controller.kp1,")
    table = query_table(session, keys, 20.0)
    assert table is not None and {p.name: p.value for p in table.params}["controller.kp1"] != 15000.0
    # taken: answered with the time of the first tick that uses it
    taken = send_set(session, keys, "tester", "controller.kp1", 15000.0, 20.0)
    assert taken is not None and taken.accepted, taken
    assert taken.value == 15000.0 and taken.sim_time_s > 0
    taken_i = send_set(session, keys, "tester", "controller.ki1", 0.0, 20.0)
    assert taken_i is not None and taken_i.accepted
    table = query_table(session, keys, 20.0)
    assert table is not None and {p.name: p.value for p in table.params}["controller.kp1"] == 15000.0
    service = running.controller_service
    deadline = time.monotonic() + 60
    while (service is None or service.tick < round(taken_i.sim_time_s / 0.005) + 50) and time.monotonic() < deadline:
        time.sleep(0.05)
        service = running.controller_service
    running.close()
    rec = running.wait(60)
    changes = [(c["kind"], c["who"], c["fields"]) for c in rec.param_changes]
    assert changes == [("param", "tester", {"kp1": 15000.0}), ("param", "tester", {"ki1": 0.0})]
    assert rec.param_changes[0]["sim_time_s"] == taken.sim_time_s
    assert rec.counters["param_sets_refused"] == 4 and rec.counters["param_changes_applied"] == 2
    k = round(taken_i.sim_time_s / 0.005)
    c, ticks = rec.columns, rec.columns["tick"]
    after = ticks >= k
    assert after.sum() >= 50
    np.testing.assert_allclose(c["pi1_v"][after], np.clip(15.0 * (c["phi_shaped1"] - c["phi1"]), -10, 10)[after], rtol=1e-12, atol=1e-15)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "workbench.cli", "param", *args], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("set", "controller.kp1"), "set needs a value"),
        (("set", "controller.kp1", "fast"), "'fast' is not a number"),
        (("set", "controller.kp1", "nan"), "'nan' is not a finite number"),
        (("get",), "get needs a parameter name"),
        (("list", "controller.kp1"), "list takes a board (controller, plant), not 'controller.kp1'"),
        (("get", "dsp.x"), "no board 'dsp' serves parameters"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(args: tuple[str, ...], needle: str) -> None:
    out = _cli(*args)
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and needle in out.stderr and "Traceback" not in out.stderr


def test_a_rig_that_answers_nothing_is_one_line_and_exit_1() -> None:
    out = _cli("set", "controller.kp1", "8000", "--rig-id", "nobody-here", "--timeout", "0.5")
    assert out.returncode == 1 and out.stderr.count("\n") == 1, out.stderr
    assert "no answer from the controller of rig 'nobody-here'" in out.stderr and "controller.param_commands=true" in out.stderr
    assert "controller.kp1 not changed" in out.stderr
