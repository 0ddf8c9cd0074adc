"""The live view's cost to the control loop: ``ralf-hil measure live``.

Runs ``ralf-hil up`` (real time, 200 Hz, three processes) in rounds of
three arms: without ``--live``, with ``--live`` and no client, and with a
client subscribed to every topic (tests/live's spec client is not
installed, so this one is the same few lines on ``websockets``), rotating
which goes first, and prints each run's overruns, deadline misses, wake-up
(SYNC lateness) p99 and TET p99 from its summary, and the medians per arm. Run it in the loopback-only
namespace (``.ci/loopback-netns``): the rig's CAN bus is udp_multicast.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from workbench.hostinfo import host_info
from workbench.launcher import free_tcp_ports


async def _subscribe_all(url: str, until: float) -> int:
    """Connect, subscribe to every channel advertised, read until ``until``; messages received."""
    import websockets

    while True:
        try:
            ws = await websockets.connect(url, subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"], max_size=None)  # type: ignore[list-item]
            break
        except OSError:
            if time.monotonic() > until:
                return 0
            await asyncio.sleep(0.2)
    received, next_id = 0, 0
    async with ws:
        while time.monotonic() < until:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.01, until - time.monotonic()))
            except (TimeoutError, websockets.ConnectionClosed):
                break
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg.get("op") == "advertise":
                    subs = [{"id": next_id + i, "channelId": ch["id"]} for i, ch in enumerate(msg["channels"])]
                    next_id += len(subs)
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif frame[:1] == b"\x01":
                received += 1
    return received


ARMS = ("no view", "view, no client", "view, a client")


def run_once(duration_s: float, arm: str, rate_hz: float) -> dict[str, Any]:
    port = free_tcp_ports(1)[0]
    with_client = arm == ARMS[2]
    with tempfile.TemporaryDirectory(prefix="ralf-live-bench-") as tmp:
        out = Path(tmp) / "summary.json"
        cmd = [sys.executable, "-m", "workbench", "up", "--duration", str(duration_s), "--rig-id", f"livebench{port}", "--json", str(out)]
        if arm != ARMS[0]:
            cmd += ["--live", str(port), "--live-rate", str(rate_hz)]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        received = asyncio.run(_subscribe_all(f"ws://127.0.0.1:{port}", time.monotonic() + duration_s + 120)) if with_client else 0
        proc.wait(timeout=duration_s + 180)
        summary = json.loads(out.read_text())
    c = summary["controller"] or {}
    lat = summary["health"]["controller"]["latencies"]
    return {
        "arm": arm,
        "exit": proc.returncode,
        "ticks": c.get("ticks"),
        "overruns": c.get("overruns"),
        "deadline_misses": c.get("deadline_misses"),
        "wakeup_p99_us": round(lat["sync_jitter"]["p99"] * 1e6, 1) if lat.get("sync_jitter", {}).get("count") else None,
        "tet_p99_us": round(lat["tet"]["p99"] * 1e6, 1) if lat.get("tet", {}).get("count") else None,
        "received": received,
        "live": summary.get("live"),
        "load_average": summary["host"].get("load_average"),
    }


def main(args: argparse.Namespace) -> int:
    rows = []
    for i in range(args.rounds):
        for arm in ARMS[i % 3 :] + ARMS[: i % 3]:
            row = run_once(args.duration, arm, args.rate)
            rows.append(row)
            print(json.dumps(row), flush=True)
    medians = {}
    for arm in ARMS:
        sel = [r for r in rows if r["arm"] == arm]
        medians[arm] = {
            k: statistics.median(r[k] for r in sel if r[k] is not None)
            for k in ("overruns", "deadline_misses", "wakeup_p99_us", "tet_p99_us")
            if any(r[k] is not None for r in sel)
        }
        print(f"{arm:16s}: medians over {len(sel)} run(s): {medians[arm]}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(
            json.dumps(
                {
                    "command": "ralf-hil measure live " + " ".join(sys.argv[3:]),
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


if __name__ == "__main__":
    from service_kit.moved import exit_moved

    exit_moved("python -m workbench.live.bench", "ralf-hil measure live")
