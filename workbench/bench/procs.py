"""Child processes of the bench: start, handshake on stdout, always stop."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import tempfile
import time
import uuid
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any


class BenchError(RuntimeError):
    """A benchmark could not run (a helper did not start, a reply never came)."""


def private_rig_id(prefix: str) -> str:
    return f"bench-{prefix}-{uuid.uuid4().hex[:8]}"


def private_can_port(rig_id: str) -> int:
    """A udp_multicast port of this run's own: 20000-29999, away from the launcher's
    43200-63199 and below Linux's ephemeral range (32768-60999)."""
    return 20000 + zlib.crc32(rig_id.encode()) % 10000


def clean_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """The caller's environment without any RALF_* (a child must see only the settings given here)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")}
    env.setdefault("PYTHONUNBUFFERED", "1")
    env.update(extra or {})
    return env


class Child:
    """A child process whose stdout carries ``READY``/``RESULT`` lines and
    whose stderr goes to a log file. Use as a context manager: it is
    terminated (SIGTERM, then SIGKILL) on exit, whatever happened."""

    def __init__(self, argv: Sequence[str], env: Mapping[str, str] | None = None, name: str = "child", log_dir: Path | None = None) -> None:
        self.name = name
        self.argv = list(argv)
        log_dir = log_dir or Path(tempfile.mkdtemp(prefix="ralf-bench-"))
        log_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = log_dir / f"{name}.log"
        self._log = open(self.log_path, "wb")
        self.popen = subprocess.Popen(
            self.argv,
            env=dict(env) if env is not None else clean_env(),
            stdout=subprocess.PIPE,
            stderr=self._log,
            stdin=subprocess.DEVNULL,
        )
        self._buffer = b""

    @classmethod
    def peer(cls, mode: str, *args: str, env: Mapping[str, str] | None = None, name: str | None = None, log_dir: Path | None = None) -> Child:
        return cls([sys.executable, "-m", "workbench.bench.peer", mode, *args], env=env, name=name or mode, log_dir=log_dir)

    def read_tagged(self, tag: str, timeout_s: float) -> dict[str, Any]:
        """Wait for a ``TAG <json>`` line on stdout."""
        assert self.popen.stdout is not None
        fd = self.popen.stdout.fileno()
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\n" in self._buffer:
                line, self._buffer = self._buffer.split(b"\n", 1)
                text = line.decode(errors="replace").strip()
                if text.startswith(tag + " "):
                    return dict(json.loads(text[len(tag) + 1 :]))
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise BenchError(f"{self.name}: no {tag} within {timeout_s:.0f} s; {self.describe_failure()}")
            ready, _, _ = select.select([fd], [], [], min(remaining, 0.2))
            if ready:
                chunk = os.read(fd, 65536)
                if not chunk:
                    self.popen.wait(timeout=5)
                    raise BenchError(f"{self.name}: exited with {self.popen.returncode} before {tag}; {self.describe_failure()}")
                self._buffer += chunk

    def alive(self) -> bool:
        return self.popen.poll() is None

    def describe_failure(self) -> str:
        code = self.popen.poll()
        state = "running" if code is None else f"exit code {code}"
        return f"{state}; log {self.log_path}: {tail(self.log_path)}"

    def stop(self, timeout_s: float = 10.0) -> int:
        from workbench.launcher import terminate  # here, so importing the bench does not import zenoh

        code = terminate(self.popen, timeout_s)
        if self.popen.stdout is not None:
            self.popen.stdout.close()
        self._log.close()
        return code

    def __enter__(self) -> Child:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def tail(path: Path, lines: int = 8) -> str:
    try:
        text = path.read_text(errors="replace").strip().splitlines()
    except OSError:
        return ""
    return " | ".join(text[-lines:])
