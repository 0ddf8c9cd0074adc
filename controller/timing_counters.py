"""The controller loop's own counters (health, run result)."""

from __future__ import annotations

from dataclasses import dataclass

from service_kit.counters import Counters


@dataclass
class TimingCounters(Counters):
    overruns: int = 0
    stale_ticks: int = 0
    stale_episodes: int = 0
    interrupts_applied: int = 0
    oatf_updates: int = 0
    undecodable: int = 0
    tf_downloads: int = 0
    tf_download_failures: int = 0
    dsp_lost: int = 0
    dsp_found: int = 0
    lockstep_waits: int = 0
    syncs_dropped: int = 0
    sync_retries: int = 0
    schedule_resyncs: int = 0
    reconfigurations: int = 0
    """Run-time commands taken (each one changed the configuration under the run)."""
    test_knob_changes: int = 0
    """Of them, those that set a test knob (protocol/command_fields.py)."""
    periods_skipped: int = 0
    batch_resends: int = 0
    tf_download_retries: int = 0
