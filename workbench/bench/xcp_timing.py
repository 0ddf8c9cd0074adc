"""What XCP costs the real-time loop: ``ralf-hil measure xcp-timing``.

Runs ``ralf-hil up`` (real time, 200 Hz, three processes) in rounds of
three arms, the order rotated each round: XCP off; the controller's XCP
slave on UDP (``--set controller.xcp_udp_port=PORT``) with no master; and
the same with a pyxcp master measuring a DAQ list of ``NAMES`` on the tick
event (every tick) from the moment the rig is ready to its end.

Each run prints the controller's overruns, its TET (task execution time:
SYNC to the end of the tick) p50 and p99, the DAQ samples the master
received and the slave's counters (DTOs sent, overloads, samples dropped);
then the medians per arm. ``--json`` writes every run and the medians;
``--markdown`` the page docs/results/xcp-timing.md. Run it in the
loopback-only namespace (``.ci/loopback-netns``): the rig's CAN bus is
udp_multicast.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from workbench.hostinfo import host_info

NAMES = ("tick", "t_s", "phi_ref1", "phi_ref2", "phi1", "phi2", "u1_v", "u2_v", "pi1_v", "pi2_v", "ai1_word", "ai2_word", "ai3_word", "ai4_word")
ARMS = ("xcp off", "xcp on, no master", "xcp on, pyxcp DAQ")
FIGURES = ("overruns", "tet_p50_us", "tet_p99_us", "daq_samples")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _daq_client(port: int, stop: threading.Event, result: dict[str, Any]) -> None:
    """A pyxcp master on 127.0.0.1:``port``: DAQ of :data:`NAMES` on event 0 until ``stop``."""
    from pyxcp.config import create_application_from_config
    from pyxcp.daq_stim import DaqList, DaqOnlinePolicy
    from pyxcp.master import Master

    from controller.xcp_table import controller_layout
    from service_kit.xcp.memory import ASAM_TYPES

    class Count(DaqOnlinePolicy):
        def __init__(self, lists: list[DaqList]) -> None:
            super().__init__(lists, logger=logging.getLogger("pyxcp.daq_stim"))
            self.pid_off = False  # PID_OFF is CAN's
            self.samples = 0

        def on_daq_list(self, daq_list: int, timestamp0: int, timestamp1: int, payload: list[Any]) -> None:
            self.samples += 1

    layout = controller_layout()
    measurements = [(n, layout.by_name[n].address, 0, ASAM_TYPES[layout.by_name[n].datatype][1]) for n in NAMES]
    policy = Count([DaqList(name="tick", event_num=0, stim=False, enable_timestamps=True, measurements=measurements, priority=0, prescaler=1)])
    app = create_application_from_config({"Transport": {"Eth": {"host": "127.0.0.1", "port": port, "protocol": "UDP"}}})
    app.transport.layer = "ETH"
    app.transport.timeout = 2.0
    try:
        with Master("eth", config=app, policy=policy) as x:
            x.connect()
            policy.setup()
            policy.start()
            stop.wait()
            result["daq_samples"] = policy.samples
    except Exception as exc:  # the rig may end first: what arrived is counted
        result["daq_samples"] = policy.samples
        result["client_error"] = f"{type(exc).__name__}: {exc}"


def run_once(duration_s: float, arm: str) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="ralf-xcp-bench-") as tmp:
        out = Path(tmp) / "summary.json"
        rig_id = f"xcpbench{int(time.time() * 1000) % 10**8}"
        port = _free_udp_port()
        cmd = [sys.executable, "-m", "workbench", "up", "--duration", str(duration_s), "--rig-id", rig_id, "--json", str(out)]
        if arm != "xcp off":
            cmd += ["--set", f"controller.xcp_udp_port={port}", "--set", f"controller.xcp_a2l={Path(tmp) / 'controller.a2l'}"]
        env = {**os.environ, "COLUMNS": "10000"}
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=tmp)
        assert proc.stdout is not None
        result: dict[str, Any] = {}
        stop = threading.Event()
        client: threading.Thread | None = None
        tail: list[str] = []
        for line in proc.stdout:
            tail = [*tail[-19:], line.rstrip()]
            if line.startswith("start-up: all services ready") and arm == "xcp on, pyxcp DAQ" and client is None:
                client = threading.Thread(target=_daq_client, args=(port, stop, result), daemon=True)
                client.start()
        proc.wait(timeout=duration_s + 180)
        stop.set()
        if client is not None:
            client.join(timeout=30)
        summary = json.loads(out.read_text())
    c = summary["controller"] or {}
    health = summary["health"]["controller"]
    counters, lat = health.get("counters", {}), health["latencies"]
    tet = lat.get("tet", {})
    return {
        "arm": arm,
        "exit": proc.returncode,
        "ticks": c.get("ticks"),
        "overruns": c.get("overruns"),
        "tet_p50_us": round(tet["p50"] * 1e6, 1) if tet.get("count") else None,
        "tet_p99_us": round(tet["p99"] * 1e6, 1) if tet.get("count") else None,
        "daq_samples": result.get("daq_samples", 0),
        "dtos_sent": counters.get("xcp_udp_dtos_sent"),
        "daq_overloads": counters.get("xcp_udp_daq_overloads"),
        "snapshots_dropped": counters.get("xcp_udp_snapshots_dropped"),
        **({"client_error": result["client_error"]} if "client_error" in result else {}),
        **(
            {"exit_reason": next((t for t in reversed(tail) if "verdict" in t.lower() or "fail" in t.lower()), tail[-1] if tail else "")}
            if proc.returncode
            else {}
        ),
        "load_average": summary["host"].get("load_average"),
    }


def markdown(data: dict[str, Any]) -> str:
    rows = data["runs"]
    lines = [
        "# XCP and the real-time loop",
        "",
        f"Generated by `{data['command']}` on {data['date']} ({data['host'].get('cpu_model', '?')}, {data['host'].get('cpus', '?')} CPUs); "
        "docs/xcp.md says how it is measured.",
        "",
        "The host runs other work meanwhile (the load average of each run is in the last column): "
        "the arms of one round ran back to back, so compare them within a round and across rounds, not with other pages' figures.",
        "",
        "Medians over the runs of each arm:",
        "",
        "| arm | runs | overruns | TET p50 (µs) | TET p99 (µs) | DAQ samples received |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for arm in ARMS:
        sel = [r for r in rows if r["arm"] == arm]
        m = data["medians"].get(arm, {})
        lines.append(
            f"| {arm} | {len(sel)} | {m.get('overruns', '-')} | {m.get('tet_p50_us', '-')} | {m.get('tet_p99_us', '-')} | {m.get('daq_samples', '-')} |"
        )
    lines += [
        "",
        "Every run:",
        "",
        "| arm | exit | ticks | overruns | TET p50 (µs) | TET p99 (µs) | DAQ samples | DTOs sent | overloads | samples dropped | load average |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        lines.append(
            f"| {r['arm']} | {r['exit']} | {r['ticks']} | {r['overruns']} | {r['tet_p50_us']} | {r['tet_p99_us']} | {r['daq_samples']} | "
            f"{r['dtos_sent'] if r['dtos_sent'] is not None else '-'} | {r['daq_overloads'] if r['daq_overloads'] is not None else '-'} | "
            f"{r['snapshots_dropped'] if r['snapshots_dropped'] is not None else '-'} | {r['load_average']} |"
        )
    lines += [
        "",
        "exit: `ralf-hil up`'s (1: the run's verdict failed, docs/reliability.md). DAQ samples: the samples the master "
        "received, from the moment its DAQ list started (after the rig was ready and the list set up) to the run's end; "
        "DTOs sent, overloads and samples dropped: the slave's counters.",
    ]
    return "\n".join(lines) + "\n"


def write_page(json_path: str, markdown_path: str) -> None:
    """The page of figures from a run's JSON (``python -m workbench.bench.xcp_timing JSON MARKDOWN``)."""
    Path(markdown_path).write_text(markdown(json.loads(Path(json_path).read_text())))


def main(args: argparse.Namespace) -> int:
    rows = []
    for i in range(args.rounds):
        for arm in ARMS[i % len(ARMS) :] + ARMS[: i % len(ARMS)]:
            row = run_once(args.duration, arm)
            rows.append(row)
            print(json.dumps(row), flush=True)
    medians: dict[str, dict[str, float]] = {}
    for arm in ARMS:
        sel = [r for r in rows if r["arm"] == arm]
        medians[arm] = {k: statistics.median(r[k] for r in sel if r[k] is not None) for k in FIGURES if any(r[k] is not None for r in sel)}
        print(f"{arm:20s}: medians over {len(sel)} run(s): {medians[arm]}")
    data = {
        "command": "ralf-hil measure xcp-timing " + " ".join(sys.argv[3:]),
        "date": time.strftime("%Y-%m-%d"),
        "host": host_info(),
        "runs": rows,
        "medians": medians,
    }
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(data, indent=1) + "\n")
    if args.markdown:
        Path(args.markdown).parent.mkdir(parents=True, exist_ok=True)
        Path(args.markdown).write_text(markdown(data))
    return 0


if __name__ == "__main__":
    write_page(sys.argv[1], sys.argv[2])
