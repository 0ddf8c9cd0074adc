from __future__ import annotations

from pathlib import Path

import pytest

from plant_emulator.fmu.build import EXAMPLE_SOURCE, build_c_fmu


@pytest.fixture(scope="session")
def two_mode_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The example plant FMU, compiled for this machine."""
    return build_c_fmu(EXAMPLE_SOURCE, tmp_path_factory.mktemp("fmu") / "two_mode_plant.fmu")
