"""A session that claims a node's zenoh id cannot keep the node out: a
node stopped (SIGSTOP) until its links' lease has expired, a session with
the tool's certificate and password claiming its id linked to the other
nodes meanwhile, the node resumed (SIGCONT): the node finds itself alone,
gives the id up, links again under a new one and its messages reach the
other nodes while the claimer still holds the old id
(service_kit/relink.py). The DSP is tried beside in-process sessions of
the other two (its flags carry its id); the controller and the plant in a
real-time rig of three processes, whose run goes on through the move and
ends cleanly. The decision is also checked alone, on an injected clock (no
timing)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from protocol.messages import ConfigChange, encode
from service_kit.relink import ALONE_S, MAX_BACKOFF_S, RelinkWatch, move_to_new_session
from tests.hardening.zenoh_rig import SERVICES, PeerRig, attacker, wait_peers
from workbench.launcher import ServiceProcess, start_service, stop_service


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


class _Handle:
    def __init__(self, session: _FakeZenoh, key: str) -> None:
        self.session, self.key = session, key

    def put(self, payload: bytes, **_: Any) -> None:
        self.session.sent.append((self.key, payload))

    def undeclare(self) -> None:
        self.session.undeclared += 1


class _FakeZenoh:
    """What a node's parts declare on a zenoh session, recorded."""

    def __init__(self, name: str, log: list[str]) -> None:
        self.name, self.log = name, log
        self.info = self
        self.sent: list[tuple[str, bytes]] = []
        self.undeclared = 0

    def zid(self) -> str:
        return self.name

    def declare_publisher(self, key: str, **_: Any) -> _Handle:
        return _Handle(self, key)

    def declare_subscriber(self, key: str, *_: Any, **__: Any) -> _Handle:
        return _Handle(self, key)

    def liveliness(self) -> Any:
        return type("Liveliness", (), {"declare_token": lambda _, key: _Handle(self, key), "declare_subscriber": lambda _, key, *a, **k: _Handle(self, key)})()

    def close(self) -> None:
        self.log.append(f"close {self.name}")


class _Part:
    def __init__(self, name: str, log: list[str]) -> None:
        self.name, self.log = name, log
        self.out_lock = threading.Lock()

    def unbind(self) -> None:
        assert self.out_lock.locked()
        self.log.append(f"unbind {self.name}")

    def bind(self, session: Any) -> None:
        assert self.out_lock.locked()
        self.log.append(f"bind {self.name} {session.name}")


def test_a_move_holds_every_part_and_a_failed_open_is_tried_again() -> None:
    log: list[str] = []
    parts = [_Part("a", log), _Part("b", log)]
    opened: Iterator[OSError | _FakeZenoh] = iter([OSError("port in use"), _FakeZenoh("s1", log)])

    def open_session() -> Any:
        got = next(opened)
        if isinstance(got, Exception):
            log.append("open failed")
            raise got
        log.append(f"open {got.name}")
        return got

    old = _FakeZenoh("s0", log)
    with pytest.raises(OSError):
        move_to_new_session(open_session, parts, old)
    assert log == ["unbind a", "unbind b", "close s0", "open failed"] and not any(p.out_lock.locked() for p in parts)
    log.clear()
    new = move_to_new_session(open_session, parts, old)  # the watch tries again with the session it still holds
    assert new.name == "s1" and log == ["unbind a", "unbind b", "close s0", "open s1", "bind a s1", "bind b s1"]


def test_the_controller_and_the_plant_never_wait_for_a_move() -> None:
    """While a move holds a port's lock, what the control loop or the node
    thread sends is dropped at once and counted; after it, it goes out on
    the new session."""
    from controller.dsp_port import ZenohDspPort
    from plant_emulator.service import PlantTestPort
    from protocol.messages import GroundTruth
    from protocol.settings import PlantSettings

    log: list[str] = []
    first, second = _FakeZenoh("s0", log), _FakeZenoh("s1", log)
    controller = ZenohDspPort(first, "r")  # type: ignore[arg-type]
    plant = PlantTestPort(PlantSettings(rig_id="r"), first)  # type: ignore[arg-type]
    truth = GroundTruth(
        seq=0,
        sim_time_s=0.0,
        modal_frequencies_hz=(1.0,),
        damping_ratios=(0.1,),
        deflections_in=(0.0, 0.0),
        theta_rad=(0.0, 0.0),
        tip_in=(0.0, 0.0),
        payload_attached=False,
        valves_held=False,
    )
    for port in (controller, plant):
        with port.out_lock:  # a move under way
            port.unbind()
            if port is controller:
                controller.send_batch(b"batch")
            else:
                plant.publish_truth(truth)
            assert port.dropped_moving == 1
            port.bind(second)  # type: ignore[arg-type]
    controller.send_batch(b"batch")
    plant.publish_truth(truth)
    assert first.sent == [] and [k for k, _ in second.sent] == ["ralf/r/dsp/batch", "ralf/r/plant/truth"]
    assert controller.dropped_moving == plant.dropped_moving == 1


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


