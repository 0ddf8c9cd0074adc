"""Health is filed by the key it arrived on: a payload whose ``service``
names another service than its key is refused and counted, in ``up``'s
observer (the run summary) and in ``ralf-hil monitor``. A rig without
access rules, so the forgery can be published at all; loopback only."""

from __future__ import annotations

import json
import time
from collections.abc import Callable

import zenoh

from protocol.keys import Keys
from protocol.messages import Health, encode
from tests.hardening.zenoh_rig import base_config, wait_peers
from workbench.launcher import RigObserver, RigPlan, free_tcp_port
from workbench.monitor import RigWatch, health_key_service

FORGED = Health(seq=1, sim_time_s=0.0, service="controller", state="failed", counters={"deadline_misses": 999999})


def _wait(condition: Callable[[], bool], timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.02)
    return condition()


def _forge(endpoint: str, keys: Keys) -> None:
    session = zenoh.open(base_config(connect=[endpoint]))
    try:
        wait_peers(session, 1)
        publishers = [
            session.declare_publisher(k) for k in (keys.health("tool"), keys.health("plant"), keys.health("controller") + "x", keys.health("controller"))
        ]
        assert _wait(lambda: all(p.matching_status.matching for p in publishers)), "the observer's subscription never arrived"
        for publisher in publishers[:-1]:
            publisher.put(encode(FORGED))
        publishers[-1].put(encode(Health(seq=2, sim_time_s=1.0, service="controller")))
    finally:
        session.close()


def test_health_key_service_is_the_last_chunk() -> None:
    assert health_key_service("ralf/r/health/plant") == "plant"


def test_the_observer_files_health_by_its_key() -> None:
    plan = RigPlan.local(rig_id="health-filing")
    observer = RigObserver(plan)
    try:
        _forge(f"tcp/127.0.0.1:{plan.zenoh_port}", Keys(plan.rig_id))
        assert _wait(lambda: "controller" in observer.health and observer.health_refused == 3)
    finally:
        observer.close()
    assert set(observer.health) == {"controller"}
    assert observer.health["controller"].state == "running" and observer.health["controller"].seq == 2


def test_the_monitor_files_health_by_its_key() -> None:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    config = base_config(listen=[endpoint])
    config.insert_json5("mode", json.dumps("peer"))
    with RigWatch("health-filing-monitor", config) as watch:
        _forge(endpoint, Keys("health-filing-monitor"))
        assert _wait(lambda: "controller" in watch.health and watch.health_refused == 3)
        snap = watch.snapshot()
    assert snap["health_refused"] == 3
    assert snap["services"]["controller"]["health"]["state"] == "running"
    assert snap["services"]["plant"]["health"] is None and "tool" not in snap["services"]
