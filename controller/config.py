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
from protocol.stimulus import parse_stimulus


def law_config(settings: ControllerSettings) -> LawConfig:
    """The control law's configuration: sample period and the OATF's mode,
    place, initial design and fallback, and its design rules (thesis §4.1);
    the valve commands' dither (off by default, :mod:`controller.excitation`); the PI gains;
    the stimulus profiles (none by default, :mod:`protocol.stimulus`)."""
    ts = settings.sample_period_s
    tuning, dither = settings.oatf, settings.dither
    oatf = OatfConfig(
        sample_period_s=ts,
        design_zeta=tuning.damping,
        delay_mode="fixed" if tuning.delay_s else "robust",
        fixed_delay_s=tuning.delay_s or 0.05,
        plausible_band_hz=tuning.band_hz,
        min_confidence=tuning.min_confidence,
        max_stages=tuning.max_stages,
        adapt_damping=tuning.adapt_damping,
    )
    return LawConfig(
        sample_period_s=ts,
        oatf_mode=settings.oatf_mode,
        oatf_location=tuning.location,
        oatf_frequency_hz=tuning.frequency_hz,
        oatf_fallback=tuning.fallback,
        oatf=oatf if settings.oatf_mode != "off" else None,
        dither=DitherConfig(amplitude_v=dither.amplitude_v, band_hz=dither.band_hz, seed=dither.seed),
        pi_gains=settings.pi,
        stimulus=parse_stimulus(settings.stimulus, "controller"),
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
