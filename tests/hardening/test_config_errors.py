"""Configuration errors: unknown variables with the closest name, NaN as
NaN, bounds everywhere, one-line transport errors with exit 2, no retry of
a syntax error, --duration checked, reconfigure fails when nothing answers."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from typing import Any

import pytest
from annotated_types import Gt, Le, Lt

from protocol import messages as m
from protocol.errors import ConfigError, TransportError
from protocol.setting_groups import SettingGroup
from protocol.settings import (
    CommonSettings,
    ControllerSettings,
    DspSettings,
    load_settings,
    settings_models,
)
from service_kit.transport import open_can_bus, open_zenoh


@pytest.fixture(autouse=True)
def clean_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    for name in list(os.environ):
        if name.upper().startswith("RALF_"):
            monkeypatch.delenv(name)
    return monkeypatch


def _error(model: type[CommonSettings], **overrides: Any) -> str:
    with pytest.raises(ConfigError) as info:
        load_settings(model, overrides)
    return str(info.value)


def test_misspelt_variable_is_refused_with_the_closest_name(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_FFT_WIDHT", "1000")
    text = _error(DspSettings)
    assert "RALF_FFT_WIDHT" in text and "did you mean RALF_FFT_WIDTH?" in text


def test_a_setting_of_another_program_is_not_unknown(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_FFT_WIDTH", "1024")  # ralf-hil up gives one environment to all three
    assert load_settings(ControllerSettings).batch_size == 30


@pytest.mark.parametrize("text", ["nan", "NaN", "-nan"])
def test_nan_is_reported_as_nan(clean_env: pytest.MonkeyPatch, text: str) -> None:
    clean_env.setenv("RALF_SAMPLE_RATE_HZ", text)
    message = _error(DspSettings)
    assert "NaN" in message and "5000" not in message


def _numeric_fields(model: Any) -> list[tuple[str, Any]]:
    """Numeric fields, each structured setting's keys among them as ``group.key``."""
    out = []
    for name, field in model.model_fields.items():
        ann = str(field.annotation)
        if isinstance(field.annotation, type) and issubclass(field.annotation, SettingGroup):
            out.extend((f"{name}.{key}", sub) for key, sub in _numeric_fields(field.annotation))
        elif ("int" in ann or "float" in ann) and "bool" not in ann and "Literal" not in ann:
            out.append((name, field))
    return out


def _has_upper(metadata: list[Any]) -> bool:
    return any(isinstance(x, (Le, Lt)) for x in metadata)


@pytest.mark.parametrize("model", settings_models(), ids=lambda c: c.__name__)
def test_every_numeric_setting_is_bounded(model: type[CommonSettings]) -> None:
    bands = ("oatf.band_hz", "dither.band_hz", "search_band_hz", "input_monitors.extension_range_in")  # bounded pairs: checked below
    gains = ("pi.kp_mv_per_rad", "pi.ki_mv_per_rad")  # a bounded gain per joint: checked below
    unbounded = [name for name, field in _numeric_fields(model) if not _has_upper(field.metadata) and name not in bands + gains]
    assert unbounded == []
    for band in bands[:2]:
        group, _, key = band.partition(".")
        assert "less than or equal to 2500" in _error(ControllerSettings, **{group: f"{key}=1,1e9"})
    assert "less than or equal to 2500" in _error(DspSettings, search_band_hz="1,1e9")
    assert "within ±100 in" in _error(ControllerSettings, input_monitors="extension_range_in=0,1e9")
    for gain in gains:
        group, _, key = gain.partition(".")
        assert "less than or equal to 1000000" in _error(ControllerSettings, **{group: f"{key}=1,1e9"})


@pytest.mark.parametrize("model", settings_models(), ids=lambda c: c.__name__)
def test_no_positive_setting_accepts_a_vanishing_value(model: type[CommonSettings]) -> None:
    """ "Greater than zero" let 1e-300 through (a health period of 1e-300 s sent
    128,593 health messages in 19 s): every positive setting has a physical floor."""
    vanishing = [name for name, field in _numeric_fields(model) if any(isinstance(x, Gt) and x.gt == 0 for x in field.metadata)]
    assert vanishing == []
    assert "greater than or equal to 0.01" in _error(model, health_period_s="1e-300")
    if model is ControllerSettings:
        assert "RALF_TIP_SPEED_IN_S" in _error(model, tip_speed_in_s="1e-300")


