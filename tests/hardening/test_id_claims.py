"""A session that claims a node's zenoh id cannot keep the node out: the
DSP stopped (SIGSTOP) until its links' lease has expired, a session with
the tool's certificate and password claiming its id linked to the other
nodes meanwhile, the DSP resumed (SIGCONT): the DSP finds itself alone,
gives the id up, links again under a new one and its flags reach the
other nodes while the claimer still holds the old id
(service_kit/relink.py). The decision is also checked alone, on an
injected clock (no timing)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path
from typing import Any

import pytest

from protocol.messages import ConfigChange, encode
from service_kit.relink import ALONE_S, MAX_BACKOFF_S, RelinkWatch
from tests.hardening.zenoh_rig import PeerRig, attacker, wait_peers


class _Session:
    def __init__(self, name: str) -> None:
        self.name = name
        self.info = self

    def zid(self) -> str:
        return self.name


def test_a_node_takes_a_new_session_only_after_being_alone_having_been_linked() -> None:
    now = [0.0]
    links = {"s0": 0}
    made: list[str] = []

    def replace(old: Any) -> Any:
        made.append(f"s{len(made) + 1}")
        links[made[-1]] = 0
        return _Session(made[-1])

    watch = RelinkWatch(_Session("s0"), replace, clock=lambda: now[0], count_links=lambda s: links[s.name])
    for t in (0.0, 5.0, 50.0):  # never linked yet (the rig is starting): never
        now[0] = t
        assert not watch.check()
    links["s0"] = 2
    assert not watch.check()
    links["s0"] = 0
    now[0] = 51.0
    assert not watch.check()  # alone from now on
    now[0] = 51.0 + ALONE_S * 0.9
    assert not watch.check()
    now[0] = 51.0 + ALONE_S
    assert watch.check() and watch.session.name == "s1" and watch.relinks == 1
    now[0] += ALONE_S  # still alone: the next try waits twice as long
    assert not watch.check()
    now[0] += ALONE_S
    assert watch.check() and watch.session.name == "s2"
    for _ in range(20):
        now[0] += MAX_BACKOFF_S
        watch.check()
    links[watch.session.name] = 1  # linked again: the wait starts over
    assert not watch.check()
    links[watch.session.name] = 0
    now[0] += 0.5
    watch.check()
    now[0] += ALONE_S
    assert watch.check()


def _flags_from(rig: PeerRig, start: int) -> list[bytes]:
    """The attachments (board ids) of the DSP flags the launcher's node (an observer: it reads the whole rig) received since ``start``."""
    tap = rig.taps["launcher"]
    with tap.cond:
        return [a for k, kind, _, a in tap.got[start:] if k == rig.keys.flag and kind == "sample:put"]


def _wait(condition: Any, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return bool(condition())


@pytest.mark.rig
@pytest.mark.timeout(120)
def test_a_claimed_id_does_not_keep_the_dsp_out(tmp_path: Path) -> None:
    rig = PeerRig.start(f"idclaim-{zlib.crc32(str(tmp_path).encode()) % 100000}", tmp_path, leave_out=("dsp",))
    env = rig.plan.env_for("dsp")
    env["RALF_LOG_LEVEL"] = "INFO"
    log_path = tmp_path / "dsp.log"
    with log_path.open("w") as log_file:
        dsp = subprocess.Popen([sys.executable, "-m", "dsp_service"], env=env, stdout=log_file, stderr=subprocess.STDOUT, cwd=tmp_path)
    claimer = None
    try:
        controller = rig.sessions[1]  # plant, controller: the in-process nodes
        reset = encode(ConfigChange(seq=1, sim_time_s=0.0, reset=True))
        # the DSP serves once it hears its controller (a reset), then re-announces its empty block every 0.5 s
        assert _wait(lambda: controller.put(rig.keys.dsp_config, reset) or _flags_from(rig, 0), 60.0), log_path.read_text()[-2000:]
        board = _flags_from(rig, 0)[-1]
        os.kill(dsp.pid, signal.SIGSTOP)
        try:
            assert _wait(lambda: board.decode() not in {str(z) for z in controller.info.peers_zid()}, 30.0)  # its lease expired
            claimer = attacker("tool", rig, zid=board.decode())
            wait_peers(claimer, len(rig.endpoints))
            start = len(rig.taps["launcher"].got)
        finally:
            os.kill(dsp.pid, signal.SIGCONT)
        # back under a new id while the claimer holds the old one
        assert _wait(lambda: any(a != board for a in _flags_from(rig, start)), 30.0), log_path.read_text()[-3000:]
        assert all(a != board for a in _flags_from(rig, start))  # nothing under the claimed id: the claimer sends nothing, the DSP left it
    finally:
        if claimer is not None:
            claimer.close()
        dsp.terminate()
        try:
            dsp.wait(20)
        except subprocess.TimeoutExpired:
            dsp.kill()
        rig.close()
    text = log_path.read_text()
    assert f"zenoh id {board.decode()} given up" in text and "linking again as" in text, text[-3000:]
