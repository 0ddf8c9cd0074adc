"""The launcher's FMU check (:func:`plant_emulator.fmu.preflight`: load,
instantiate, one step of the sample period) run in a process of its own.

The check executes the FMU's native code; an FMU that crashes in it (a
segmentation fault in ``fmi2DoStep``, an ``abort()``) would end the
launcher itself, with no line. In a child process the crash is the
child's: :func:`preflight_isolated` reports it as one
:class:`~plant_emulator.fmu.instance.FmuRefused` line naming the FMU, the
signal and the FMI call in progress (from the child's faulthandler dump,
:mod:`service_kit.crash_report`). Run once per ``ralf-hil up`` of an FMU
plant, before any service starts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from typing import Any

from plant_emulator.fmu.instance import FmuRefused
from service_kit.crash_report import fmi_call, signal_text

__all__ = ["CHECK_TIMEOUT_S", "preflight_isolated"]

CHECK_TIMEOUT_S = 120.0
"""How long the check may take (an FMU that hangs in its first step is refused after it)."""


def preflight_isolated(plant: dict[str, Any], timeout_s: float = CHECK_TIMEOUT_S) -> None:
    """:func:`plant_emulator.fmu.preflight` of the plant settings ``plant``
    (names without ``RALF_``; the environment's ``RALF_*`` too) in a child
    process; a refusal or a crash is one :class:`FmuRefused` line."""
    model = str(plant.get("model", ""))
    # The child extracts the FMU into a folder of this process's, removed here however the child ended.
    with tempfile.TemporaryDirectory(prefix="ralf-fmu-check-") as scratch:
        try:
            proc = subprocess.run(
                [sys.executable, "-P", "-m", "plant_emulator.fmu.isolated_check"],
                input=json.dumps(plant),
                capture_output=True,
                text=True,
                timeout=timeout_s,
                check=False,
                env={**os.environ, "TMPDIR": scratch},
            )
        except subprocess.TimeoutExpired:
            proc = None
    if proc is None:
        raise FmuRefused(f"{model.removeprefix('fmu:')}: its check (load, initialize, one step) did not end within {timeout_s:g} s")
    if proc.returncode == 0:
        return
    if proc.returncode > 0:
        said = proc.stderr.strip().splitlines()
        raise FmuRefused(said[-1] if said else f"its check ended with exit code {proc.returncode}")
    call = fmi_call(proc.stderr)
    where = f" in {call}" if call else ""
    raise FmuRefused(f"{model.removeprefix('fmu:')}: crashed with {signal_text(proc.returncode)}{where} during its check (load, initialize, one step)")


def main() -> int:
    from plant_emulator.fmu import preflight
    from protocol.errors import ConfigError
    from protocol.settings import PlantSettings, load_settings
    from service_kit.crash_report import enable

    enable()
    try:
        preflight(load_settings(PlantSettings, json.loads(sys.stdin.read())))
    except ConfigError as exc:
        print(" ".join(str(exc).split()), file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
