"""``--record RUN.mcap`` for a service started on its own (``ralf-plant``,
``ralf-controller``, ``ralf-dsp``): a ``ralf-hil record`` child process
connected to the service's own zenoh endpoints and its CAN bus, so the
recording runs beside the service, never inside its loop. The services
reach it through :func:`attach_recorder`, registered as the
``ralf_hil.service_recorder`` entry point (``service_kit.runtime.RECORDER_HOOK``):
the boards never import the launcher. (The service's
``RALF_RUN_RECORD`` / ``RALF_TRUTH_RECORD`` are the npz records, unrelated.)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import BaseModel


def _env_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value)
    return str(value)


def recorder_env(settings: BaseModel) -> dict[str, str]:
    """The child's environment: the caller's, then every setting of the
    service as ``RALF_*`` (its ``--set`` overrides included), then zenoh
    pointed at the service's own endpoints."""
    env = dict(os.environ)
    for name, value in settings.model_dump(mode="json").items():
        if value is not None:
            env[f"RALF_{name.upper()}"] = _env_value(value)
    # The dump masks the secrets (they are not for files); the child needs them as they are.
    password = getattr(settings, "zenoh_password", None)
    env["RALF_ZENOH_PASSWORD"] = password.get_secret_value() if password is not None else ""
    for name in ("zenoh_credentials_file", "zenoh_tls_ca", "zenoh_tls_certificate", "zenoh_tls_key"):  # paths the dump does not show
        env[f"RALF_{name.upper()}"] = str(getattr(settings, name, ""))
    for name in ("zenoh_tls_ca_base64", "zenoh_tls_certificate_base64", "zenoh_tls_key_base64"):  # inline TLS, masked by the dump
        secret = getattr(settings, name, None)
        env[f"RALF_{name.upper()}"] = secret.get_secret_value() if secret is not None else ""
    endpoints = [e for e in (getattr(settings, "zenoh_listen", "") + "," + getattr(settings, "zenoh_connect", "")).split(",") if e.strip()]
    env["RALF_ZENOH_CONNECT"] = ",".join(e.strip().replace("0.0.0.0", "127.0.0.1") for e in endpoints)
    env["RALF_ZENOH_LISTEN"] = ""
    env["RALF_ZENOH_MODE"] = "peer" if getattr(settings, "zenoh_mode", "peer") == "peer" else "client"
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def start_recorder(settings: BaseModel, path: str) -> subprocess.Popen[bytes]:
    """Start ``ralf-hil record PATH`` beside the service (stops on SIGTERM)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return subprocess.Popen([sys.executable, "-m", "workbench", "record", path], env=recorder_env(settings), stdin=subprocess.DEVNULL)


def stop_recorder(proc: subprocess.Popen[bytes] | None) -> None:
    if proc is None:
        return
    from workbench.launcher import terminate

    terminate(proc, timeout_s=30.0)


def attach_recorder(settings: BaseModel, path: str) -> Callable[[], None]:
    """The services' ``--record`` hook: start the recorder beside the
    service and return the function that stops it."""
    proc = start_recorder(settings, path)
    return lambda: stop_recorder(proc)
