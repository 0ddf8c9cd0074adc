"""The example C source FMU (examples/fmu/two_mode_plant) built with gcc against
FMPy's FMI headers, and mappings for it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from plant_emulator.fmu.build import EXAMPLE_MAPPING

__all__ = ["EXAMPLE_MAPPING", "write_mapping"]


def write_mapping(directory: Path, name: str = "map.yaml", parameters: dict[str, Any] | None = None, **changes: Any) -> Path:
    """The example mapping with ``parameters`` merged into its own and top-level keys replaced by ``changes``."""
    data = yaml.safe_load(EXAMPLE_MAPPING.read_text())
    data["parameters"] = {**data.get("parameters", {}), **(parameters or {})}
    data.update(changes)
    path = directory / name
    path.write_text(yaml.safe_dump(data))
    return path


def plant_settings(fmu: Path, mapping: Path, **more: Any) -> dict[str, Any]:
    return {"model": f"fmu:{fmu}", "fmu_mapping": str(mapping), **more}
