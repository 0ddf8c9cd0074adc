"""The compose rig's log check (.ci/compose_rig.py): ERROR and WARNING lines
of each container's log, in the rig's own format, zenoh's Rust format
(coloured or not) and anything else; an ERROR line fails the run, WARNING
lines are counted and reported."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def compose_rig() -> ModuleType:
    spec = importlib.util.spec_from_file_location("compose_rig", ROOT / ".ci" / "compose_rig.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["compose_rig"] = module
    spec.loader.exec_module(module)
    return module


CONTROLLER_LOG = """\
2026-12-03 05:12:01,100 controller INFO runtime: zenoh session open
2026-12-03 05:12:01,200 controller INFO controller: waiting for the plant node 1 on CAN udp_multicast (its boot-up or heartbeat)...
2026-12-03 05:12:02,300 controller WARNING controller.dsp_side: no DSP answered within 60.0 s; controlling without identification until it does
2026-12-03 05:12:03,000 controller INFO controller: timing verdict PASS (no WARNING, no ERROR: words inside an INFO message)
2026-12-03 05:12:40,000 controller INFO controller: run ended after 9475 ticks (47.38 s simulated): {'rx_errors': 0, 'tx_errors': 0}
2026-12-03 05:12:41,000 controller ERROR controller.zenoh_transport: Received a close message (reason INVALID) in response to an OpenSyn
"""

ZENOH_RAW = (
    "\x1b[2m2026-12-03T03:55:12.688809Z\x1b[0m \x1b[31mERROR\x1b[0m net-0 ThreadId(03) "
    "\x1b[2mzenoh_transport::unicast::establishment::open\x1b[0m\x1b[2m:\x1b[0m Received a close message (reason INVALID) "
    "in response to an OpenSyn at /build/zenoh/io/zenoh-transport/src/unicast/establishment/open.rs:526.\n"
    "\x1b[2m2026-12-03T04:02:07.378539Z\x1b[0m \x1b[33m WARN\x1b[0m ThreadId(01) \x1b[2mzenoh::net::runtime::orchestrator\x1b[0m: Link lost.\n"
    "2026-12-03T04:02:07.378539Z  WARN ThreadId(01) zenoh::net::runtime::orchestrator: Scouting delay elapsed before start conditions are met.\n"
    "2026-12-03T04:02:08.000000Z  INFO ThreadId(01) zenoh::net::runtime: Zenoh can be reached at: tcp/10.89.0.2:7447\n"
)

OTHER = """\
/opt/venv/lib/python3.11/multiprocessing/resource_tracker.py:254: UserWarning: resource_tracker: There appear to be 2 leaked semaphore objects
Traceback (most recent call last):
  File "/opt/venv/bin/ralf-dsp", line 8, in <module>
