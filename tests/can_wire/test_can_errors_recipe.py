"""docs/can-errors.md's recipe, run as written: a fault scenario's can_errors
on a ``ralfwire`` bench, the plant node stepped on the manual wire clock, a
stock canopen master seeing the node's error-passive and bus-off EMCYs."""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import pytest

from tests.plant.support import FakeApp

ROOT = Path(__file__).resolve().parents[2]


def test_recipe_as_written(monkeypatch: pytest.MonkeyPatch) -> None:
    page = (ROOT / "docs" / "can-errors.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- can-errors-recipe:begin -->\n```python\n(.*?)```\n<!-- can-errors-recipe:end -->", page, re.S)
    assert block is not None, "the recipe's markers are missing"
    monkeypatch.chdir(ROOT)
    ns: dict[str, Any] = {"app": FakeApp()}
    try:
        exec(compile(block.group(1), "docs/can-errors.md", "exec"), ns)  # noqa: S102 - the page's own code
        remote = ns["remote"]
        end = time.monotonic() + 5.0
        while len(remote.emcy.log) < 3 and time.monotonic() < end:
            time.sleep(0.005)
        assert [(e.code, e.register) for e in remote.emcy.log] == [(0x8120, 0x11), (0x8140, 0x11), (0x0000, 0x00)]
        assert ns["plant_bus"].wire.error_frames == 32
        assert ns["node"].error_register == 0
    finally:
        if "network" in ns:
            ns["network"].disconnect()
        if "plant_bus" in ns:
            ns["plant_bus"].shutdown()
