"""The controller's XCP slave (docs/xcp.md): the table's map served over UDP
and/or TCP on 127.0.0.1 and/or CAN on the rig's bus, fed by the loop without ever making it wait.

A calibration write is checked in the transport's thread before it is
answered: the map checks the limits (ERR_OUT_OF_RANGE), a measurement
(ERR_WRITE_PROTECTED), a partial write (ERR_ACCESS_DENIED); then it joins
the controller's one path for parameter changes (:mod:`controller.params`):
an OATF parameter in a run without an OATF (ERR_ACCESS_DENIED), an OATF
design the filter's guards refuse (ERR_OUT_OF_RANGE), more changes pending
than :data:`controller.params.PENDING_CAPACITY` (ERR_MEMORY_OVERFLOW). The
path applies it before the next tick and lists it in the run's
``config_changes`` (kind ``xcp``, at the simulated time of the tick that
first uses it).

At the end of every tick (:meth:`XcpLink.after_tick`, in the loop's thread)
the tick's values (the run record's row, the service's counters, the
parameters in effect) are packed into one image and handed to each
transport's bounded queue with the tick's timestamp: the sample instant
``tick * Ts`` on the rig's clock (simulated time in lockstep and
co-simulation), in µs, mod 2^32. Event 0 is every tick; event 1 the ticks
at which a new DSP interrupt was taken.
"""

from __future__ import annotations

import logging
import math
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Final, Protocol

from controller.dsp_link import DspLink
from controller.dsp_side import DspSide
from controller.loop import ControlLaw
from controller.params import PI, ParamPath
from controller.timing_counters import TimingCounters
from controller.xcp_table import A2L_MODULE, CALIBRATIONS, XCP_TABLE, controller_a2l, controller_layout, xcp_events
from protocol.errors import ConfigError
from protocol.settings import ControllerSettings
from service_kit.runtime import LatencyTracker
from service_kit.xcp.memory import Variable, Write
from service_kit.xcp.server import Server
from service_kit.xcp.slave import Slave, SlaveInfo, Snapshot
from service_kit.xcp.tcp import TcpServer
from service_kit.xcp.transports import CanIds, XcpPorts, counter_prefix, on_can, open_servers
from service_kit.xcp.udp import UdpServer

__all__ = ["XcpLink", "make_xcp"]

log = logging.getLogger(__name__)

TIMESTAMP_PER_S: Final = 1_000_000
"""DAQ timestamp ticks per second (1 µs, DAQ_TIMESTAMP_UNIT_1US)."""


class Service(Protocol):
    """What the XCP link reads of :class:`controller.service.ControllerService`."""

    settings: ControllerSettings
    law: ControlLaw
    tet: LatencyTracker
    link: DspLink
    timing: TimingCounters
    dsp: DspSide
    params: ParamPath
    tick: int


def default_a2l_path(rig_id: str) -> str:
    return str(Path(tempfile.gettempdir()) / f"ralf-{rig_id}.a2l")


def xcp_ports(s: ControllerSettings) -> XcpPorts:
    """The transports the settings ask for (all off by default)."""
    return XcpPorts(s.xcp_udp_port, s.xcp_tcp_port, s.xcp_host, CanIds(s.xcp_can_id_master, s.xcp_can_id_slave) if s.xcp_can else None)


def make_xcp(service: Service, record_columns: Sequence[str]) -> XcpLink | None:
    """The XCP slave of ``service`` (a :class:`controller.service.ControllerService`; its
    run record has ``record_columns``), or None when no transport is set (the default)."""
    s = service.settings
    if not xcp_ports(s).any:
        return None
    return XcpLink(service, record_columns)


