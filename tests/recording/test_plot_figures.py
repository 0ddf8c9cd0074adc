"""``ralf-hil plot``'s modes and TF-spectrogram figures on a synthetic recording: the pole colours follow the
frequency order, the time before the first estimate is marked, and the spectrogram counts what it draws."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.figure import Figure

from workbench.recording import plot

T = np.arange(0.0, 30.0, 0.5)


class FakeRecording:
    """What the two figures read from a :class:`~workbench.recording.reader.Recording`."""

    def truth(self) -> dict[str, np.ndarray]:
        return {"sim_time_s": T, "modal_frequencies_hz": np.column_stack([np.full(T.size, 4.0), np.full(T.size, 7.0)])}

    def interrupts(self) -> list[dict[str, Any]]:
        # no pole before 10.24 s; afterwards the DSP ranks the poles differently from one interrupt to the next
        out = []
        for k, t in enumerate(T):
            poles = [] if t < 10.24 else [{"frequency_hz": 7.1}, {"frequency_hz": 3.9}]
            out.append({"sim_time_s": float(t), "poles": poles if k % 2 else poles[::-1]})
        return out

    def settings(self, service: str) -> dict[str, Any]:
        return {"fft_width": 2048, "sample_rate_hz": 200.0}

    def tf_downloads(self) -> list[dict[str, Any]]:
        f = np.linspace(0.0, 100.0, 65)
        snaps = []
        for t in (5.0, 10.0, 15.0, 20.0):
            valid = np.full(f.size, t > 10.24)
            mag = np.where(valid, 1.0 + np.exp(-((f - 4.0) ** 2)), 0.0)
            snaps.append({"sim_time_s": t, "freqs_hz": f, "valid": valid, "estimates": {"Htot": {"magnitude": mag}}})
        return snaps


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> dict[str, Figure]:
    saved: dict[str, Figure] = {}

    def keep(fig: Figure, out: Path, name: str) -> Path:
        saved[name] = fig
        return out / name

    monkeypatch.setattr(plot, "_save", keep)
    rec: Any = FakeRecording()
    plot.plot_modes(rec, tmp_path)
    plot.plot_tf_spectrogram(rec, tmp_path)
    return saved


def test_the_identified_poles_keep_their_colour_whatever_the_dsp_ranking(figures: dict[str, Figure]) -> None:
    ax = figures["modes.png"].axes[0]
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    lower = np.asarray(lines["identified, lower pole"].get_ydata(), dtype=float)
    upper = np.asarray(lines["identified, upper pole"].get_ydata(), dtype=float)
    assert np.nanmax(lower) == pytest.approx(3.9) and np.nanmin(upper) == pytest.approx(7.1)


def test_the_time_before_the_first_estimate_is_marked_and_explained(figures: dict[str, Figure]) -> None:
    fig = figures["modes.png"]
    ax = fig.axes[0]
    assert any("N/fs = 10.24 s" in t.get_text() for t in ax.texts)
    assert ax.get_xlim()[0] == 0.0
    assert fig.get_supxlabel()  # the caption line


def test_the_spectrogram_counts_the_downloads_it_draws_from_time_zero(figures: dict[str, Figure]) -> None:
    fig = figures["tf_spectrogram.png"]
    ax = fig.axes[0]
    assert "2 of 4 downloads with an estimate" in ax.get_title()
    assert ax.get_xlim()[0] == 0.0
    assert "before its download" in fig.get_supxlabel()
