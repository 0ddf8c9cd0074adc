"""The controller loop's own counters (health, run result)."""

from __future__ import annotations

from dataclasses import dataclass

from service_kit.counters import Counters


@dataclass
class TimingCounters(Counters):
    overruns: int = 0
    """ticks whose work ran past the next SYNC (real time)"""
    stale_ticks: int = 0
    """ticks run on parameters older than the stale limit (timeouts.stale_after_s)"""
    stale_episodes: int = 0
    """times the parameters went stale"""
    interrupts_applied: int = 0
    """interrupts taken by the control law (matched to their batch)"""
    oatf_updates: int = 0
    """interrupts that changed the OATF's shaping"""
    undecodable: int = 0
    """DSP-side messages or TF snapshots that did not decode (dropped)"""
    tf_downloads: int = 0
    """transfer-function snapshots downloaded from the DSP"""
    tf_download_failures: int = 0
    """TF downloads that failed or found the previous one still under way"""
    dsp_lost: int = 0
    """times the DSP's liveliness went away"""
    dsp_found: int = 0
    """times the DSP's liveliness came (back)"""
    lockstep_waits: int = 0
    """lockstep: waits for a batch's interrupt"""
    syncs_dropped: int = 0
    """SYNCs a link fault dropped (nothing sent)"""
    sync_retries: int = 0
    """SYNCs sent again because the plant's TPDO did not come"""
    schedule_resyncs: int = 0
    """real time: times the loop was so late that its schedule was re-based"""
    reconfigurations: int = 0
    """Run-time commands taken (each one changed the configuration under the run)."""
    test_knob_changes: int = 0
    """Of them, those that set a test knob (protocol/command_fields.py)."""
    periods_skipped: int = 0
    """real time: sample instants skipped by those re-basings"""
    batch_resends: int = 0
    """lockstep: batches sent again while waiting for their interrupt"""
    tf_download_retries: int = 0
    """lockstep: TF downloads asked again after no reply"""
    plant_faults: int = 0
    """plant faults that ended the run (heartbeat or TPDOs lost, the node out of OPERATIONAL, the model dead)"""
    valves_zeroed: int = 0
    """times the valves were commanded to zero at the run's end (every end, a plant fault's included)"""
