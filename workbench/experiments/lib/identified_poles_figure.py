"""A run's deflections, its configuration and its identified poles beside the plant's true modes, in one figure."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from workbench.experiments.report import new_figure
from workbench.rig_record import RunRecord

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["deflections_and_poles_figure"]


def deflections_and_poles_figure(res: RunRecord, th2: np.ndarray, shaded: np.ndarray, step: int = 20) -> Figure:
    """Both links' measured deflections, θ2, and the true modal frequencies (on the controller's clock) with the
    identified poles (``f_id_hz`` dots coloured by ``id_confidence``, ``f_id2_hz`` crosses; every ``step``-th tick);
    the ticks where ``shaded`` holds are shaded in every panel."""
    t = res.t_s
    c = res.columns
    truth_t = np.asarray(res.truth_columns["sim_time_s"]) - res.sample_period_s
    truth_f = np.asarray(res.truth_columns["modal_frequencies_hz"])
    f_id, f_id2, conf = (np.asarray(c[k], dtype=float) for k in ("f_id_hz", "f_id2_hz", "id_confidence"))
    fig = new_figure(11.0, 8.5)
    ax1, ax2, ax3, ax4 = fig.subplots(4, 1, sharex=True, gridspec_kw={"height_ratios": [1, 1, 0.7, 1.4]})
    for ax in (ax1, ax2, ax3, ax4):
        ax.fill_between(t, 0, 1, where=shaded, color="0.9", transform=ax.get_xaxis_transform(), lw=0)
        ax.grid(True, lw=0.3)
    ax1.plot(t, c["defl1_in"], lw=0.6)
    ax1.set_ylabel("link 1 defl. (in)")
    ax2.plot(t, c["defl2_in"], lw=0.6, color="tab:red")
    ax2.set_ylabel("link 2 defl. (in)")
    ax3.plot(t, th2, lw=0.8, color="k")
    ax3.set_ylabel("θ2 (rad)")
    ax4.plot(truth_t, truth_f[:, 0], color="k", lw=1.2, label="true mode 1")
    ax4.plot(truth_t, truth_f[:, 1], color="k", lw=1.0, ls="--", label="true mode 2")
    sc = ax4.scatter(t[::step], f_id[::step], c=conf[::step], s=4, cmap="viridis", vmin=0, vmax=0.6, label="identified pole 1")
    ax4.scatter(t[::step], f_id2[::step], s=4, marker="x", color="tab:orange", lw=0.5, label="identified pole 2")
    ax4.set_ylim(0, 14)
    ax4.set_ylabel("frequency (Hz)")
    ax4.set_xlabel("time (s)")
    ax4.legend(fontsize=7, ncol=4, loc="upper right")
    fig.colorbar(sc, ax=ax4, label="confidence", pad=0.01, fraction=0.03)
    return fig