class XcpLink:
    """The table's map, its A2L, its transports, and the loop's side of them."""

    def __init__(self, service: Service, record_columns: Sequence[str]) -> None:
        s = service.settings
        self.service = service
        self._columns = list(record_columns)
        self.law = service.law
        self.layout = controller_layout()
        self.period_s = s.sample_period_s
        self.events = xcp_events(self.period_s)
        self.params = service.params
        self._last_irq: Any = None
        self._getters = [self._getter(e.variable, e.source) for e in XCP_TABLE]
        order = {v.name: i for i, v in enumerate(self.layout.variables)}
        self._getters = [g for _, g in sorted(zip((order[e.variable.name] for e in XCP_TABLE), self._getters, strict=True), key=lambda t: t[0])]
        self.a2l_path = s.xcp_a2l or default_a2l_path(s.rig_id)
        self.servers: list[Server] = open_servers(xcp_ports(s), s, self._slave)
        udp = next((x.port for x in self.servers if isinstance(x, UdpServer)), 0)
        tcp = next((x.port for x in self.servers if isinstance(x, TcpServer)), 0)
        can_ids = (s.xcp_can_id_master, s.xcp_can_id_slave) if s.xcp_can else None
        try:
            Path(self.a2l_path).write_text(controller_a2l(self.period_s, udp, tcp, s.xcp_host, can_ids), encoding="utf-8")
        except OSError as exc:
            self.close()
            raise ConfigError(f"xcp_a2l {self.a2l_path}: {exc.strerror or exc}") from exc
        log.info("XCP on %s (UDP %d, TCP %d); A2L %s", s.xcp_host, udp, tcp, self.a2l_path)

    def _slave(self, can: bool = False) -> Slave:
        info = SlaveInfo(A2L_MODULE, self.a2l_path, self.events, timestamp_unit=3)
        info = on_can(info) if can else info
        return Slave(self.layout, info, self._calibrate, self._image(self.service.tick, []))

    # -- the values --------------------------------------------------------------------
    def _getter(self, v: Variable, source: str) -> Callable[[list[Any]], float | int]:
        """How the loop reads ``v``'s raw value (from the record's row, the service, the law)."""
        columns = self._columns
        svc, law = self.service, self.law
        integer = not v.is_float
        if source in columns:
            i = columns.index(source)
            return (lambda row: int(row[i])) if integer else (lambda row: row[i])
        if source == "tet_prev_s":
            return lambda row: svc.tet.last
        if source == "deadline_misses":
            return lambda row: svc.link.counters.deadline_misses
        if source == "overruns":
            return lambda row: svc.timing.overruns
        if source in PI:  # kept by the parameter path: they change only through it
            gains = self.params.pi_gains
            return lambda row: gains[source]
        if source == "oatf_frequency_hz":
            return lambda row: law.oatf.stages[0].frequency_hz if law.oatf is not None and law.oatf.stages else float("nan")
        if source == "oatf_zeta":
            return lambda row: law.oatf.stages[0].zeta if law.oatf is not None and law.oatf.stages else float("nan")
        if source in CALIBRATIONS:  # the dither's amplitude, the input monitors' limits: as the path holds them
            params = self.params

            def held(row: list[Any]) -> float | int:
                raw = params.value_raw(v)
                return (int(raw) if math.isfinite(raw) else 0) if integer else raw

            return held
        raise ValueError(f"XCP table entry {v.name}: no source {source!r}")

    def _image(self, tick: int, row: list[Any]) -> bytes:
        if not row:  # before the first tick: zeros, the parameters as the law holds them
            row = [0.0] * len(self._columns)
        return self.layout.pack([g(row) for g in self._getters])

    # -- the loop's side ------------------------------------------------------------------
    def after_tick(self, tick: int, row: list[Any]) -> None:
        """Hand this tick's snapshot to each transport. Never blocks on the network."""
        irq = self.service.dsp.latest_interrupt
        events = 1 | (2 if irq is not self._last_irq else 0)
        self._last_irq = irq
        snapshot = Snapshot(events, round(tick * self.period_s * TIMESTAMP_PER_S) & 0xFFFFFFFF, self._image(tick, row))
        for server in self.servers:
            server.offer(snapshot)

    # -- the transports' side ----------------------------------------------------------------
    def _calibrate(self, changes: list[Write]) -> None:
        """A write the map accepted (limits checked): to the parameter path, queued for the
        next tick, or refused (:class:`controller.params.ParamRefused`, an XCP error code)."""
        self.params.submit(changes, "xcp", "xcp master")

    # -- life --------------------------------------------------------------------------------
    def start(self) -> None:
        for server in self.servers:
            server.start()

    def close(self) -> None:
        for server in self.servers:
            server.close()

    def counters(self) -> dict[str, int]:
        """The slaves' counters (``xcp_udp_*``, ``xcp_tcp_*``) and the calibrations applied."""
        out = {"xcp_calibrations_applied": self.params.applied["xcp"], "xcp_calibrations_failed": self.params.failed["xcp"]}
        for server in self.servers:
            prefix = counter_prefix(server)
            out.update({prefix + k: n for k, n in server.counters.as_dict().items()})
        return out
