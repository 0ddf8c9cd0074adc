"""The live view's parameter panel (workbench/live/params.py) against a running
one-process lockstep rig, through a WebSocket client written from the
Foxglove protocol's specification on plain ``websockets`` (no code shared with
the server): ``getParameters`` lists the controller's table, ``setParameters``
takes the controller's one path as the tool role (taken where the run lets
tools write, in the record from its tick; refused with a status otherwise,
counted, nothing changed)."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Iterator
from typing import Any

import pytest
import websockets
from websockets.typing import Subprotocol

from tests.live.ws_client import SUBPROTOCOLS
from workbench.hil import HilRig
from workbench.live.params import ParamPanel
from workbench.live.view import LiveView

DSP = {"fft_width": 256}


async def _exchange(
    url: str, requests: list[dict[str, Any]], timeout_s: float = 60.0
) -> tuple[dict[str, Any], dict[str, dict[str, Any]], list[dict[str, Any]]]:
    """serverInfo, the answers to ``requests`` by their id (sent one after the other), and the statuses seen."""
    answers: dict[str, dict[str, Any]] = {}
    statuses: list[dict[str, Any]] = []
    async with websockets.connect(url, subprotocols=[Subprotocol(p) for p in SUBPROTOCOLS], max_size=None) as ws:
        info: dict[str, Any] = {}
        deadline = time.monotonic() + timeout_s
        pending = list(requests)
        waiting: str | None = None
        while time.monotonic() < deadline and (pending or waiting is not None):
            if waiting is None and info and pending:
                request = pending.pop(0)
                waiting = request["id"]
                await ws.send(json.dumps(request))
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.01, deadline - time.monotonic()))
            except TimeoutError:
                break
            if not isinstance(frame, str):
                continue
            msg = json.loads(frame)
            if msg["op"] == "serverInfo":
                info = msg
            elif msg["op"] == "parameterValues" and msg.get("id") == waiting:
                answers[waiting] = msg
                waiting = None
            elif msg["op"] == "status":
                statuses.append(msg)
        return info, answers, statuses


def _values(answer: dict[str, Any]) -> dict[str, Any]:
    return {p["name"]: p.get("value") for p in answer["parameters"]}


@pytest.fixture
def panel_rig(request: pytest.FixtureRequest) -> Iterator[tuple[HilRig, LiveView]]:
    roles = request.param
    rig = HilRig(
        clock="lockstep",
        controller={"duration_s": 3600.0, "tf_download_samples": 0, "param_commands": True, "param_write_roles": roles},
        dsp_settings=dict(DSP),
    )
    rig.start()
    view = LiveView("127.0.0.1", 0, params=ParamPanel(rig.rig_id, rig._session, timeout_s=20.0))  # noqa: SLF001 - the rig's own session
    try:
        yield rig, view
    finally:
        view.close()
        rig.close()


@pytest.mark.parametrize("panel_rig", ["tester,tool"], indirect=True)
def test_the_panel_lists_the_table_and_a_set_is_in_the_record_from_its_tick(panel_rig: tuple[HilRig, LiveView]) -> None:
    rig, view = panel_rig
    info, answers, statuses = asyncio.run(
        _exchange(
            view.url,
            [
                {"op": "getParameters", "parameterNames": [], "id": "all"},
                {"op": "setParameters", "parameters": [{"name": "controller.kp1", "value": 2e6}], "id": "too-big"},
                {"op": "setParameters", "parameters": [{"name": "controller.kp1", "value": 15000.0}], "id": "set"},
                {"op": "getParameters", "parameterNames": ["controller.kp1"], "id": "one"},
            ],
        )
    )
    assert "parameters" in info["capabilities"]
    table = _values(answers["all"])
    assert list(table) == [f"controller.{n}" for n in ("kp1", "kp2", "ki1", "ki2")]  # no OATF in this run: its parameters have no value
    assert _values(answers["too-big"])["controller.kp1"] == table["controller.kp1"]  # refused: unchanged
    assert any("outside its limits 0 .. 1e+06 mV/rad" in s["message"] for s in statuses)
    assert _values(answers["set"])["controller.kp1"] == 15000.0 and _values(answers["one"]) == {"controller.kp1": 15000.0}
    assert (view.stats.param_sets_taken, view.stats.param_sets_refused) == (1, 1)
    rig.close()
    rec = rig.wait(60)
    assert [(c["kind"], c["who"], c["fields"]) for c in rec.param_changes] == [("param", "tool", {"kp1": 15000.0})]


@pytest.mark.parametrize("panel_rig", ["tester"], indirect=True)
def test_a_run_that_takes_no_tool_changes_refuses_the_panels_with_a_status(panel_rig: tuple[HilRig, LiveView]) -> None:
    rig, view = panel_rig
    _, answers, statuses = asyncio.run(
        _exchange(view.url, [{"op": "setParameters", "parameters": [{"name": "controller.kp1", "value": 15000.0}], "id": "set"}])
    )
    assert _values(answers["set"])["controller.kp1"] != 15000.0
    (status,) = [s for s in statuses if "refused" in s["message"]]
    assert "the tool role may not change parameters in this run (param_write_roles: tester)" in status["message"]
    assert view.stats.param_sets_refused == 1 and view.params is not None and view.params.refused == 1
    rig.close()
    assert rig.wait(60).param_changes == []