ValueError: something went wrong
ready: process 7
"""


def test_the_rig_format_is_judged_by_its_level_field(compose_rig: ModuleType) -> None:
    errors, warnings = compose_rig.log_problems(CONTROLLER_LOG)
    assert errors == [CONTROLLER_LOG.splitlines()[-1]]
    assert warnings == [CONTROLLER_LOG.splitlines()[2]]


def test_zenoh_rust_lines_coloured_or_not_are_judged_by_zenohs_level(compose_rig: ModuleType) -> None:
    errors, warnings = compose_rig.log_problems(ZENOH_RAW)
    assert len(errors) == 1 and "Received a close message" in errors[0] and "\x1b[" not in errors[0]
    assert len(warnings) == 1 and warnings[0].endswith("Link lost.")  # the routine start-up warning is INFO


def test_other_lines_tracebacks_and_python_warnings_count_by_their_words(compose_rig: ModuleType) -> None:
    errors, warnings = compose_rig.log_problems(OTHER)
    assert errors == ["Traceback (most recent call last):", "ValueError: something went wrong"]
    assert len(warnings) == 1 and "UserWarning" in warnings[0]


def test_a_clean_log_has_nothing(compose_rig: ModuleType) -> None:
    lines = CONTROLLER_LOG.splitlines()
    clean = "\n".join(lines[:2] + lines[3:-1])
    assert compose_rig.log_problems(clean) == ([], [])


def record(services: tuple[str, ...]) -> dict[str, Any]:
    return {
        "problems": [],
        "exit": dict.fromkeys(services, 0),
        "networks": {"zenoh-router": ["cabinet", "lab"], "dsp": ["lab"], "plant": ["cabinet"], "controller": ["cabinet"]},
        "healthy_after_s": dict.fromkeys(services, 4.0),
        "bad_input": {},
        "run_s": 45,
        "monitor": {},
        "cold_start": {"compiled": 3},
        "load_avg_before": 1.0,
        "load_avg_after": 1.5,
    }


def test_an_error_line_fails_the_run_and_warnings_are_counted(compose_rig: ModuleType, tmp_path: Path) -> None:
    (tmp_path / "logs").mkdir()
    (tmp_path / "run.json").write_text(json.dumps(record(compose_rig.SERVICES)))
    for service in compose_rig.SERVICES:
        (tmp_path / "logs" / f"{service}.log").write_text(
            f"2026-12-03 05:12:00,000 {service} INFO x: ready in 1.00 s (process start to ready); numba kernels: 1 loaded from cache, 0 compiled\n"
        )
    (tmp_path / "logs" / "controller.log").write_text(CONTROLLER_LOG)
    (tmp_path / "logs" / "dsp.log").write_text((tmp_path / "logs" / "dsp.log").read_text() + ZENOH_RAW)
    result = compose_rig.evaluate(tmp_path)
    counts = {s: (n["errors"], n["warnings"]) for s, n in result["log_lines"].items()}
    assert counts == {"zenoh-router": (0, 0), "dsp": (1, 1), "plant": (0, 0), "controller": (1, 1)}
    log_failures = [f for f in result["failures"] if "ERROR line" in f]
    assert len(log_failures) == 2 and any("Received a close message" in f for f in log_failures)
    assert result["verdict"] == "fail"
    compose_rig.write_results({**result, "stages": {"rig_s": 60.0}, "date": "2026-12-03", "machine": "test"}, tmp_path / "out")
    readme = (tmp_path / "out" / "README.md").read_text()
    assert "| controller | 1 | 1 | `2026-12-03 05:12:02,300 controller WARNING" in readme
    assert "| plant | 0 | 0 | - |" in readme


def _healthy(compose_rig: ModuleType, work: Path) -> None:
    """A record and logs of a run that passes every check."""
    data = record(compose_rig.SERVICES)
    data["monitor"] = {
        "snapshot": {"services": {"controller": {"health": {"latencies": {"hop_sync_to_tpdo": {"count": 9, "p50": 1e-3, "p99": 2e-3, "max": 3e-3}}}}}}
    }
    data["bad_input"] = {
        "missing_credentials": {"exit": 2, "line": "No such file"},
        "wrong_password": {"exit": 1, "line": "the router refused the session"},
        "foreign_certificate": {"exit": 1, "line": "the router refused the session"},
        "router_not_up": {"exit": 1, "line": "nothing answered"},
    }
    (work / "logs").mkdir()
    (work / "run.json").write_text(json.dumps(data))
    for service in compose_rig.SERVICES:
        (work / "logs" / f"{service}.log").write_text(
            f"2026-12-03 05:12:00,000 {service} INFO x: ready in 1.00 s (process start to ready); numba kernels: 1 loaded from cache, 0 compiled\n"
        )
    with open(work / "logs" / "zenoh-router.log", "a") as fh:
        fh.write("2026-12-03 05:12:00,100 router INFO router: zenoh router 1f2e listening on tls/0.0.0.0:7447\n")
    with open(work / "logs" / "controller.log", "a") as fh:
        fh.write(
            "2026-12-03 05:12:40,000 controller INFO controller: run ended after 9475 ticks (47.38 s simulated): {'batches_sent': 310, 'interrupts': 309}\n"
        )


def test_a_sound_run_passes_and_says_over_how_many_checks(compose_rig: ModuleType, tmp_path: Path) -> None:
    _healthy(compose_rig, tmp_path)
    result = compose_rig.evaluate(tmp_path)
    assert result["failures"] == [] and result["verdict"] == "pass"
    assert result["checks"] == 4 * 3 + 3 * 2 + 4 + 1 + 1 + 3 + 1 + 1 + 4 >= result["min_checks"] == 27


def test_a_check_over_nothing_does_not_pass(compose_rig: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With no service to look at (an empty service list) every failure-finding loop finds nothing:
    the run is judged on too few checks and fails."""
    _healthy(compose_rig, tmp_path)
    monkeypatch.setattr(compose_rig, "SERVICES", ())
    monkeypatch.setattr(compose_rig, "NETWORKS", {})
    (tmp_path / "logs" / "controller.log").unlink()
    monkeypatch.setattr(compose_rig, "RUN_ENDED", compose_rig.re.compile("x^"))
    result = compose_rig.evaluate(tmp_path)
    assert result["verdict"] == "fail" and result["checks"] < result["min_checks"]
    assert f"too few checks: {result['checks']} made, at least 27 needed to judge the run" in result["failures"]
