"""What a flood of an allowed message costs the real-time loop: ``ralf-hil measure input-flood``.

Runs ``ralf-hil up`` (real time, 200 Hz, three processes, access rules on)
in rounds of two arms, the order rotated each round: undisturbed, and with
a tool's session (the run's own ``tool.env`` credentials) putting
``--messages`` ConfigChange on ``controller/command`` as fast as zenoh
takes them (blocking rather than dropping at the sender, so every one
reaches the controller) from ``--at`` seconds into the control. ``--other``
adds the same flood against another installation's ``ralf-hil`` (e.g. an
earlier version) in the same sitting.

Each run prints the controller's overruns, deadline misses, wake-up (SYNC
lateness) p99 and largest, what the
controller's inbox counted of the commands (taken, over the rate, queue
full) and the host's load average; then the medians per arm. Run it in the
loopback-only namespace (``.ci/loopback-netns``): the rig's CAN bus is
udp_multicast.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from workbench.hostinfo import host_info

START_LINE = re.compile(r"zenoh ((?:tcp|tls)/127\.0\.0\.1:\d+).*tools' credentials in (\S+)")


def _read_env(path: Path) -> dict[str, str]:
    return dict(line.split("=", 1) for line in path.read_text().splitlines() if "=" in line)


def flood(endpoint: str, tool_env: dict[str, str], messages: int, deadline_s: float) -> dict[str, Any]:
    """Put ``messages`` ConfigChange on the rig's ``controller/command`` from a
    tool's session (stops at ``deadline_s`` on the monotonic clock)."""
    import zenoh

    from protocol.keys import Keys
    from protocol.messages import ConfigChange, encode
    from protocol.settings import CommonSettings
    from service_kit.transport import zenoh_config

    # a tool's session as the tools open it, from the run's tool.env (an older run's: its user and password)
    values: dict[str, Any] = {name.removeprefix("RALF_").lower(): value for name, value in tool_env.items() if name.startswith("RALF_")}
    session = zenoh.open(zenoh_config(CommonSettings.model_validate({**values, "zenoh_connect": endpoint})))
    sent, spent = 0, 0.0
    try:
        keys = Keys(tool_env["RALF_RIG_ID"])
        publisher = session.declare_publisher(keys.controller_command, congestion_control=zenoh.CongestionControl.BLOCK)
        # a MatchingStatus at run time (zenoh 1.10's stub says bool)
        while not getattr(publisher.matching_status, "matching", False) and time.monotonic() < deadline_s:
            time.sleep(0.02)
        payload = encode(ConfigChange(seq=0, sim_time_s=0.0))
        start = time.monotonic()
        while sent < messages and time.monotonic() < deadline_s:
            publisher.put(payload)
            sent += 1
        spent = time.monotonic() - start
    finally:
        session.close()
    return {"sent": sent, "flood_s": round(spent, 3)}


def _attack(result: dict[str, Any], endpoint: str, tool_env: dict[str, str], messages: int, at_s: float, duration_s: float) -> None:
    time.sleep(at_s)
    result.update(flood(endpoint, tool_env, messages, time.monotonic() + duration_s))


def run_once(up: list[str], duration_s: float, arm: str, messages: int, at_s: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="ralf-flood-bench-") as tmp:
        out = Path(tmp) / "summary.json"
        rig_id = f"floodbench{int(time.time() * 1000) % 10**8}"
        cmd = [*up, "up", "--duration", str(duration_s), "--rig-id", rig_id, "--json", str(out)]
        env = {**os.environ, "COLUMNS": "10000"}  # the start line unwrapped
        # started elsewhere than here: services started with ``python -m`` import from their
        # working directory first, which would be this tree for another installation too
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=tmp)
        assert proc.stdout is not None
        result: dict[str, Any] = {}
        threads: list[threading.Thread] = []
        endpoint, tool_env = "", {}
        for line in proc.stdout:
            m = START_LINE.search(line)
            if m:
                endpoint, tool_env = m[1], _read_env(Path(m[2]))
            if line.startswith("start-up: all services ready") and arm != "quiet" and not threads:
                threads.append(threading.Thread(target=_attack, args=(result, endpoint, tool_env, messages, at_s, duration_s), daemon=True))
                threads[0].start()
        proc.wait(timeout=duration_s + 180)
        for t in threads:
            t.join(timeout=60)
        summary = json.loads(out.read_text())
    c = summary["controller"] or {}
    health = summary["health"]["controller"]
    counters, lat = health.get("counters", {}), health["latencies"]
    jitter = lat.get("sync_jitter", {})
    return {
        "arm": arm,
        "exit": proc.returncode,
        "ticks": c.get("ticks"),
        "overruns": c.get("overruns"),
        "deadline_misses": c.get("deadline_misses"),
        "wakeup_p99_us": round(jitter["p99"] * 1e6, 1) if jitter.get("count") else None,
        "wakeup_max_us": round(jitter["max"] * 1e6, 1) if jitter.get("count") and "max" in jitter else None,
        "commands_taken": counters.get("reconfigurations", 0),
        "commands_over_rate": counters.get("in_command_dropped_rate", 0),
        "commands_queue_full": counters.get("in_command_dropped_full", 0),
        **result,
        "load_average": summary["host"].get("load_average"),
    }


FIGURES = ("overruns", "deadline_misses", "wakeup_p99_us", "wakeup_max_us")


def main(args: argparse.Namespace) -> int:
    arms: list[tuple[str, list[str]]] = [("quiet", [sys.executable, "-m", "workbench"]), ("flood", [sys.executable, "-m", "workbench"])]
    if args.other:
        arms.append(("flood, other ralf-hil", [args.other]))
    rows = []
    for i in range(args.rounds):
        for arm, up in arms[i % len(arms) :] + arms[: i % len(arms)]:
            row = run_once(up, args.duration, arm, args.messages, args.at)
            rows.append(row)
            print(json.dumps(row), flush=True)
    medians = {}
    for arm, _ in arms:
        sel = [r for r in rows if r["arm"] == arm]
        medians[arm] = {k: statistics.median(r[k] for r in sel if r[k] is not None) for k in FIGURES if any(r[k] is not None for r in sel)}
        print(f"{arm:22s}: medians over {len(sel)} run(s): {medians[arm]}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(
            json.dumps(
                {
                    # the other installation's path names this machine's folders: OTHER stands for it
                    "command": "ralf-hil measure input-flood " + " ".join("OTHER" if args.other and a == args.other else a for a in sys.argv[3:]),
                    "date": time.strftime("%Y-%m-%d"),
                    "host": host_info(),
                    "runs": rows,
                    "medians": medians,
                },
                indent=1,
            )
            + "\n"
        )
    return 0
