"""``ralf-hil up --can-bitrate N [--restbus FILE.dbc]``: the rig's CAN on one
wire (docs/can-bus.md).

With a bit rate (option, or the setting ``can_bitrate``) the launcher starts
the wire arbiter (:mod:`service_kit.can_wire.hub`) as a process of its own
on a Unix socket in the run's private folder, and points the three services,
the recorder's tap, the live view and the tools' ``tool.env`` at it
(``RALF_CAN_INTERFACE=ralfhub``, ``RALF_CAN_CHANNEL=<socket>``) instead of
``udp_multicast``. ``--restbus`` (or ``can_restbus``) adds the restbus
sender (:mod:`service_kit.can_wire.restbus`) on the same wire. Bad input —
a bit rate not allowed, a DBC that does not parse or breaks a convention,
a load above 100 % with the rig's own cycle, an identifier of the rig's —
is one line and exit 2 before any process starts
(:func:`service_kit.can_wire.restbus.traffic.check`). After the run the
arbiter's figures (bus load, queuing delays, SYNC→TPDO1) go into the summary.
While it runs the arbiter rewrites ``can-wire-live.json`` with the last
second's figures (:mod:`service_kit.can_wire.hub_live`); the launcher reads
each new one (:meth:`RigWire.poll_live`) and hands it to the recording and the
live view on ``/can/bus_load``.
Off by default: without a bit rate nothing here runs.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from service_kit.can_wire.restbus.traffic import STANDARD_BITRATES

HUB_LOG = "can-wire.log"
RESTBUS_LOG = "restbus.log"
SOCKET_NAME = "can-wire.sock"
STATS_NAME = "can-wire.json"
LIVE_NAME = "can-wire-live.json"
LIVE_PERIOD_S = 1.0
"""How often the arbiter publishes its figures while it runs."""
READY_TIMEOUT_S = 30.0
"""How long the arbiter may take to listen (a loaded host's Python start-up)."""


@dataclass(frozen=True)
class WireRequest:
    bitrate: int
    restbus: str = ""


def _setting(name: str, overrides: Mapping[str, Mapping[str, str]]) -> str:
    """A common setting as the services would read it: ``--set`` first, then the environment."""
    var = f"RALF_{name.upper()}"
    for env in overrides.values():
        if var in env:
            return env[var]
    return os.environ.get(var, "")


def wire_request(can_bitrate: int | None, restbus: str | None, overrides: Mapping[str, MutableMapping[str, str]], clock: str) -> WireRequest | None:
    """The wire the user asked for (None: none), checked before anything starts; ``SystemExit``
    with one line for bad input."""
    text = str(can_bitrate) if can_bitrate is not None else _setting("can_bitrate", overrides)
    dbc = restbus if restbus is not None else _setting("can_restbus", overrides)
    try:
        bitrate = int(text) if text.strip() else 0
    except ValueError:
        raise SystemExit(f"ralf-hil up: can_bitrate {text!r} is not a whole number of bit/s") from None
    if bitrate == 0:
        if dbc:
            raise SystemExit("ralf-hil up: --restbus needs a wire: give --can-bitrate (125000, 250000, 500000 or 1000000)")
        return None
    if bitrate not in STANDARD_BITRATES:
        rates = ", ".join(str(r) for r in STANDARD_BITRATES)
        raise SystemExit(f"ralf-hil up: unsupported CAN bit rate {bitrate} bit/s (one of {rates}; 0: off)")
    if clock == "cosim":  # the co-simulation's own simulated wire (docs/can-wire.md), checked by its settings
        for env in overrides.values():
            env["RALF_CAN_BITRATE"] = str(bitrate)
            if dbc:
                env["RALF_CAN_RESTBUS"] = str(Path(dbc).absolute())
        return None
    if dbc:
        check_restbus(dbc, bitrate)
    return WireRequest(bitrate, str(Path(dbc).absolute()) if dbc else "")


def check_restbus(dbc: str, bitrate: int) -> None:
    """The restbus CLI's checks beside the rig's own cycle: one line, exit 2."""
    from service_kit.can_wire.restbus.traffic import RestbusError, check, load, rig_cycle

    try:
        restbus = load(dbc)
        problems = check(restbus, bitrate, rig=rig_cycle())
    except RestbusError as exc:
        raise SystemExit(f"ralf-hil up: --restbus: {exc}") from None
    if not problems and not restbus.messages:
        problems = [f"{dbc} has no message with a GenMsgCycleTime: nothing to send"]
    if problems:
        raise SystemExit(f"ralf-hil up: --restbus: {'; '.join(problems)}")


def point_plan_at(plan: Any, socket_path: Path) -> None:
    """Every node of the rig (services, tap, tools) on the arbiter instead of udp_multicast."""
    plan.common_env.update(RALF_CAN_INTERFACE="ralfhub", RALF_CAN_CHANNEL=str(socket_path))


def _wait_ready(proc: subprocess.Popen[bytes], log: Path, socket_path: Path, timeout_s: float) -> None:
    from service_kit.can_wire.hub import HubError

    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc.poll() is not None:
            lines = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
            raise HubError(lines[-1] if lines else f"the wire arbiter exited with {proc.returncode}")
        if socket_path.exists() and "can wire hub:" in log.read_text(errors="replace"):
            return
        time.sleep(0.05)
    raise HubError(f"the wire arbiter did not listen within {timeout_s:.0f} s")


class RigWire:
    """The arbiter (and the restbus sender) of one ``ralf-hil up`` run."""

    def __init__(self, request: WireRequest, run_dir: Path, log_dir: Path, plan: Any) -> None:
        """Points ``plan`` at the arbiter's socket in ``run_dir`` (the run's private folder)."""
        self.request = request
        self.socket_path = run_dir / SOCKET_NAME
        self.stats_path = run_dir / STATS_NAME
        self.live_path = run_dir / LIVE_NAME
        self._live_seq = 0
        self.log_dir = log_dir
        point_plan_at(plan, self.socket_path)
        self.env = {**os.environ, **plan.common_env, "RALF_LAUNCHER_PID": str(os.getpid())}
        self.hub: subprocess.Popen[bytes] | None = None
        self.restbus: subprocess.Popen[bytes] | None = None

    def _spawn(self, args: list[str], log_name: str) -> subprocess.Popen[bytes]:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        with open(self.log_dir / log_name, "wb") as log:
            return subprocess.Popen(
                [sys.executable, "-P", "-m", *args], env=self.env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True
            )

    def start(self) -> None:
        """The arbiter, listening, then the restbus on it (HubError, one line, when it cannot start)."""
        from service_kit.can_wire.hub import HubError, check_socket_path

        check_socket_path(self.socket_path)
        self.hub = self._spawn(
            ["service_kit.can_wire.hub", "--socket", str(self.socket_path), "--bitrate", str(self.request.bitrate), "--stats", str(self.stats_path)]
            + ["--live", str(self.live_path), "--live-period-s", str(LIVE_PERIOD_S)],
            HUB_LOG,
        )
        _wait_ready(self.hub, self.log_dir / HUB_LOG, self.socket_path, READY_TIMEOUT_S)
        if self.request.restbus:
            self.restbus = self._spawn(
                ["service_kit.can_wire.restbus", self.request.restbus, "--bitrate", str(self.request.bitrate), "--send", "--rig-bus"], RESTBUS_LOG
            )
            time.sleep(0.2)
            if self.restbus.poll() is not None:
                raise HubError(f"the restbus sender exited with {self.restbus.returncode}: see {self.log_dir / RESTBUS_LOG}")

    def poll_live(self) -> dict[str, Any] | None:
        """The arbiter's newest period figures, once each (None: none new, or the file not yet whole)."""
        record = read_live(self.live_path)
        if record is None or int(record.get("seq", 0)) <= self._live_seq:
            return None
        self._live_seq = int(record["seq"])
        return record

    def stop(self) -> dict[str, Any] | None:
        """Stops the restbus, then the arbiter; the arbiter's figures (None if it left none)."""
        from workbench.launcher import terminate

        if self.restbus is not None:
            terminate(self.restbus, 10.0)
        if self.hub is not None:
            terminate(self.hub, 20.0)
        try:
            report: dict[str, Any] = json.loads(self.stats_path.read_text())
        except (OSError, ValueError):
            return None
        report["restbus"] = self.request.restbus or None
        if self.restbus is not None:
            lines = [ln for ln in (self.log_dir / RESTBUS_LOG).read_text(errors="replace").splitlines() if ln.startswith("restbus:")]
            report["restbus_sender"] = lines[-1].removeprefix("restbus: ") if lines else f"exit {self.restbus.returncode}"
        return report


def read_live(path: Path) -> dict[str, Any] | None:
    """The record in the arbiter's live file (None: none yet; it is replaced whole, never half written)."""
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def summary_rows(wire: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The arbiter's figures as rows of ``ralf-hil up``'s summary."""
    rows = [
        (
            "CAN wire",
            f"{wire['bitrate']} bit/s: {wire['frames']} frames, busy {wire['busy_pct']:.1f} % "
            f"(peak {wire.get('peak_window_busy_pct', 0.0):.1f} % per {wire['window_ms']:g} ms), "
            f"{wire['frames_per_s']:.0f} frames/s, {wire['bits_per_s'] / 1e3:.0f} kbit/s",
        )
    ]
    if "sync_to_tpdo1_us" in wire:
        s = wire["sync_to_tpdo1_us"]
        rows.append(
            (
                "CAN wire SYNC→TPDO1",
                f"min {s['min']:.0f} µs, p50 {s['p50']:.0f} µs, p99 {s['p99']:.0f} µs, max {s['max']:.0f} µs (n={s['n']}); "
                f"{wire['sync_to_tpdo1_floor_margin_min_us']:.0f} µs above the wire's floor at least",
            )
        )
    delays = wire.get("queuing_delay_us", {})
    if delays:
        worst = sorted(delays.items(), key=lambda kv: -kv[1]["p99"])[:3]
        rows.append(("CAN wire queuing delay (worst p99)", ", ".join(f"{ident} p99 {d['p99']:.0f} µs max {d['max']:.0f} µs" for ident, d in worst)))
    c = wire["clients"]
    rows.append(
        (
            "CAN wire clients",
            f"{c['connected']} connected, {c['vanished']} left, {c['overruns']} deliveries lost to a full outbox, {c['junk']} junk packets, "
            f"{c['refused_frames']} frames refused, {c['frames_dropped']} dropped with their sender",
        )
    )
    if wire.get("restbus"):
        rows.append(("restbus", f"{wire['restbus']}: {wire.get('restbus_sender', '')}"))
    return rows
