"""Build a C source co-simulation FMU with the machine's C compiler against
the FMI headers FMPy ships (``fmpy/c-code``): the binary for this platform,
zipped with the model description. Used for the example FMU
(:data:`EXAMPLE_SOURCE`, shipped in the package; ``examples/fmu/two_mode_plant``
in a checkout links to it) and usable for any single-directory FMI 2.0
C source whose model identifier names its ``.c`` files' library::

    ralf-hil plant fmu-build examples/fmu/two_mode_plant two_mode_plant.fmu
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path
from typing import Any

from plant_emulator.fmu.instance import FmuRefused

__all__ = ["EXAMPLE_MAPPING", "EXAMPLE_SOURCE", "build_c_fmu"]

EXAMPLE_SOURCE = Path(__file__).resolve().parent / "example" / "two_mode_plant"
"""The example plant's C source and model description: package data, so an
installed ``ralf-hil`` (``pip install .``, not only a checkout) builds it."""
EXAMPLE_MAPPING = EXAMPLE_SOURCE.parent / "two_mode_plant.yaml"
"""The example plant's mapping onto the node's I/O (RALF's channel scales)."""


def build_c_fmu(source_dir: str | Path, dest: str | Path, compiler: str = "gcc") -> Path:
    """Compile ``source_dir/*.c`` into ``binaries/<platform>/<modelIdentifier>``
    and zip it with ``source_dir/modelDescription.xml`` (and the sources) into ``dest``."""
    import fmpy

    src = Path(source_dir)
    description = read_description_xml(src / "modelDescription.xml")
    identifier = description.coSimulation.modelIdentifier
    headers = Path(fmpy.__file__).parent / "c-code"
    sources = sorted(src.glob("*.c"))
    if not sources:
        raise FileNotFoundError(f"{src}: no C sources")
    if shutil.which(compiler) is None:
        raise FileNotFoundError(f"no C compiler {compiler!r} on this machine")
    out = Path(dest)
    with tempfile.TemporaryDirectory() as tmp:
        lib = Path(tmp) / f"{identifier}{fmpy.sharedLibraryExtension}"
        cmd = [compiler, "-shared", "-fPIC", "-O2", "-std=c99", f"-I{headers}", "-o", str(lib), *map(str, sources), "-lm"]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.write(src / "modelDescription.xml", "modelDescription.xml")
            zf.write(lib, f"binaries/{fmpy.platform}/{lib.name}")
            for c in sources:
                zf.write(c, f"sources/{c.name}")
    return out


def read_description_xml(path: Path) -> Any:
    """The model description of a source directory (its XML file)."""
    import fmpy

    try:
        return fmpy.read_model_description(str(path))
    except Exception as exc:  # noqa: BLE001 - lxml and FMPy's validation errors
        raise FmuRefused(f"{path}: unreadable model description ({' '.join(str(exc).split())})") from None


if __name__ == "__main__":
    from service_kit.moved import exit_moved

    exit_moved("python -m plant_emulator.fmu.build", "ralf-hil plant fmu-build")