def _peers(rig: PeerRig) -> set[str]:
    """The zenoh ids the launcher's node (every service links to it) is linked to."""
    return {str(z) for z in rig.observer.session.info.peers_zid()}


def _health_of(rig: PeerRig, node: str, start: int) -> int:
    """Health messages of ``node`` the launcher's node received since ``start``."""
    tap = rig.taps["launcher"]
    with tap.cond:
        return sum(1 for k, kind, _, _ in tap.got[start:] if k == rig.keys.health(node) and kind == "sample:put")


@pytest.mark.rig
@pytest.mark.timeout(240)
@pytest.mark.parametrize("node", ["controller", "plant"])
def test_a_claimed_id_does_not_keep_the_controller_or_the_plant_out(node: str, tmp_path: Path) -> None:
    rig = PeerRig.start(f"idclaim-{node[0]}{zlib.crc32(str(tmp_path).encode()) % 100000}", tmp_path, leave_out=SERVICES)
    # the stop freezes one end of the CAN link for seconds: the controller waits for the plant's heartbeat, it does not end the run
    rig.plan.service_env["controller"]["RALF_TIMEOUTS"] = "plant_heartbeat_s=60"
    # a plant resumed after seconds reads the SYNCs and RPDOs queued in its socket meanwhile and reports them as a second
    # master's (counter going back, two RPDO1 in a period): warned, not the run's end, which is not the subject here
    rig.plan.service_env["controller"]["RALF_POLICIES"] = "can_conflict=warn"
    for name in SERVICES:
        rig.plan.service_env[name]["RALF_LOG_LEVEL"] = "INFO"
    procs: dict[str, ServiceProcess] = {}
    claimer = None
    observer = rig.observer

    def logs() -> str:
        return "\n".join(f"--- {n}\n{p.log_path.read_text()[-2500:]}" for n, p in procs.items())

    def ticks() -> int:
        return observer.status.ticks if observer.status is not None else 0

    try:
        for name in ("dsp", "plant", "controller"):
            procs[name] = start_service(rig.plan, name, tmp_path / "logs")
        assert _wait(lambda: ticks() > 200 and len(_peers(rig)) == len(SERVICES), 120.0), logs()
        before = _peers(rig)
        os.kill(procs[node].popen.pid, signal.SIGSTOP)
        try:
            assert _wait(lambda: len(_peers(rig)) == len(SERVICES) - 1, 30.0), logs()  # its lease expired
            (claimed,) = before - _peers(rig)
            others = [f"tls/127.0.0.1:{rig.plan.service_ports[n]}" for n in SERVICES if n != node]
            claimer = attacker("tool", rig, endpoints=[rig.plan.zenoh_endpoint, *others], zid=claimed)
            wait_peers(claimer, len(SERVICES))
            start = len(rig.taps["launcher"].got)
        finally:
            os.kill(procs[node].popen.pid, signal.SIGCONT)
        # back under a new id while the claimer holds the old one
        assert _wait(lambda: _health_of(rig, node, start) >= 2 and len(_peers(rig) - before) == 1, 60.0), logs()
        (new_id,) = _peers(rig) - before
        assert claimed in _peers(rig)  # the claimer still holds it
        resumed, interrupts = ticks(), observer.status.interrupts  # type: ignore[union-attr]
        # the loop runs on (the CAN side and the run unbroken) and the DSP still answers its batches
        assert _wait(lambda: ticks() > resumed + 400 and observer.status.interrupts > interrupts + 3, 60.0), logs()  # type: ignore[union-attr]
        assert _wait(lambda: observer.health[node].counters.get("zenoh_relinks", 0) >= 1, 10.0), observer.health[node]  # said in its health too
        text = procs[node].log_path.read_text()
        assert f"zenoh id {claimed} given up" in text and f"linking again as {new_id}" in text, logs()
    finally:
        if claimer is not None:
            claimer.close()
        codes = {name: stop_service(procs[name]) for name in ("controller", "plant", "dsp") if name in procs}
        rig.close()
    assert codes == {"controller": 0, "plant": 0, "dsp": 0}, logs()
