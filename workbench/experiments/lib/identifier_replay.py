"""The DSP's identifiers replayed from a run's record, sample for sample.

The DSP's inputs are the controller record's valve commands ``u1_v``, ``u2_v``
and its outputs the measured deflections ``defl1_in``, ``defl2_in``, pushed in
batches of the run's batch size from tick 0. Replaying them through the same
identifier, configured from the run's DSP settings, gives what the run's
downloads hold and what they do not (the complex estimate, which solve each
bin used, the ARX model's own transfer functions).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from workbench.rig_record import RunRecord

__all__ = ["arx_memory_s", "record_inputs", "record_io", "replay_arx_responses", "replay_downloads"]


def record_inputs(res: RunRecord) -> np.ndarray:
    """The DSP's inputs ``(2, n)`` from the record: the valve commands (V)."""
    return np.vstack([np.asarray(res.columns["u1_v"], dtype=float), np.asarray(res.columns["u2_v"], dtype=float)])


def record_io(res: RunRecord) -> tuple[np.ndarray, np.ndarray]:
    """The DSP's inputs ``(2, n)`` (valve commands, V) and outputs ``(2, n)`` (deflections, in) from the record."""
    return record_inputs(res), np.vstack([np.asarray(res.columns["defl1_in"], dtype=float), np.asarray(res.columns["defl2_in"], dtype=float)])


def replay_downloads(res: RunRecord, batch_size: int) -> dict[int, Any]:
    """The DSP's ETFE replayed from the controller's record: per download index, the
    :class:`~dsp_service.identifier.TransferFunctionEstimate` (complex H, per-bin solve ``mode``) whose
    magnitudes equal the download's (a download holds the estimate after the batch ending at its
    ``sim_time_s``: the batches around it are tried). Downloads the replay does not reproduce to 1e-9
    (relative) are left out."""
    from dsp_service.core import identifier_config
    from dsp_service.identifier import Identifier
    from protocol.settings import DspSettings

    tf = res.tf
    if tf is None:
        return {}
    u, y = record_io(res)
    ident = Identifier(identifier_config(DspSettings(**dict(res.settings["dsp"]))))
    dl_t = np.asarray(tf["sim_time_s"], dtype=float)
    want: dict[int, list[int]] = {}
    for i, ts in enumerate(dl_t):
        k = int(round(ts / (batch_size * res.sample_period_s))) - 1
        for kk in (k, k - 1, k + 1, k - 2, k + 2):
            want.setdefault(kk, []).append(i)
    found: dict[int, Any] = {}
    for k in range(u.shape[1] // batch_size):
        ident.push(u[:, k * batch_size : (k + 1) * batch_size], y[:, k * batch_size : (k + 1) * batch_size])
        ident.step()
        pending = [i for i in want.get(k, []) if i not in found]
        if not pending:
            continue
        est = ident.transfer_functions()
        for i in pending:
            got = np.abs(np.nan_to_num(np.asarray(est.htot), nan=0.0))
            ref = np.asarray(tf["Htot_mag"][i], dtype=float)
            if np.any(ref > 0) and np.max(np.abs(got - ref)) <= 1e-9 * max(1e-30, float(np.max(ref))):
                found[i] = est
    return found


def replay_arx_responses(res: RunRecord, batch_size: int, at_batches: dict[int, int], freqs: np.ndarray) -> dict[int, np.ndarray]:
    """The DSP's recursive ARX replayed from the record (the same configuration as the run's DSP): per
    download index, the model's ``H11, H12, H21, H22`` (``(4, n)``) after the batch ``at_batches`` names for it."""
    from dsp_service.arx import RecursiveArx
    from dsp_service.core import identifier_config
    from dsp_service.identifier import arx_config
    from protocol.settings import DspSettings

    u, y = record_io(res)
    model = RecursiveArx(arx_config(identifier_config(DspSettings(**dict(res.settings["dsp"])))))
    model.restart()
    out: dict[int, np.ndarray] = {}
    last = max(at_batches, default=-1)
    for k in range(min(u.shape[1] // batch_size, last + 1)):
        model.update(u[:, k * batch_size : (k + 1) * batch_size], y[:, k * batch_size : (k + 1) * batch_size])
        if k in at_batches:
            out[at_batches[k]] = model.frequency_response(freqs)
    return out


def arx_memory_s(fs_hz: float) -> float:
    """The DSP's recursive ARX's exponential memory (s): its decimation over its forgetting, at the default configuration."""
    from dsp_service.identifier import IdentifierConfig

    c = IdentifierConfig()
    return c.arx_decimation / (fs_hz * (1.0 - c.arx_forgetting))
