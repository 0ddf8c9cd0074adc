"""The transports a service's settings ask for: UDP and TCP ports (0 = off) and
XCP on CAN on the rig's bus, each with its own :class:`Slave` (one master per
transport). A port in use, a bus that does not open or identifiers the rig's
CANopen network uses are refused in one line (:class:`ConfigError`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from protocol.errors import ConfigError
from protocol.settings import CommonSettings
from service_kit.transport import TransportError, open_can_bus
from service_kit.xcp.can import CAN_MAX_CTO, CAN_MAX_DTO, CanServer, IdentifierError, check_identifiers
from service_kit.xcp.server import Server
from service_kit.xcp.slave import Slave, SlaveInfo
from service_kit.xcp.tcp import TcpServer
from service_kit.xcp.udp import UdpServer

__all__ = ["CanIds", "XcpPorts", "counter_prefix", "on_can", "open_servers"]


@dataclass(frozen=True)
class CanIds:
    """XCP on CAN's identifiers and the setting names they come from."""

    master: int
    slave: int
    setting: str = "xcp_can_id_master/xcp_can_id_slave"


@dataclass(frozen=True)
class XcpPorts:
    udp: int = 0
    tcp: int = 0
    host: str = "127.0.0.1"
    can: CanIds | None = None
    """None: no XCP on CAN."""

    @property
    def any(self) -> bool:
        return bool(self.udp or self.tcp or self.can)


def on_can(info: SlaveInfo) -> SlaveInfo:
    """``info`` for XCP on CAN: MAX_CTO = MAX_DTO = 8, parameters written in parts."""
    return replace(info, max_cto=CAN_MAX_CTO, max_dto=CAN_MAX_DTO, partial_writes=True)


def open_servers(ports: XcpPorts, settings: CommonSettings, slave: Callable[[bool], Slave]) -> list[Server]:
    """The servers ``ports`` names, not started; ``slave(False)`` makes an Ethernet
    transport's slave, ``slave(True)`` the CAN one's (its info through :func:`on_can`)."""
    servers: list[Server] = []
    what = ""
    try:
        for name, port, kind in (("xcp_udp_port", ports.udp, UdpServer), ("xcp_tcp_port", ports.tcp, TcpServer)):
            if port:
                what = f"{name} {port} on {ports.host}"
                servers.append(kind(slave(False), ports.host, port))
        if ports.can is not None:
            ids = ports.can
            check_identifiers({ids.setting: (ids.master, ids.slave)}, settings.node_id)
            what = "xcp_can"
            bus = open_can_bus(settings)
            servers.append(CanServer(slave(True), bus, ids.master, ids.slave))
    except OSError as exc:
        for s in servers:
            s.close()
        raise ConfigError(f"{what}: {exc.strerror or exc}") from exc
    except (IdentifierError, TransportError) as exc:
        for s in servers:
            s.close()
        raise ConfigError(str(exc)) from exc
    return servers


def counter_prefix(server: Server) -> str:
    """``xcp_udp_``, ``xcp_tcp_`` or ``xcp_can_``: the service's counters of this transport."""
    return {UdpServer: "xcp_udp_", TcpServer: "xcp_tcp_", CanServer: "xcp_can_"}.get(type(server), "xcp_")
