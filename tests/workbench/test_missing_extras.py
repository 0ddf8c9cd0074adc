"""A command that needs a module of an extra the install left out says which
extra to install, in one line, exit 2, no traceback (the quick start installs
only ``ralf-hil[rig]``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from workbench.extras import missing_extra
from workbench.progress import messages


def run_without(module: str, argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """``ralf-hil ARGV`` in a fresh interpreter in which ``import MODULE`` fails
    as it does when the module is not installed."""
    code = f"import sys; sys.modules[{module!r}] = None; from workbench.cli import main; sys.exit(main({argv!r}))"
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_a_yaml_sweep_spec_without_yaml_names_the_campaign_extra(tmp_path: Path) -> None:
    spec = tmp_path / "spec.yaml"
    spec.write_text("name: t\ncontroller:\n  duration_s: 1\n", encoding="utf-8")
    done = run_without("yaml", ["sweep", str(spec), "--dry-run"], tmp_path)
    assert done.returncode == 2, done.stderr
    assert "pip install 'ralf-hil[campaign]'" in done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    assert len(messages(done.stderr)) == 1, done.stderr


def test_an_experiment_on_dask_without_distributed_names_the_campaign_extra(tmp_path: Path) -> None:
    done = run_without("distributed", ["experiment", "battery", "--quick", "--out", str(tmp_path / "out")], tmp_path)
    assert done.returncode == 2, done.stderr
    assert "needs the module 'distributed'" in done.stderr and "pip install 'ralf-hil[campaign]'" in done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    assert not (tmp_path / "out" / "error.txt").exists()


def test_a_sweep_spec_that_is_not_there_is_named(tmp_path: Path) -> None:
    done = run_without("nothing_at_all", ["sweep", str(tmp_path / "absent.yaml")], tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip() == f"ralf-hil sweep: {tmp_path / 'absent.yaml'}: No such file or directory"


@pytest.mark.parametrize(
    ("exc", "expected"),
    [
        (ModuleNotFoundError("No module named 'fmpy'", name="fmpy"), "needs the module 'fmpy': pip install 'ralf-hil[fmu]'"),
        (ModuleNotFoundError("No module named 'dask.array'", name="dask.array"), "needs the module 'dask.array': pip install 'ralf-hil[campaign]'"),
        (ModuleNotFoundError("No module named 'numpy'", name="numpy"), None),  # the core install: a broken install keeps its traceback
        (ValueError("x"), None),
    ],
)
def test_which_errors_are_a_missing_extra(exc: BaseException, expected: str | None) -> None:
    assert missing_extra(exc) == expected