def test_a_bad_cpu_list_ends_the_service_with_one_line_before_it_boots(tmp_path: Any) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")} | {"RALF_REALTIME": "cpus=abc", "RALF_CAN_INTERFACE": "virtual"}
    for module in ("controller", "plant_emulator", "dsp_service"):
        proc = subprocess.run([sys.executable, "-m", module], env=env, capture_output=True, text=True, timeout=120, check=False)
        assert proc.returncode == 2, proc.stderr
        assert "RALF_REALTIME" in proc.stderr and "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) <= 3, proc.stderr


def test_message_fields_are_bounded() -> None:
    with pytest.raises(Exception, match="emulated_latency_s"):
        m.decode(m.ConfigChange, b'{"seq": 0, "sim_time_s": 0.0, "wall_time_s": 0.0, "emulated_latency_s": 1000000.0}')
    with pytest.raises(Exception, match="poles"):
        pole = '{"frequency_hz": 1.0, "damping_ratio": 0.1}'
        m.decode(
            m.Interrupt,
            ('{"seq": 0, "sim_time_s": 0.0, "batch_seq": 0, "confidence": 1.0, "compute_time_s": 0.0, "poles": [' + ",".join([pole] * 33) + "]}").encode(),
        )
    with pytest.raises(Exception, match="counters"):
        m.decode(m.Health, ('{"seq": 0, "sim_time_s": 0.0, "service": "x", "counters": {' + ",".join(f'"c{i}": 1' for i in range(600)) + "}}").encode())


def test_bad_endpoint_syntax_is_a_config_error_not_a_retry() -> None:
    assert "not a zenoh endpoint" in _error(CommonSettings, zenoh_connect="tcp/127.0.0.1")
    assert "above 65535" in _error(CommonSettings, zenoh_listen="tcp/127.0.0.1:70000")


def test_port_in_use_fails_at_once_without_retry() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        settings = load_settings(CommonSettings, {"zenoh_listen": f"tcp/127.0.0.1:{port}"})
        slept: list[float] = []
        with pytest.raises(TransportError) as info:
            open_zenoh(settings, retry_for_s=30.0, sleep=slept.append)
    assert slept == [] and "Address already in use" in str(info.value)
    assert "\n" not in str(info.value) and ".rs:" not in str(info.value)


def test_a_client_without_its_router_retries_then_fails_on_one_line() -> None:
    settings = load_settings(CommonSettings, {"zenoh_mode": "client", "zenoh_connect": "tcp/127.0.0.1:1"})
    slept: list[float] = []
    with pytest.raises(TransportError, match="nothing answered"):
        open_zenoh(settings, retry_for_s=0.0, sleep=slept.append)


def test_can_open_error_is_one_line() -> None:
    settings = load_settings(CommonSettings, {"can_interface": "socketcan", "can_channel": "nosuchcan0"})
    with pytest.raises(TransportError) as info:
        open_can_bus(settings)
    assert "\n" not in str(info.value) and "nosuchcan0" in str(info.value)


def _run(args: list[str], env: dict[str, str] | None = None, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    full = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")}
    full.update(env or {})
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=timeout, env=full, check=False)


def test_service_with_a_port_in_use_exits_2_with_one_line() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        proc = _run(["-m", "dsp_service"], {"RALF_ZENOH_LISTEN": f"tcp/127.0.0.1:{port}"})
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Address already in use" in lines[0] and "Traceback" not in proc.stderr
    assert "retrying" not in proc.stderr  # no "not reachable yet" for a port in use


def test_controller_with_no_can_interface_exits_2_with_one_line() -> None:
    proc = _run(["-m", "controller"], {"RALF_CAN_INTERFACE": "socketcan", "RALF_CAN_CHANNEL": "nosuchcan0"})
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "cannot open CAN bus" in errors[0]


@pytest.mark.parametrize("value", ["-5", "0", "nan"])
def test_up_refuses_a_bad_duration(value: str) -> None:
    proc = _run(["-m", "workbench", "up", "--duration", value])
    assert proc.returncode == 2 and "--duration" in proc.stderr


def test_reconfigure_fails_when_nothing_answers() -> None:
    proc = _run(["-m", "workbench", "reconfigure", "--connect", "tcp/127.0.0.1:1", "--fft-width", "1024", "--timeout", "1"])
    assert proc.returncode == 1 and "no acknowledgement" in proc.stderr.replace("\n", " ")
