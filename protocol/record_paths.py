"""The files each program writes for a record setting, so no two programs of
a rig ever write one path: the controller's ``run_record`` and the plant's
``truth_record`` name different files even when given the same ``PATH``
(``PATH.npz`` and ``PATH.json`` beside ``PATH.truth.npz``), and
:func:`collisions` finds any overlap a launcher must refuse before starting.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

__all__ = ["collisions", "run_record_files", "run_record_outputs", "truth_file"]


def _stem(path: str | Path, *suffixes: str) -> Path:
    p = Path(path)
    for suffix in suffixes:
        if p.name.endswith(suffix) and p.name != suffix:
            p = p.with_name(p.name[: -len(suffix)])
    return p


def truth_file(path: str | Path) -> Path:
    """The plant's ground-truth file for ``truth_record = path``: ``PATH.truth.npz``
    (a ``.npz`` or ``.truth.npz`` ending on ``path`` is not doubled)."""
    stem = _stem(_stem(path, ".npz"), ".truth")
    return stem.with_name(stem.name + ".truth.npz")


RUN_RECORD_OUTPUTS: dict[str, tuple[str, ...]] = {
    "run record": ("npz", "json", "parts", "npz.tmp.npz", "json.tmp"),
    "timing record": ("timing.npz", "timing.json", "timing.parts", "timing.npz.tmp.npz", "timing.json.tmp"),
    "TF record": ("tf.npz",),
    "hop stamps": ("hops.npz",),
}
"""What the controller writes for ``run_record = PATH``, by kind: the name
endings after ``PATH.`` (``parts``: the folder the rows stream to during
the run; ``*.tmp.npz``: the file written before its rename at the end)."""


def run_record_outputs(path: str | Path) -> dict[str, list[Path]]:
    """Every file and folder the controller writes for ``run_record = path``, by kind."""
    stem = _stem(_stem(path, ".npz"), ".json")
    return {kind: [stem.with_name(f"{stem.name}.{name}") for name in names] for kind, names in RUN_RECORD_OUTPUTS.items()}


def run_record_files(path: str | Path) -> list[Path]:
    """Every file and folder the controller writes for ``run_record = path``."""
    return [p for paths in run_record_outputs(path).values() for p in paths]


def collisions(files: Mapping[str, list[Path]]) -> list[str]:
    """Paths claimed by more than one program (``{program: files}``), one line each."""
    owners: dict[Path, list[str]] = {}
    for program, paths in files.items():
        for p in paths:
            owners.setdefault(Path(p).resolve(), []).append(program)
    return [f"{p} would be written by both {' and '.join(who)}" for p, who in owners.items() if len(who) > 1]
