"""The plant link's counters (:class:`controller.plant_link.PlantLink`):
frames sent and received, and every frame judged foreign, forged or
malformed on the way, as its health reports them."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PlantLinkCounters"]


@dataclass
class PlantLinkCounters:
    syncs_sent: int = 0
    """SYNC frames sent (one per control tick, and retries)"""
    tpdos: int = 0
    """TPDO1 frames (the plant's samples) taken"""
    tpdo_timeouts: int = 0
    """waits for a TPDO1 that ended without one"""
    extra_tpdos: int = 0
    """TPDO1 frames that came while another was still untaken"""
    stale_tpdos: int = 0
    """TPDO1 frames still untaken at the next SYNC (a late answer): dropped"""
    rpdos_sent: int = 0
    """RPDO1 frames (valve voltages) sent"""
    heartbeats: int = 0
    """heartbeats from the plant node"""
    emergencies: int = 0
    """EMCY frames from the plant node"""
    malformed: int = 0
    """frames from the plant that did not decode (dropped)"""
    outputs_clipped: int = 0
    """valve voltages clipped to the D/A range (per output)"""
    rx_errors: int = 0
    """received datagrams/frames the bus could not decode (dropped)"""
    own_echoes: int = 0
    """our own frames seen again (udp_multicast loopback)"""
    foreign_sync: int = 0
    """SYNC frames this link did not send: a second SYNC producer"""
    foreign_nmt: int = 0
    """NMT commands this link did not send"""
    foreign_rpdo: int = 0
    """RPDO1 frames to the node this link did not send"""
    foreign_sdo: int = 0
    """SDO requests to the node this link did not send"""
    foreign_sdo_reads: int = 0
    """of those, reads (uploads): counted, not a conflict (they change nothing)"""
    conflict_emcys: int = 0
    """SYNC_CONFLICT / RPDO_CONFLICT emergencies from the plant (not disowned by it)"""
    plant_model_faults: int = 0
    """PLANT_MODEL_FAULT emergencies from the plant (not disowned by it): its model's step failed"""
    plant_model_dead: int = 0
    """of those, the ones after which the model makes no further step (the plant fault policy ends the run)"""
    comm_resets: int = 0
    """NMT RESET_COMMUNICATION sent before starting the node"""
    surplus_tpdos: int = 0
    """TPDO1 frames beyond one per SYNC sent (one late answer allowed): another node answers on the plant's TPDO1"""
    ambiguous_samples: int = 0
    """ticks whose TPDO1 came twice before it was taken: no sample (the loop holds the last one)"""
    forged_heartbeats: int = 0
    """heartbeats on the plant's COB-ID contradicted by the plant (its EMCY 0x8150, a later TPDO1 or heartbeat)"""
    forged_emcys: int = 0
    """EMCYs on the plant's COB-ID the plant disowned (its EMCY 0x8150)"""
    impersonations: int = 0
    """EMCY CAN_ID_COLLISION from the plant: frames on its COB-IDs it did not send"""
    comm_restores: int = 0
    """SDO writes of a configured object sent back after another master's write"""
    plant_can_error_passive: int = 0
    """EMCY 0x8120 from the plant: its CAN controller went error passive (ralfwire with injected errors)"""
    plant_can_bus_off_recoveries: int = 0
    """EMCY 0x8140 from the plant: its CAN controller recovered from bus off"""
    own_can_error_passive: int = 0
    """times the controller's own CAN controller was seen error passive (a bus that tells its error state)"""
    own_can_bus_off: int = 0
    """times the controller's own CAN controller was seen bus off"""
    kernel_drops: int = 0
    """datagrams the kernel dropped for a full receive buffer (the bus's count)"""
    fd_frames_dropped: int = 0
    """CAN FD frames the bus dropped (the rig speaks classic CAN)"""
    junk_frames: int = 0
    """datagrams on the CAN group that were not CAN frames, skipped by the bus before decoding (the bus's count)"""

    def as_dict(self) -> dict[str, int]:
        return dict(vars(self))
