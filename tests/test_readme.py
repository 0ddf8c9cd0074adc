"""The README stays true: its configuration tables list every setting, and
CI runs its test command verbatim."""

from __future__ import annotations

import re
from pathlib import Path

from protocol.settings import ControllerSettings, DspSettings, PlantSettings, describe

ROOT = Path(__file__).resolve().parents[1]


def test_every_setting_is_in_the_readme() -> None:
    readme = (ROOT / "README.md").read_text()
    for model in (PlantSettings, ControllerSettings, DspSettings):
        for variable, _default, _text in describe(model):
            assert f"`{variable}`" in readme, f"{variable} missing from the README configuration tables"


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, flags=re.S)
    test_command = next(b for b in blocks if "pytest" in b)
    assert test_command in (ROOT / ".ci" / "run").read_text()
