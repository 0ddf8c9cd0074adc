"""The controller's TF downloader (controller/tf_download.py) in real time:
one worker thread for the whole run, a download asked while one is under
way counted as a failure, a malformed snapshot counted and dropped."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from controller.tf_download import TfDownloader
from protocol import messages as m
from protocol.tf_codec import encode_tf
from service_kit.clock import RealTimeScheduler


def _payload(seq: int) -> bytes:
    snap = m.TfSnapshot(
        seq=seq,
        sim_time_s=1.0,
        batch_seq=4,
        freqs_hz=np.arange(4.0),
        valid=[True, True, False, True],
        estimates={"Htot": m.TransferFunction(np.ones(4), np.zeros(4))},
    )
    return encode_tf(snap)


@dataclass
class FakePort:
    replies: list[bytes]
    gate: threading.Event = field(default_factory=threading.Event)
    published: list[bytes] = field(default_factory=list)
    threads: set[str] = field(default_factory=set)

    def download_tf(self, timeout_s: float) -> list[bytes]:
        self.threads.add(threading.current_thread().name + str(threading.get_ident()))
        self.gate.wait(5.0)
        return [self.replies.pop(0)]

    def publish_tf(self, payload: bytes) -> None:
        self.published.append(payload)


def _counters() -> SimpleNamespace:
    return SimpleNamespace(tf_downloads=0, tf_download_failures=0, tf_download_retries=0, undecodable=0)


def _downloader(port: FakePort, counters: SimpleNamespace) -> TfDownloader:
    return TfDownloader(port, RealTimeScheduler(), counters, lockstep=False, every_samples=10, lockstep_timeout_s=1.0, resend_s=0.1, keep_all=True)  # type: ignore[arg-type]


def _wait_idle(dl: TfDownloader) -> None:
    for _ in range(6000):  # up to 60 s: a starved host is slow, not wrong
        if not dl._busy:
            return
        threading.Event().wait(0.01)
    raise AssertionError("the download did not finish")


def _download_twice(replies: list[bytes]) -> tuple[FakePort, SimpleNamespace, TfDownloader]:
    """A real-time downloader whose port answers at once, after downloads at ticks 10 and 20."""
    port = FakePort(list(replies))
    c = _counters()
    dl = _downloader(port, c)
    port.gate.set()
    for tick in (10, 20):
        dl.on_tick(tick, dsp_idle=False, dsp_alive=True)
        _wait_idle(dl)
    return port, c, dl


def test_one_worker_serves_every_download_and_a_busy_one_counts_as_failed() -> None:
    payloads = [_payload(0), _payload(1), _payload(2)]
    port, c, dl = _download_twice(payloads)
    assert c.tf_downloads == 2 and c.tf_download_failures == 0
    assert len(port.threads) == 1  # the same worker thread both times
    port.gate.clear()
    dl.on_tick(30, dsp_idle=False, dsp_alive=True)  # blocks in the port until the gate opens
    dl.on_tick(40, dsp_idle=False, dsp_alive=True)  # still busy: a failure, no second request
    assert c.tf_download_failures == 1
    port.gate.set()
    _wait_idle(dl)
    dl.join(timeout=30.0)
    assert dl._thread is not None and not dl._thread.is_alive()
    assert c.tf_downloads == 3 and [s.seq for s in dl.snapshots] == [0, 1, 2]
    assert port.published == payloads  # republished as downloaded


def test_a_malformed_snapshot_is_counted_and_dropped() -> None:
    good = _payload(0)
    port, c, dl = _download_twice([good[:-3], good[:4] + b"\x09" + good[5:]])  # truncated; a version this build does not read
    dl.join(timeout=30.0)
    assert (c.undecodable, c.tf_download_failures, c.tf_downloads) == (2, 2, 0)
    assert dl.snapshots == [] and port.published == []


def test_the_worker_can_start_before_the_first_download() -> None:
    """The loop starts the worker before its first tick (a thread started inside
    a tick makes the tick wait for it to run); the downloads then use it, and
    a lockstep downloader never starts one."""
    port = FakePort([_payload(0)])
    c = _counters()
    dl = _downloader(port, c)
    dl.start_worker()
    worker = dl._thread
    assert worker is not None and worker.is_alive()
    dl.start_worker()
    assert dl._thread is worker  # started once
    port.gate.set()
    dl.on_tick(10, dsp_idle=False, dsp_alive=True)
    _wait_idle(dl)
    assert c.tf_downloads == 1 and port.threads == {worker.name + str(worker.ident)}
    dl.join(timeout=30.0)
    lockstep = TfDownloader(port, RealTimeScheduler(), c, lockstep=True, every_samples=10, lockstep_timeout_s=1.0, resend_s=0.1, keep_all=True)  # type: ignore[arg-type]
    lockstep.start_worker()
    assert lockstep._thread is None
