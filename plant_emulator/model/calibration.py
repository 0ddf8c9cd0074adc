"""How the structure's defaults were fitted, reproducibly.

``ralf-hil plant calibration`` prints the calibration metrics of the
current defaults; ``--fit`` re-runs the fit of the three
stiffnesses (the masses and geometry are chosen, not fitted: see
docs/plant-model.md) and prints the parameters to paste into
:class:`plant_emulator.model.modes.Structure`.

Targets (thesis §3 "Dynamics"):

* mean first-mode frequency over the inspection loop (sampled in time at
  5 in/s, pauses included): 4.4 Hz without, 3.6 Hz with the 15.65 lb payload;
* the two modes closest near the apex of the loop (the top of the
  workspace): f2/f1 = 1.4 there, at least 1.9 at the bottom of the loop.

Reported but not fitted: the spread of the first mode over the workspace
(target "about 50 %") and the static deflections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plant_emulator.model import kinematics as kin
from plant_emulator.model.modes import DEFAULT_STRUCTURE, Structure, modal_parameters, static_deflection_in

APEX_RAD = (math.radians(87.842), math.radians(17.083))
"""Top of the loop's first (radial) section: the trajectory's apex."""
BOTTOM_RAD = (math.radians(66.62), math.radians(69.70))
"""A corner of the loop's bottom row."""


@dataclass(frozen=True)
class CalibrationMetrics:
    mean_f1_hz: float
    mean_f1_payload_hz: float
    workspace_f1_min_hz: float
    workspace_f1_max_hz: float
    workspace_f1_mean_hz: float
    variation: float
    """(max - min) / mean of f1 over a uniform joint-space grid of the workspace."""
    max_over_min: float
    apex_hz: tuple[float, float]
    apex_payload_hz: tuple[float, float]
    apex_ratio: float
    bottom_hz: tuple[float, float]
    bottom_ratio: float
    min_ratio_on_loop: float
    min_ratio_theta2_deg: float
    static_mm: tuple[float, float, float]
    """min, median, max over the loop of the larger link deflection, no payload."""
    static_payload_mm: tuple[float, float, float]


def metrics(structure: Structure = DEFAULT_STRUCTURE, dt_s: float = 0.02) -> CalibrationMetrics:
    tr = kin.sample_trajectory(dt_s=dt_s)
    f, _ = modal_parameters(tr.theta1_rad, tr.theta2_rad, False, structure)
    fp, _ = modal_parameters(tr.theta1_rad, tr.theta2_rad, True, structure)
    g1, g2 = kin.workspace_grid(41, 111)
    fw = modal_parameters(g1, g2, False, structure)[0][:, 0]
    fa = modal_parameters(*APEX_RAD, False, structure)[0]
    fap = modal_parameters(*APEX_RAD, True, structure)[0]
    fb = modal_parameters(*BOTTOM_RAD, False, structure)[0]
    ratio = f[:, 1] / f[:, 0]
    i = int(np.argmin(ratio))

    def stat(p: bool) -> tuple[float, float, float]:
        sd = np.abs(static_deflection_in(tr.theta1_rad, tr.theta2_rad, p, structure)).max(axis=-1) * 25.4
        return float(sd.min()), float(np.median(sd)), float(sd.max())

    return CalibrationMetrics(
        mean_f1_hz=float(f[:, 0].mean()),
        mean_f1_payload_hz=float(fp[:, 0].mean()),
        workspace_f1_min_hz=float(fw.min()),
        workspace_f1_max_hz=float(fw.max()),
        workspace_f1_mean_hz=float(fw.mean()),
        variation=float((fw.max() - fw.min()) / fw.mean()),
        max_over_min=float(fw.max() / fw.min()),
        apex_hz=(float(fa[0]), float(fa[1])),
        apex_payload_hz=(float(fap[0]), float(fap[1])),
        apex_ratio=float(fa[1] / fa[0]),
        bottom_hz=(float(fb[0]), float(fb[1])),
        bottom_ratio=float(fb[1] / fb[0]),
        min_ratio_on_loop=float(ratio[i]),
        min_ratio_theta2_deg=float(np.degrees(tr.theta2_rad[i])),
        static_mm=stat(False),
        static_payload_mm=stat(True),
    )


FITTED = ("link1_root_stiffness_nm_per_rad", "bar_stiffness_n_per_m")
"""Fitted to the modal targets below.  Link 2's root stiffness is not: the modal
targets leave one stiffness free, and k_r2 is set instead by how much of link 2's
deflection its camera sees (docs/plant-model.md, "What the cameras see")."""


def fit(start: Structure = DEFAULT_STRUCTURE, fitted: tuple[str, ...] = FITTED) -> Structure:
    """Least-squares fit of the stiffnesses ``fitted`` to the targets above."""
    from scipy.optimize import least_squares

    scale = np.array([getattr(start, n) for n in fitted])

    def make(z: np.ndarray) -> Structure:
        return start.model_copy(update={n: float(v) for n, v in zip(fitted, z * scale, strict=True)})

    def residuals(z: np.ndarray) -> np.ndarray:
        m = metrics(make(z), dt_s=0.05)
        return np.array(
            [
                (m.mean_f1_hz - 4.4) / 0.01,
                (m.mean_f1_payload_hz - 3.6) / 0.01,
                (m.apex_ratio - 1.4) / 0.02,
                max(0.0, 1.9 - m.bottom_ratio) / 0.02,
            ]
        )

    res = least_squares(residuals, np.ones(len(fitted)), bounds=(0.05, 20.0), x_scale="jac")
    return make(res.x)


if __name__ == "__main__":
    from service_kit.moved import exit_moved

    exit_moved("python -m plant_emulator.model.calibration", "ralf-hil plant calibration")
