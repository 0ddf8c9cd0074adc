"""Transfer-function downloads from the DSP (thesis §4.2.2: every
``tf_download_samples`` samples the CPU reads the DSP's current estimates).

In lockstep and the co-simulation a download is made in the loop's thread
while no batch is in flight (the DSP is idle, so the snapshot is
deterministic) and retried until ``lockstep_timeout_s``; in real time it
runs in a worker thread of its own so the query never holds up the loop (a
download still under way when the next is due counts as a failure). The
worker is started once, by the loop's first download (so it inherits the
loop's FIFO policy and steps one level below it), and then woken per
download: starting a thread in the loop's tick cost that tick ~0.1 ms, and
the new thread contended for the GIL while the tick ran.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from controller.dsp_port import DspPort
from protocol.errors import ProtocolError
from protocol.messages import TfSnapshot
from protocol.tf_codec import decode_tf
from service_kit.clock import Scheduler
from service_kit.query_gate import QUERY_LIMITS
from service_kit.realtime import helper_priority, lower_current_thread

RETRY_SPACING_S = 1.0 / QUERY_LIMITS["tf"].rate_per_s
"""Lockstep: a download the DSP refused (over its TF query rate) is asked again no sooner than this."""

log = logging.getLogger(__name__)


@dataclass
class TfDownloader:
    port: DspPort
    clock: Scheduler
    counters: Any
    """The controller's timing counters (``tf_downloads``, ``tf_download_failures``, ``tf_download_retries``, ``undecodable``)."""
    lockstep: bool
    every_samples: int
    lockstep_timeout_s: float
    resend_s: float
    keep_all: bool
    """Keep every snapshot (a record will save them); else only the latest."""
    snapshots: list[TfSnapshot] = field(default_factory=list)
    due: bool = False
    _thread: threading.Thread | None = None
    _wake: threading.Event = field(default_factory=threading.Event)
    _busy: bool = False
    """A download was asked of the worker and has not finished."""
    _closing: bool = False

    def on_tick(self, tick: int, dsp_idle: bool, dsp_alive: bool) -> None:
        """Called once per tick after the sample joined the batch."""
        if self.every_samples and tick > 0 and tick % self.every_samples == 0:
            self.due = True
        if not self.due:
            return
        if self.lockstep:
            if dsp_idle:  # the DSP is idle: the snapshot is deterministic
                self.due = False
                self.download()
        elif dsp_alive:
            self.due = False
            if self._busy:
                self.counters.tf_download_failures += 1  # the previous download is still under way
                return
            self._busy = True
            self.start_worker()  # started before the loop's first tick (run): nothing to do here then
            self._wake.set()

    def start_worker(self) -> None:
        """Start the real-time download worker if it is not running. The loop
        calls it before its first tick, once its real-time measures are in
        effect: ``Thread.start`` waits for the new thread to run, and the new
        thread starts on the normal scheduler (the loop's FIFO resets on
        fork), so inside a tick it could wait behind any other process."""
        if self._thread is None and not self.lockstep:
            self._thread = threading.Thread(target=self._worker, args=(helper_priority(),), name="tf-download", daemon=True)
            self._thread.start()

    def _worker(self, priority: int) -> None:
        lower_current_thread(priority)  # started by the loop: one FIFO level below it, if it runs FIFO
        while True:
            self._wake.wait()
            self._wake.clear()
            if self._closing:
                return
            try:
                self.download()
            finally:
                self._busy = False

    def download(self) -> None:
        c = self.counters
        try:
            replies = self.port.download_tf(self.resend_s if self.lockstep else 2.0)
            if self.lockstep:
                # Ask again (the DSP is idle, the answer is the same) until
                # lockstep_timeout_s, so a reply lost on a starved host costs time only.
                deadline = self.clock.now() + self.lockstep_timeout_s
                while not replies and self.clock.now() < deadline and not self.clock.stopping:
                    c.tf_download_retries += 1
                    asked = time.monotonic()
                    replies = self.port.download_tf(self.resend_s)
                    if not replies:  # refused at once (over the DSP's query rate): ask again no sooner than the rate allows
                        time.sleep(max(0.0, RETRY_SPACING_S - (time.monotonic() - asked)))
        except Exception as exc:  # a dying session must not end the run
            c.tf_download_failures += 1
            log.warning("TF download failed: %s", exc)
            return
        for reply in replies:
            try:
                self.snapshots.append(decode_tf(reply))
                if not self.keep_all:
                    del self.snapshots[:-1]  # nothing will save them: keep the latest only
                c.tf_downloads += 1
                self.port.publish_tf(reply)  # controller/tf: each download, for recorders and viewers
                return
            except ProtocolError as exc:
                c.undecodable += 1
                log.warning("bad TF snapshot: %s", exc)
        c.tf_download_failures += 1

    def join(self, timeout: float) -> None:
        """Let a download under way finish (up to ``timeout``), then end the worker."""
        if self._thread is not None:
            self._closing = True
            self._wake.set()
            self._thread.join(timeout=timeout)
