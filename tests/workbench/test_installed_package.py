"""An installed ralf-hil (``pip install .``, not editable) carries what its
commands read: the example FMU's C source, model description and mapping
are package data, so ``experiment fmu-plant`` and ``plant fmu-build`` work
far from any checkout.

The installed copy is made as the wheel's is: setuptools' ``build_py`` of this
tree (the packages and their package data, per pyproject.toml) into a fresh
venv's site-packages; the venv reaches the third-party packages through a
``.pth`` file, and every command runs from a folder outside the tree."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE_DATA = [
    "plant_emulator/fmu/example/two_mode_plant/modelDescription.xml",
    "plant_emulator/fmu/example/two_mode_plant/two_mode_plant.c",
    "plant_emulator/fmu/example/two_mode_plant.yaml",
]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A venv whose site-packages holds this tree as installed (its Python)."""
    pytest.importorskip("setuptools")  # what pip itself builds the wheel with
    tmp = tmp_path_factory.mktemp("installed")
    build = tmp / "build"
    setup = [sys.executable, "-c", "from setuptools import setup; setup()", "-q", "build_py", "--build-lib", str(build)]
    done = subprocess.run(setup, cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    purelib = Path(
        subprocess.run(
            [venv / "bin" / "python", "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], capture_output=True, text=True, check=True
        ).stdout.strip()
    )
    shutil.copytree(build, purelib, dirs_exist_ok=True)
    # numpy, fmpy, ... where this environment has them (their folders only: no .pth of theirs, so no editable install)
    (purelib / "third_party.pth").write_text("".join(f"{p}\n" for p in sys.path if p.endswith("site-packages")))
    return venv / "bin" / "python"


def _run(python: Path, args: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH" and not k.startswith("RALF_")}
    return subprocess.run([str(python), "-P", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env, check=False)


def test_the_example_fmu_sources_are_package_data(installed: Path, tmp_path: Path) -> None:
    site = Path(_run(installed, ["-c", "import plant_emulator, pathlib; print(pathlib.Path(plant_emulator.__file__).parent.parent)"], tmp_path).stdout.strip())
    assert site.name == "site-packages" and site.parent.parent.parent == installed.parent.parent, site  # the venv's own, not the checkout
    for name in PACKAGE_DATA:
        assert (site / name).read_bytes() == (ROOT / name).read_bytes(), name
    # the checkout's examples/ reaches the same files
    assert (ROOT / "examples/fmu/two_mode_plant/two_mode_plant.c").resolve() == (ROOT / PACKAGE_DATA[1]).resolve()


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler to build the example FMU")
@pytest.mark.timeout(600)
def test_an_installed_package_builds_and_checks_the_example_fmu_outside_the_checkout(installed: Path, tmp_path: Path) -> None:
    built = _run(installed, ["-m", "workbench", "plant", "fmu-build"], tmp_path)
    assert built.returncode == 0 and (tmp_path / "two_mode_plant.fmu").is_file(), built.stdout + built.stderr
    mapping = _run(installed, ["-c", "from plant_emulator.fmu.build import EXAMPLE_MAPPING; print(EXAMPLE_MAPPING)"], tmp_path).stdout.strip()
    assert Path(mapping).is_relative_to(installed.parent.parent / "lib"), mapping
    # the launcher's check of an FMU plant: the FMU and the packaged mapping read, one step on a throw-away instance
    check = "from plant_emulator.fmu import preflight; from protocol.settings import PlantSettings, load_settings; "
    check += f"preflight(load_settings(PlantSettings, {{'model': 'fmu:two_mode_plant.fmu', 'fmu_mapping': {mapping!r}}})); print('checked')"
    done = _run(installed, ["-c", check], tmp_path)
    assert done.returncode == 0 and done.stdout.strip() == "checked", done.stdout + done.stderr
