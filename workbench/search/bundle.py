"""A failure bundle: everything needed to see and repeat a violation.

A directory holding

* ``faults.yaml``: the minimal scenario's link faults and stalls, a
  :mod:`service_kit.link_faults` scenario file (``--set fault_scenario=``);
* ``settings.json``: the run's settings per service (the plant's channel
  faults in its ``scenario`` setting);
* ``bundle.json``: the candidate, the property, the clock, the search's seed,
  the project's version, the failing checks' lines and the run's summary;
* ``recording.mcap``: the confirming run's MCAP recording (co-simulation);
* ``reproduce.txt``: the command that runs the bundle again and judges the
  property (``ralf-hil search --replay DIR``: exit 1 when it fails again),
  and the ``ralf-hil up`` command of the same run.
"""

from __future__ import annotations

import hashlib
import json
import shlex
import shutil
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import yaml

from workbench.search.strategies import Candidate

BUNDLE_FILE = "bundle.json"


def project_version() -> str:
    try:
        return version("ralf-hil")
    except PackageNotFoundError:  # pragma: no cover - a source tree without its install
        return "unknown"


def bundle_name(candidate: Candidate, property_text: str) -> str:
    """A folder name stable for one candidate and property."""
    return "violation-" + hashlib.sha256(f"{candidate.key()}\n{property_text}".encode()).hexdigest()[:12]


def _set_value(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


def up_command(candidate: Candidate, directory: Path, clock: str) -> str:
    """``ralf-hil up`` with the candidate's length, fault file and settings, recording into the bundle."""
    parts = ["ralf-hil", "up", "--clock", clock, "--duration", f"{candidate.duration_s:g}", "--record", str(directory / "up-run.mcap")]
    if candidate.faults() is not None:
        parts += ["--set", f"fault_scenario={directory / 'faults.yaml'}"]
    for service, values in candidate.rig_settings().items():
        for name, value in values.items():
            parts += ["--set", f"{service}.{name}={_set_value(value)}"]
    return shlex.join(parts)


def replay_command(directory: Path) -> str:
    return shlex.join(["ralf-hil", "search", "--replay", str(directory)])


def write_bundle(
    directory: Path,
    candidate: Candidate,
    *,
    property_text: str,
    properties: list[str] | None = None,
    clock: str,
    seed: int,
    lines: list[str],
    summary: str,
    recording: Path | None,
    search: dict[str, Any] | None = None,
) -> Path:
    """Write the bundle into ``directory`` (created); returns it."""
    directory = directory.resolve()
    directory.mkdir(parents=True, exist_ok=True)
    faults = candidate.faults()
    if faults is not None:
        (directory / "faults.yaml").write_text(yaml.safe_dump(faults, sort_keys=False), encoding="utf-8")
    (directory / "settings.json").write_text(json.dumps(candidate.rig_settings(), indent=1) + "\n", encoding="utf-8")
    if recording is not None and recording.exists() and recording.resolve() != (directory / "recording.mcap"):
        shutil.copyfile(recording, directory / "recording.mcap")
    info = {
        "candidate": candidate.as_dict(),
        "property": property_text,
        "properties": properties or [property_text],
        "clock": clock,
        "seed": seed,
        "version": project_version(),
        "violated": lines,
        "run": summary,
        "search": search or {},
    }
    (directory / BUNDLE_FILE).write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")
    (directory / "reproduce.txt").write_text(
        f"# judge the property again (exit 1: it fails again)\n{replay_command(directory)}\n"
        f"# the same run under ralf-hil up (its verdict, its recording)\n{up_command(candidate, directory, clock)}\n",
        encoding="utf-8",
    )
    return directory


def read_bundle(directory: Path) -> dict[str, Any]:
    """A bundle's ``bundle.json`` (``OSError``/``ValueError`` on a folder that is not a bundle)."""
    data = json.loads((directory / BUNDLE_FILE).read_text(encoding="utf-8"))
    if not isinstance(data, dict) or "candidate" not in data or "property" not in data:
        raise ValueError(f"{directory / BUNDLE_FILE} is not a failure bundle")
    return data
