"""An FMI 2.0 / 3.0 co-simulation FMU as the plant (``plant.model=fmu:PATH``,
``plant.fmu_mapping=MAP.yaml``; docs/fmu-plant.md).

* :mod:`.mapping`: the YAML mapping of the node's I/O onto FMU variables;
* :mod:`.instance`: loading with FMPy, the checks that refuse a bad FMU
  before the rig starts, the per-step FMI calls;
* :mod:`.plant`: :class:`FmuPlant`, the
  :class:`~plant_emulator.plant_model.PlantModel` the node drives.
"""

from __future__ import annotations

from pathlib import Path

from plant_emulator.fmu.instance import FmuInstance, FmuRefused, check_fmu, open_fmu
from plant_emulator.fmu.mapping import FmuMapping, load_mapping
from plant_emulator.fmu.plant import FmuPlant
from protocol.settings import PlantSettings

__all__ = ["FmuInstance", "FmuMapping", "FmuPlant", "FmuRefused", "check_fmu", "fmu_path", "load_mapping", "open_fmu", "open_fmu_plant", "preflight"]


def fmu_path(model: str) -> Path:
    """The path of ``fmu:PATH``."""
    if not model.startswith("fmu:"):
        raise ValueError(f"not an FMU model setting: {model!r}")
    return Path(model.removeprefix("fmu:"))


def preflight(settings: PlantSettings) -> None:
    """The checks of :func:`open_fmu_plant` without keeping anything
    (instance freed, files removed): what the launcher runs before any
    service starts. Nothing for the built-in model."""
    if settings.model == "ralf":
        return
    check_fmu(fmu_path(settings.model), load_mapping(settings.fmu_mapping), settings.sample_period_s, settings.seed)


def open_fmu_plant(settings: PlantSettings) -> FmuPlant:
    """The FMU plant the settings name: mapping loaded, FMU checked, one
    step of the sample period tried on a throw-away instance, then the
    plant's own instance made and initialized."""
    mapping = load_mapping(settings.fmu_mapping)
    path = fmu_path(settings.model)
    check_fmu(path, mapping, settings.sample_period_s, settings.seed)
    instance = open_fmu(path, mapping, settings.seed)
    try:
        return FmuPlant(instance, settings.sample_period_s, settings.adc_bits)
    except ValueError as exc:
        instance.close()
        raise FmuRefused(str(exc)) from None
