"""The launcher starts each service from the installed packages, the ones
``ralf-hil`` itself runs, even when the working folder holds a package of the
same name (a checkout, or a user's own ``controller`` folder)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from workbench.launcher import SERVICE_MODULES, RigPlan


@pytest.mark.parametrize("service", list(SERVICE_MODULES))
def test_a_service_is_not_taken_from_the_working_folder(tmp_path: Path, service: str) -> None:
    shadow = tmp_path / SERVICE_MODULES[service]
    shadow.mkdir()
    (shadow / "__init__.py").write_text("")
    (shadow / "__main__.py").write_text("raise SystemExit('the working folder shadowed the installed service')\n")
    plan = RigPlan(rig_id="shadow", zenoh_port=0, can_port=0, service_ports={}, common_env={})
    done = subprocess.run([*plan.command_for(service), "--help"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "shadowed" not in done.stderr
    assert "RALF_" in done.stdout  # the installed service's settings help
