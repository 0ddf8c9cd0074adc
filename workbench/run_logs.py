"""Where ``ralf-hil up`` puts the services' logs, and whether they stay.

Given ``--log-dir``, the logs go there and stay. Otherwise they go into a
fresh ``ralf-<rig>-*`` folder in the temporary directory, removed when the
run ends well and kept (and named) when it failed, was interrupted or
``--keep-logs`` was given, so a run that went well leaves nothing behind.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path


@dataclass
class RunLogs:
    path: Path
    chosen: bool
    """The caller named the folder (``--log-dir``): it stays."""
    keep: bool = False
    """``--keep-logs``: a temporary folder stays too."""

    @classmethod
    def create(cls, log_dir: str | None, rig_id: str, keep: bool = False) -> RunLogs:
        """The folder, created now (call it after every refusal, so a refused run creates none)."""
        if log_dir:
            path = Path(log_dir)
            path.mkdir(parents=True, exist_ok=True)
            return cls(path, chosen=True, keep=True)
        return cls(Path(tempfile.mkdtemp(prefix=f"ralf-{rig_id}-")), chosen=False, keep=keep)

    def finish(self, exit_code: int) -> str:
        """At the end of the run: a temporary folder is removed after a run
        that ended well (exit 0) unless it is kept; returns the line to say
        where the logs are ('' when they were removed)."""
        if self.chosen or self.keep or exit_code != 0:
            return f"service logs kept in {self.path}"
        shutil.rmtree(self.path, ignore_errors=True)
        return ""
