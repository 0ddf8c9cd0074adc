"""The plant's XCP slave (docs/xcp.md, "The plant's slave"): the table of
:mod:`plant_emulator.xcp_table` served over UDP, TCP and/or CAN, fed by the
node's SYNC path without ever making it wait.

On each SYNC (:class:`plant_emulator.service.PlantApplication`):

1. a write the map takes joins the plant's parameter path
   (:mod:`plant_emulator.params`, kind ``xcp``): applied before the next
   SYNC's step (a plant event ``payload``, as a scenario's command, and a
   ``ParamChanged`` on ``plant/param_changes``), so that step already uses it;
2. after the sample, the state is packed into one image and handed to each
   transport's bounded queue with its timestamp: the model's time after the
   step (simulated time in lockstep; in real time the model's time, caught
   up to the wall clock), in µs, mod 2^32. Event 0 is every SYNC.
"""

from __future__ import annotations

import logging
import math
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Final

from plant_emulator.params import PlantParams
from plant_emulator.plant_model import PlantModel
from plant_emulator.xcp_table import A2L_MODULE, XCP_TABLE, plant_a2l, plant_layout, xcp_events
from protocol.errors import ConfigError
from protocol.settings import PlantSettings
from service_kit.xcp.memory import Write
from service_kit.xcp.server import Server
from service_kit.xcp.slave import Slave, SlaveInfo, Snapshot
from service_kit.xcp.tcp import TcpServer
from service_kit.xcp.transports import CanIds, XcpPorts, counter_prefix, on_can, open_servers
from service_kit.xcp.udp import UdpServer

__all__ = ["PlantXcp", "make_plant_xcp", "xcp_ports"]

log = logging.getLogger(__name__)

TIMESTAMP_PER_S: Final = 1_000_000
_NAN = math.nan


def xcp_ports(s: PlantSettings) -> XcpPorts:
    return XcpPorts(s.xcp_udp_port, s.xcp_tcp_port, s.xcp_host, CanIds(s.xcp_can_id_master, s.xcp_can_id_slave) if s.xcp_can else None)


def make_plant_xcp(settings: PlantSettings, arm: PlantModel, params: PlantParams) -> PlantXcp | None:
    """The plant's slave, or None when no transport is set (the default)."""
    return PlantXcp(settings, arm, params) if xcp_ports(settings).any else None


class PlantXcp:
    """The plant table's map, its A2L, its transports, and the SYNC path's side of them."""

    def __init__(self, settings: PlantSettings, arm: PlantModel, params: PlantParams) -> None:
        s = settings
        self.arm = arm
        self.params = params
        self.layout = plant_layout()
        self.events = xcp_events(s.sample_period_s)
        order = [e.variable.name for e in XCP_TABLE]
        self._order = [order.index(v.name) for v in self.layout.variables]
        self.a2l_path = s.xcp_a2l or str(Path(tempfile.gettempdir()) / f"ralf-{s.rig_id}-plant.a2l")
        self.servers: list[Server] = open_servers(xcp_ports(s), s, self._slave)
        udp = next((x.port for x in self.servers if isinstance(x, UdpServer)), 0)
        tcp = next((x.port for x in self.servers if isinstance(x, TcpServer)), 0)
        try:
            Path(self.a2l_path).write_text(
                plant_a2l(s.sample_period_s, udp, tcp, s.xcp_host, (s.xcp_can_id_master, s.xcp_can_id_slave) if s.xcp_can else None), encoding="utf-8"
            )
        except OSError as exc:
            self.close()
            raise ConfigError(f"xcp_a2l {self.a2l_path}: {exc.strerror or exc}") from exc
        log.info("plant XCP on %s (UDP %d, TCP %d, CAN %s); A2L %s", s.xcp_host, udp, tcp, s.xcp_can, self.a2l_path)

    def _slave(self, can: bool = False) -> Slave:
        info = SlaveInfo(A2L_MODULE, self.a2l_path, self.events, timestamp_unit=3)
        return Slave(self.layout, on_can(info) if can else info, self._calibrate, self.image(0, []))

    # -- the values ----------------------------------------------------------------------
    def _table_values(self, syncs: int, codes: Sequence[int]) -> list[float | int]:
        """The raw values in the table's order."""
        arm = self.arm
        freqs, zetas, defl, theta, tip, payload = arm.truth_summary()
        valves = getattr(arm, "valve_volts", (_NAN, _NAN))
        f = [*freqs[:2], _NAN, _NAN][:2]
        z = [*zetas[:2], _NAN, _NAN][:2]
        ai = [*(int(c) for c in codes[:4]), 0, 0, 0, 0][:4]
        pl = int(bool(payload))
        return [
            syncs,
            arm.time_s,
            theta[0],
            theta[1],
            defl[0],
            defl[1],
            tip[0],
            tip[1],
            f[0],
            f[1],
            z[0],
            z[1],
            valves[0],
            valves[1],
            *ai,
            arm.hard_stop_count,
            pl,
            pl,
        ]

    def image(self, syncs: int, codes: Sequence[int]) -> bytes:
        values = self._table_values(syncs, codes)
        return self.layout.pack([values[i] for i in self._order])

    # -- the SYNC path's side --------------------------------------------------------------------
    def after_sync(self, syncs: int, codes: Sequence[int]) -> None:
        """Hand this SYNC's sample to each transport. Never blocks on the network."""
        snapshot = Snapshot(1, round(self.arm.time_s * TIMESTAMP_PER_S) & 0xFFFFFFFF, self.image(syncs, codes))
        for server in self.servers:
            server.offer(snapshot)

    # -- the transports' side -------------------------------------------------------------------
    def _calibrate(self, changes: list[Write]) -> None:
        """A write the map took, onto the plant's parameter path (its guards; refused: an XCP error code)."""
        self.params.submit(changes, "xcp", "xcp master")

    # -- life --------------------------------------------------------------------------------------
    def start(self) -> None:
        for server in self.servers:
            server.start()

    def close(self) -> None:
        for server in self.servers:
            server.close()

    def counters(self) -> dict[str, int]:
        out = {"xcp_payload_writes_applied": self.params.applied["xcp"]}
        for server in self.servers:
            out.update({counter_prefix(server) + k: n for k, n in server.counters.as_dict().items()})
        return out
