"""The controller's settings (``RALF_*``, :class:`~protocol.settings.ControllerSettings`)
mapped into the terms of its pure core, as the plant (``node_config``) and the
DSP (``identifier_config``) map theirs: the control law's configuration, the
trajectory lap, and the run's length."""

from __future__ import annotations

from controller.excitation import DitherConfig
from controller.loop import LawConfig
from controller.oatf import OatfConfig
from controller.trajectory import DEFAULT_TRAJECTORY_PATH, SampledTrajectory, load_trajectory, sample_trajectory
from protocol.settings import ControllerSettings


def law_config(settings: ControllerSettings) -> LawConfig:
    """The control law's configuration: sample period and the OATF's mode,
    place, initial design and fallback, and its design rules (thesis §4.1);
    the valve commands' dither (off by default, :mod:`controller.excitation`)."""
    ts = settings.sample_period_s
    oatf = OatfConfig(
        sample_period_s=ts,
        design_zeta=settings.oatf_damping,
        delay_mode="fixed" if settings.oatf_delay_s else "robust",
        fixed_delay_s=settings.oatf_delay_s or 0.05,
        plausible_band_hz=settings.oatf_band_hz,
        min_confidence=settings.oatf_min_confidence,
        max_stages=settings.oatf_max_stages,
        adapt_damping=settings.oatf_adapt_damping,
    )
    return LawConfig(
        sample_period_s=ts,
        oatf_mode=settings.oatf_mode,
        oatf_location=settings.oatf_location,
        oatf_frequency_hz=settings.oatf_frequency_hz,
        oatf_fallback=settings.oatf_fallback,
        oatf=oatf if settings.oatf_mode != "off" else None,
        dither=DitherConfig(amplitude_v=settings.dither_amplitude_v, band_hz=settings.dither_band_hz, seed=settings.dither_seed),
    )


def build_trajectory(settings: ControllerSettings) -> SampledTrajectory:
    """One lap of the configured trajectory at the configured speed and rate."""
    traj = load_trajectory(settings.trajectory or DEFAULT_TRAJECTORY_PATH)
    return sample_trajectory(traj, settings.sample_period_s, speed_in_per_s=settings.tip_speed_in_s)


def run_ticks(settings: ControllerSettings, lap_ticks: int) -> int | None:
    """How many ticks the run lasts (None: until stopped)."""
    if settings.duration_s is not None:
        return int(round(settings.duration_s * settings.sample_rate_hz))
    if settings.repeats > 0:
        return settings.repeats * lap_ticks
    return None
