"""Every file a ``ralf-hil up`` run writes, by kind, in every clock, and the
plans in which two of them would name one file (refused before anything
starts, :func:`output_clashes`).

The kinds: the controller's run record, timing record, TF record and (real
time) hop stamps, all named by ``controller.run_record``
(:func:`protocol.record_paths.run_record_outputs`); the plant's truth
record (``plant.truth_record``); the MCAP recording (``--record``) and its
CAN log (``--can-log``); the JSON summary (``--json``); the services' logs
(``--log-dir``: the folder and one ``<service>.log`` per process, or
``cosim.log`` for a co-simulation). A setting is read as the service reads
it: its ``--set`` value, else its ``RALF_*`` variable.

The commands that write a report folder (``--out``) and a JUnit file
(``--junit``: ``timing-test``, ``experiment``, ``sweep``) refuse a JUnit
path that is the folder or one of the files the report writes in it
(:func:`junit_clash`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from fnmatch import fnmatch
from pathlib import Path

from protocol.record_paths import collisions, run_record_outputs, truth_file
from protocol.rig_description import start_order

__all__ = ["COSIM_LOG", "REPORT_FILES", "junit_clash", "output_clashes", "up_outputs"]

COSIM_LOG = "cosim.log"
"""The co-simulation's log in ``--log-dir`` (the three boards run in one thread)."""


def service_setting(overrides: Mapping[str, Mapping[str, str]], service: str, name: str) -> str:
    """``name``'s value as ``service`` will read it: its ``--set`` override, else the environment."""
    variable = f"RALF_{name.upper()}"
    return overrides.get(service, {}).get(variable, os.environ.get(variable, ""))


def log_files(log_dir: str | Path, clock: str) -> list[Path]:
    """The folder ``--log-dir`` and the log files a run of ``clock`` writes in it."""
    folder = Path(log_dir)
    names = [COSIM_LOG] if clock == "cosim" else [f"{name}.log" for name in start_order()]
    return [folder, *(folder / name for name in names)]


def up_outputs(
    overrides: Mapping[str, Mapping[str, str]],
    *,
    clock: str,
    json: str | None = None,
    record: str | None = None,
    can_log: str | None = None,
    log_dir: str | None = None,
) -> dict[str, list[Path]]:
    """Every path a ``ralf-hil up --clock clock`` run writes, by the output that writes it."""
    files: dict[str, list[Path]] = {}
    run_record = service_setting(overrides, "controller", "run_record")
    if run_record:
        for kind, paths in run_record_outputs(run_record).items():
            if kind != "hop stamps" or clock == "realtime":
                files[f"the {kind} (controller.run_record)"] = paths
    truth_record = service_setting(overrides, "plant", "truth_record")
    if truth_record:
        files["the truth record (plant.truth_record)"] = [truth_file(truth_record)]
    if record:
        files["the MCAP recording (--record)"] = [Path(record)]
    if can_log:
        files["the CAN log (--can-log)"] = [Path(can_log)]
    if json:
        files["the JSON summary (--json)"] = [Path(json)]
    if log_dir:
        files["the logs (--log-dir)"] = log_files(log_dir, clock)
    return files


def _folders(files: Mapping[str, list[Path]]) -> set[Path]:
    """The claimed paths that are folders (a record's streamed parts, the log folder)."""
    out = {Path(p).resolve() for p in files.get("the logs (--log-dir)", [])[:1]}
    return out | {Path(p).resolve() for paths in files.values() for p in paths if p.name.endswith(".parts")}


def nested(files: Mapping[str, list[Path]]) -> list[str]:
    """A file of one output that another output needs as a folder on its path."""
    folders = _folders(files)
    claims = [(Path(p).resolve(), owner) for owner, paths in files.items() for p in paths]
    owner_of = {p: owner for p, owner in claims}
    lines: dict[tuple[Path, str], str] = {}
    for q, owner in claims:
        for parent in q.parents:
            other = owner_of.get(parent)
            if other is not None and other != owner and parent not in folders:
                lines.setdefault((parent, owner), f"{parent} would be a file of {other} and a folder of {owner} ({q})")
    return list(lines.values())


def output_clashes(
    overrides: Mapping[str, Mapping[str, str]],
    *,
    clock: str,
    json: str | None = None,
    record: str | None = None,
    can_log: str | None = None,
    log_dir: str | None = None,
) -> list[str]:
    """One line per path two outputs of the run would write (empty: none do)."""
    files = up_outputs(overrides, clock=clock, json=json, record=record, can_log=can_log, log_dir=log_dir)
    return collisions(files) + nested(files)


REPORT_FILES: dict[str, tuple[str, ...]] = {
    "timing-test": ("report.json", "report.md", "hist_*.png"),
    "experiment": ("report.md", "results.json", "error.txt", "*.png", "records/*"),
    "experiment all": ("index.md", "index.json", "*/report.md", "*/results.json", "*/error.txt", "*/*.png", "*/records/*"),
    "sweep": ("spec.json", "runs.jsonl", "*.parquet", "*.csv"),
}
"""The files each command writes in its ``--out`` folder (patterns relative to it)."""


def junit_clash(junit: str | None, out: str | Path, command: str) -> str | None:
    """The line refusing ``--junit`` when it names ``--out`` or a file the report writes there (None: no clash)."""
    if not junit:
        return None
    path, folder = Path(junit).resolve(), Path(out).resolve()
    if path == folder:
        return f"{path} would be both the report folder (--out) and the JUnit XML (--junit)"
    if folder not in path.parents:
        return None
    inside = path.relative_to(folder).as_posix()
    if any(fnmatch(inside, pattern) for pattern in REPORT_FILES[command]):
        return f"{path} would be written by both the report (--out) and the JUnit XML (--junit)"
    return None
