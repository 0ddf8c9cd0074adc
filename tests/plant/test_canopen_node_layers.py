"""The CANopen node's modules import each other bottom-up only (no cycle)."""

from __future__ import annotations

import ast
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import plant_emulator.canopen_node as pkg

PKG_DIR = Path(pkg.__file__).parent
PREFIX = "plant_emulator.canopen_node."


def _imports(path: Path) -> set[str]:
    """Sibling modules a module imports, anywhere in it (also inside functions or TYPE_CHECKING)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith(PREFIX):
            out.add(node.module.removeprefix(PREFIX))
        elif isinstance(node, ast.Import):
            out.update(a.name.removeprefix(PREFIX) for a in node.names if a.name.startswith(PREFIX))
    return out


def test_modules_form_a_dag_with_storage_and_config_at_the_bottom() -> None:
    graph = {p.stem: _imports(p) for p in PKG_DIR.glob("*.py") if p.stem not in ("__init__", "__main__")}
    try:
        order = list(TopologicalSorter(graph).static_order())
    except CycleError as exc:  # pragma: no cover - the failure message
        raise AssertionError(f"import cycle in plant_emulator.canopen_node: {exc.args[1]}") from None
    assert graph["od"] == set() and graph["config"] == set()
    assert order.index("node") > order.index("sdo_server") > order.index("od")
    assert "node" not in graph["eds"] | graph["objects"] | graph["sdo_server"] | graph["od"]
