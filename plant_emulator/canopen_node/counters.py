"""What the node counts, as one snapshot for health messages and tests."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, fields

from plant_emulator.canopen_node.od import ObjectDictionary
from plant_emulator.canopen_node.sdo_server import SdoCounters
from protocol.can_map import OD_DIAGNOSTICS


@dataclass
class NodeCounters:
    """Everything the node counts (monotonic over the node's life, NMT resets included)."""

    rx: Counter[str] = field(default_factory=Counter)
    """frames received, by kind: nmt, sync, rpdo, sdo, time, foreign (other nodes), own_cob_id
    (echoes of our frames), nmt_other_node, sync_stopped, sdo_stopped (SDO requests in STOPPED,
    not answered), error_frame, extended"""
    tx: Counter[str] = field(default_factory=Counter)
    """frames produced, by kind: bootup, heartbeat, tpdo1, tpdo2, tpdo3, emcy, sdo"""
    malformed: Counter[str] = field(default_factory=Counter)
    """ignored frames, by kind: nmt_dlc, nmt_command, nmt_node_id, sync_dlc, sync_counter, rpdo_dlc,
    rpdo_not_operational, sdo_dlc, unknown_cob_id, rtr"""
    impersonated: Counter[str] = field(default_factory=Counter)
    """frames on our own COB-IDs that this node did not send (another node using its identifiers),
    by kind: heartbeat, emcy, tpdo1, tpdo2, tpdo3, sdo_tx"""
    comm_writes: Counter[str] = field(default_factory=Counter)
    """successful SDO writes of communication objects, by index (``0x1017``): a master compares them with its own"""
    sync_received: int = 0
    """valid SYNCs (any state but STOPPED)"""
    sync_gaps: int = 0
    """times the SYNC counter skipped"""
    syncs_missed: int = 0
    """SYNCs missing in those gaps"""
    sync_repeats: int = 0
    """SYNCs repeating the previous counter"""
    samples: int = 0
    """on_sync calls that produced TPDOs"""
    sync_conflicts: int = 0
    """SYNCs whose counter one producer cannot give (repeat, jump back, mixed forms): a second producer"""
    rpdo_conflicts: int = 0
    """SYNC periods with more RPDO1 frames than SYNCs: a second RPDO producer"""
    watchdog_trips: int = 0
    watchdog_recoveries: int = 0
    """trips ended by a SYNC or RPDO1 (trips ended by NMT are not counted here)"""
    rpdo_timeouts: int = 0
    """trips with SYNC present but no RPDO1 for the watchdog time (counted in watchdog_trips too)"""
    watchdog_disable_refused: int = 0
    """SDO writes of 0x2003 = 0 refused"""
    outputs_applied: int = 0
    clipped_outputs: int = 0
    """output writes (RPDO or SDO) with at least one channel clipped"""
    outputs_held: int = 0
    """RPDOs not applied because the watchdog held the valves"""
    saturated_samples: int = 0
    """channel-samples the application flagged saturated"""
    emcy_suppressed: int = 0
    """EMCYs not sent because the node was STOPPED"""
    heartbeat_late: int = 0
    """heartbeats more than one period late (poll not called often enough)"""
    app_errors: int = 0
    """application callbacks that raised or returned garbage"""
    app_codes_clipped: int = 0
    """samples with codes outside the ADC range (clipped before sending)"""
    tx_errors: int = 0
    """frames the runner failed to send"""
    rx_errors: int = 0
    """receive errors the runner saw (e.g. an undecodable udp_multicast datagram)"""
    kernel_drops: int = 0
    """datagrams the kernel dropped for a full receive buffer (the bus's ``kernel_drops``, Linux ``SO_RXQ_OVFL``)"""
    fd_frames_dropped: int = 0
    """CAN FD frames the bus received and dropped (the node speaks classic CAN; the bus's ``fd_frames_dropped``)"""
    junk_frames: int = 0
    """datagrams on the CAN group that were not CAN frames, skipped by the bus before decoding (the bus's ``junk_frames``)"""
    internal_errors: int = 0
    """exceptions caught around the state machine (should stay 0)"""
    sdo: SdoCounters = field(default_factory=SdoCounters)

    @property
    def malformed_total(self) -> int:
        return sum(dict.copy(self.malformed).values())

    @property
    def impersonated_total(self) -> int:
        return sum(dict.copy(self.impersonated).values())

    def as_dict(self) -> dict[str, int]:
        """A flat, JSON-ready snapshot of ints: the scalar counters by name,
        the per-kind ones as ``rx_<kind>``, ``tx_<kind>``, ``malformed_<kind>``
        (plus the total ``malformed``), and ``sdo_uploads``, ``sdo_downloads``,
        ``sdo_client_aborts``, ``sdo_aborts`` (total) and ``sdo_abort_0x<code>``."""
        # dict.copy is one C call under the GIL: safe while the node thread adds kinds
        out: dict[str, int] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, Counter):
                for kind, n in sorted(dict.copy(v).items()):
                    out[f"{f.name}_{kind}"] = int(n)
            elif isinstance(v, SdoCounters):
                aborts = dict.copy(v.aborts)
                out["sdo_uploads"] = v.uploads
                out["sdo_downloads"] = v.downloads
                out["sdo_client_aborts"] = v.client_aborts
                out["sdo_aborts"] = sum(aborts.values())
                for code, n in sorted(aborts.items()):
                    out[f"sdo_abort_0x{code:08X}"] = int(n)
            else:
                out[f.name] = int(v)
        out["malformed"] = self.malformed_total
        out["impersonated"] = self.impersonated_total
        return out


def install_diagnostics(od: ObjectDictionary, c: NodeCounters) -> None:
    """0x2010 sub 1-7 read the counters live: SYNCs received, SYNCs missed,
    watchdog trips, clipped outputs, malformed frames, SDO aborts, impersonated frames."""
    getters = (
        lambda: c.sync_received,
        lambda: c.syncs_missed,
        lambda: c.watchdog_trips,
        lambda: c.clipped_outputs,
        lambda: c.malformed_total,
        lambda: sum(c.sdo.aborts.values()),
        lambda: c.impersonated_total,
    )
    for sub, fn in enumerate(getters, start=1):
        od.getter(OD_DIAGNOSTICS, sub, fn)
