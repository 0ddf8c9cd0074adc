"""The plant model the settings name (``plant.model``), built: the RALF arm
with its :class:`~plant_emulator.model.PlantConfig` taken from the plant's
settings, or the FMU at ``fmu:PATH``. Both are a
:class:`~plant_emulator.plant_model.PlantModel` to the node."""

from __future__ import annotations

from plant_emulator.model import PlantConfig
from plant_emulator.plant_model import PlantModel
from protocol.settings import PlantSettings

__all__ = ["build_plant_model", "plant_config"]


def plant_config(settings: PlantSettings) -> PlantConfig:
    return PlantConfig(
        seed=settings.seed,
        payload_attached=settings.payload_attached,
        valve_time_constant_s=settings.valve_time_constant_s,
        adc_bits=settings.adc_bits,
        **_scaled_noise(settings.sensor_noise_scale),
    )


def _scaled_noise(scale: float) -> dict[str, tuple[float, float]]:
    """The thesis's sensor noise stds (the PlantConfig defaults) times ``scale`` (only when it is not 1)."""
    if scale == 1.0:
        return {}
    fields = PlantConfig.model_fields
    return {k: tuple(scale * x for x in fields[k].default) for k in ("extension_noise_std_in", "deflection_noise_std_in")}


def build_plant_model(settings: PlantSettings) -> PlantModel:
    """The model ``settings.model`` names: the RALF arm, or the FMU at
    ``fmu:PATH`` with the mapping ``settings.fmu_mapping`` (checked, one
    step of the sample period tried, then instantiated; a bad FMU raises
    :class:`protocol.errors.ConfigError` in one line)."""
    if settings.model == "ralf":
        from plant_emulator.model import RalfArm

        return RalfArm(plant_config(settings))
    from plant_emulator.fmu import open_fmu_plant

    return open_fmu_plant(settings)
