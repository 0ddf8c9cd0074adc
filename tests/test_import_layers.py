"""The packages import bottom-up and without cycles, read statically (AST).

Layers, lowest first: ``protocol`` < ``service_kit`` < the boards
(``plant_emulator``, ``controller``, ``dsp_service``; no board imports
another) < ``workbench``. Every ``import`` counts, wherever it stands: at
the top of a module, inside a function, under ``TYPE_CHECKING``. An
import names the deepest module of the tree it reaches (``from a.b import
c`` is ``a.b.c`` when that is a module, else ``a.b``).
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYER = {"protocol": 0, "service_kit": 1, "plant_emulator": 2, "controller": 2, "dsp_service": 2, "workbench": 3}
BOARDS = {"plant_emulator", "controller", "dsp_service"}

Edge = tuple[str, str, int]
"""(importing module, imported module, line)."""


def modules(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` below the packages."""
    found: dict[str, Path] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def _deepest(name: str, known: dict[str, Path]) -> str | None:
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def imports(known: dict[str, Path]) -> list[Edge]:
    """Every import between the known modules (self-imports left out)."""
    edges: list[Edge] = []
    for name, path in known.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
            for target in targets:
                resolved = _deepest(target, known)
                if resolved is not None and resolved != name:
                    edges.append((name, resolved, node.lineno))
    return list(dict.fromkeys(edges))


def upward(edges: Iterable[Edge]) -> list[str]:
    """Imports from a lower layer to a higher one, or from one board to another."""
    bad = []
    for src, dst, line in edges:
        a, b = src.split(".")[0], dst.split(".")[0]
        if LAYER[b] > LAYER[a] or (a in BOARDS and b in BOARDS and a != b):
            bad.append(f"{src}:{line} imports {dst}")
    return bad


def cycles(edges: Iterable[Edge]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    graph: dict[str, set[str]] = {}
    for src, dst, _ in edges:
        graph.setdefault(src, set()).add(dst)
        graph.setdefault(dst, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        top = stack.pop()
                        on_stack.discard(top)
                        component.append(top)
                        if top == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
            elif child not in index:
                index[child] = low[child] = len(index)
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph[child]))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return found


@pytest.fixture(scope="module")
def product_imports() -> list[Edge]:
    return imports(modules(ROOT, LAYER))


def test_no_import_goes_up_a_layer_or_across_boards(product_imports: list[Edge]) -> None:
    assert upward(product_imports) == []


def test_no_import_cycle(product_imports: list[Edge]) -> None:
    assert cycles(product_imports) == []


def test_the_walk_sees_every_kind_of_import(product_imports: list[Edge]) -> None:
    """The walk is not blind: it finds the imports a reader sees, relative and deferred ones included."""
    found = {(src, dst) for src, dst, _ in product_imports}
    assert ("workbench.cli", "workbench.bench") in found
    assert ("plant_emulator.plant_factory", "plant_emulator.fmu") in found  # inside a function
    assert len(found) > 500


def test_a_cycle_and_an_upward_import_are_caught(tmp_path: Path) -> None:
    """The same checks on a made-up tree: two cycles (relative and deferred imports), one import up, one across boards."""
    for package, files in {
        "protocol": {"__init__.py": "", "a.py": "from protocol import b\n", "b.py": "def f():\n    import protocol.a\n"},
        "service_kit": {"__init__.py": "", "run.py": "from workbench.tool import x\n"},
        "controller": {"__init__.py": "", "law.py": "from dsp_service import core\n"},
        "dsp_service": {"__init__.py": "", "core.py": "import protocol.a\n"},
        "workbench": {"__init__.py": "", "tool.py": "from .sub import y\n", "sub.py": "from . import tool\n"},
    }.items():
        (tmp_path / package).mkdir()
        for name, text in files.items():
            (tmp_path / package / name).write_text(text, encoding="utf-8")
    edges = imports(modules(tmp_path, LAYER))
    assert sorted(cycles(edges)) == [["protocol.a", "protocol.b"], ["workbench.sub", "workbench.tool"]]
    assert upward(edges) == ["service_kit.run:1 imports workbench.tool", "controller.law:1 imports dsp_service.core"]
