"""Per-program settings (protocol.settings) from RALF_* variables and
overrides, and the zenoh key expressions of a rig (protocol.keys)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from protocol.errors import ConfigError
from protocol.keys import SERVICES, Keys, validate_rig_id
from protocol.setting_groups import Smoothing
from protocol.settings import CommonSettings, ControllerSettings, DspSettings, PlantSettings, describe, load_settings, upgrade_recorded

LOOP = Path(__file__).resolve().parents[2] / "protocol" / "trajectories" / "inspection_loop.json"

MODELS = [CommonSettings, PlantSettings, ControllerSettings, DspSettings]


@pytest.fixture(autouse=True)
def clean_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    """No RALF_* variable of the developer's shell leaks into a test."""
    for name in list(os.environ):
        if name.upper().startswith("RALF_"):
            monkeypatch.delenv(name)
    return monkeypatch


def _config_error(model: type[CommonSettings], overrides: dict[str, Any] | None = None) -> str:
    with pytest.raises(ConfigError) as info:
        load_settings(model, overrides)
    return str(info.value)


# --- defaults ------------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS, ids=lambda c: c.__name__)
def test_defaults_are_valid(model: type[CommonSettings]) -> None:
    s = load_settings(model)
    assert isinstance(s, model)
    assert s.rig_id == "default"
    assert s.zenoh_mode == "peer" and s.zenoh_multicast_scouting is False
    assert s.node_id == 1 and s.can_port == 43113
    assert s.sample_rate_hz == 200.0 and s.sample_period_s == pytest.approx(0.005)
    assert s.endpoints("connect") == [] and s.endpoints("listen") == []
    assert model() == s  # the same without load_settings


def test_program_defaults() -> None:
    plant = load_settings(PlantSettings)
    assert (plant.adc_bits, plant.seed, plant.payload_attached, plant.watchdog_periods) == (12, 0, False, 5)
    ctrl = load_settings(ControllerSettings)
    assert ctrl.oatf.band_hz == (1.0, 20.0) and ctrl.duration_s is None and ctrl.oatf_mode == "off"
    assert ctrl.batch_size == 30 and ctrl.tip_speed_in_s == 5.0
    dsp = load_settings(DspSettings)
    assert dsp.fft_width == 2048 and dsp.alpha == 0.1 and dsp.search_band_hz == (0.5, 40.0)


@pytest.mark.parametrize("model", MODELS, ids=lambda c: c.__name__)
def test_describe_lists_every_field(model: type[CommonSettings]) -> None:
    rows = describe(model)
    assert [var for var, _, _ in rows] == [f"RALF_{name.upper()}" for name in model.model_fields]
    assert all(text for _, _, text in rows), "every field is documented"
    assert dict((var, default) for var, default, _ in rows)["RALF_RIG_ID"] == "default"


# --- environment ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "model,var,raw,field,expected",
    [
        (CommonSettings, "RALF_RIG_ID", "lab-2_b", "rig_id", "lab-2_b"),
        (CommonSettings, "RALF_ZENOH_MODE", "client", "zenoh_mode", "client"),
        (CommonSettings, "RALF_CAN_PORT", "50000", "can_port", 50000),
        (CommonSettings, "RALF_NODE_ID", "127", "node_id", 127),
        (CommonSettings, "RALF_CLOCK", "lockstep", "clock", "lockstep"),
        (CommonSettings, "RALF_SAMPLE_RATE_HZ", "1000.5", "sample_rate_hz", 1000.5),
        (CommonSettings, "RALF_SAMPLE_RATE_HZ", "5e3", "sample_rate_hz", 5000.0),
        (CommonSettings, "RALF_LOG_LEVEL", "DEBUG", "log_level", "DEBUG"),
        (CommonSettings, "RALF_CAN_INTERFACE", "virtual", "can_interface", "virtual"),
        (CommonSettings, "ralf_can_channel", "vcan0", "can_channel", "vcan0"),
        (PlantSettings, "RALF_SEED", "42", "seed", 42),
        (PlantSettings, "RALF_ADC_BITS", "16", "adc_bits", 16),
        (PlantSettings, "RALF_ADC_BITS", "20", "adc_bits", 20),
        (PlantSettings, "RALF_ADC_BITS", "12", "adc_bits", 12),
        (PlantSettings, "RALF_TRUTH_RATE_HZ", "0", "truth_rate_hz", 0.0),
        (ControllerSettings, "RALF_DURATION_S", "12.5", "duration_s", 12.5),
        (ControllerSettings, "RALF_OATF_MODE", "adaptive", "oatf_mode", "adaptive"),
        (ControllerSettings, "RALF_TRAJECTORY", str(LOOP), "trajectory", str(LOOP)),
        (DspSettings, "RALF_FFT_WIDTH", "4096", "fft_width", 4096),
        (DspSettings, "RALF_SOLVER", "uncorrelated", "solver", "uncorrelated"),
        (DspSettings, "RALF_BUDGET_S", "0.02", "budget_s", 0.02),
        (DspSettings, "RALF_ARX_REGIME_BANK", "4", "arx_regime_bank", 4),
    ],
)
def test_environment_values_are_parsed(clean_env: pytest.MonkeyPatch, model: type[CommonSettings], var: str, raw: str, field: str, expected: Any) -> None:
    clean_env.setenv(var, raw)
    value = getattr(load_settings(model), field)
    assert value == expected and type(value) is type(expected)


@pytest.mark.parametrize(
    "raw,expected",
    [("true", True), ("True", True), ("1", True), ("yes", True), ("on", True), ("false", False), ("FALSE", False), ("0", False), ("no", False), ("off", False)],
)
def test_environment_booleans(clean_env: pytest.MonkeyPatch, raw: str, expected: bool) -> None:
    clean_env.setenv("RALF_ZENOH_MULTICAST_SCOUTING", raw)
    clean_env.setenv("RALF_PAYLOAD_ATTACHED", raw)
    s = load_settings(PlantSettings)
    assert s.zenoh_multicast_scouting is expected and s.payload_attached is expected


def test_overrides_take_precedence_over_the_environment(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_CLOCK", "lockstep")
    clean_env.setenv("RALF_SEED", "1")
    s = load_settings(PlantSettings, {"seed": "2", "adc_bits": "20"})
    assert (s.clock, s.seed, s.adc_bits) == ("lockstep", 2, 20)


@pytest.mark.parametrize("raw", ["1,20", " 1 , 20 ", "[1, 20]", "(1,20)", "[1.0,20.0]"])
def test_band_override_as_text(raw: str) -> None:
    # --set oatf=band_hz=... arrives as a string
    assert load_settings(ControllerSettings, {"oatf": f"band_hz={raw}"}).oatf.band_hz == (1.0, 20.0)


@pytest.mark.parametrize(
    "raw",
    [
        "band_hz=2,15.5,delay_s=0.1,fallback=fixed",
        "delay_s=0.1, band_hz=[2, 15.5], fallback=fixed",
        '{"band_hz": [2, 15.5], "delay_s": 0.1, "fallback": "fixed"}',
    ],
)
def test_structured_setting_from_the_environment_keeps_unnamed_defaults(clean_env: pytest.MonkeyPatch, raw: str) -> None:
    clean_env.setenv("RALF_OATF", raw)
    oatf = load_settings(ControllerSettings).oatf
    assert (oatf.band_hz, oatf.delay_s, oatf.fallback) == ((2.0, 15.5), 0.1, "fixed")
    assert (oatf.frequency_hz, oatf.damping, oatf.location, oatf.max_stages) == (4.4, 0.09, "outer", 1)


def test_structured_settings_read_back_their_own_text() -> None:
    ctrl = load_settings(ControllerSettings, {"oatf": "frequency_hz=4.40183,band_hz=2.5,7", "dither": "amplitude_v=0.01", "policies": "stale=stop"})
    again = load_settings(ControllerSettings, {name: str(getattr(ctrl, name)) for name in ("oatf", "dither", "policies")})
    assert (again.oatf, again.dither, again.policies) == (ctrl.oatf, ctrl.dither, ctrl.policies)
    assert again.oatf.frequency_hz == 4.40183 and again.policies.stale == "stop" and again.policies.can_conflict == "stop"
    dumped = ControllerSettings(**ctrl.model_dump(mode="json"))  # as a run record stores them
    assert dumped.oatf == ctrl.oatf and dumped.dither == ctrl.dither


def test_policies_defaults_and_one_changed(clean_env: pytest.MonkeyPatch) -> None:
    assert load_settings(ControllerSettings).policies.as_dict() == {
        "deadline": "warn",
        "stale": "degrade",
        "dsp_lost": "degrade",
        "overrun": "count",
        "can_conflict": "stop",
        "can_error_passive": "count",  # a CAN node not error active: counted, the run goes on
        "input_range": "stop",  # the input monitors' (all off unless named in input_monitors)
        "input_stuck": "stop",
        "input_rate": "stop",
        "input_disagree": "stop",
    }
    clean_env.setenv("RALF_POLICIES", "deadline=stop")
    policies = load_settings(ControllerSettings).policies
    assert policies.deadline == "stop" and policies.stale == "degrade"


def test_an_older_recordings_settings_are_read_in_todays_names() -> None:
    old = {"oatf_mode": "adaptive", "oatf_frequency_hz": 4.4018, "oatf_band_hz": [1.0, 15.0], "policy_deadline": "degrade", "dither_seed": 3}
    old |= {"inject_stall_s": 0.0, "inject_stall_at_s": None, "rt_priority": 10, "cpu_affinity": "1"}
    ctrl = ControllerSettings(**upgrade_recorded(old))
    assert (ctrl.oatf_mode, ctrl.oatf.frequency_hz, ctrl.oatf.band_hz, ctrl.oatf.damping) == ("adaptive", 4.4018, (1.0, 15.0), 0.09)
    assert (ctrl.policies.deadline, ctrl.policies.stale, ctrl.dither.seed, ctrl.realtime.priority, ctrl.realtime.cpus) == ("degrade", "degrade", 3, 10, "1")
    assert DspSettings(**upgrade_recorded({"search_max_hz": 30.0, "fft_width": 1024})).search_band_hz == (0.5, 30.0)
    assert DspSettings(**upgrade_recorded({"smoothing_window": 9, "smoothing_order": 3})).smoothing == Smoothing(window=9, order=3)


def test_pi_gains_and_timeouts_default_to_todays_and_change_one_key(clean_env: pytest.MonkeyPatch) -> None:
    from controller.pi import PIConfig

    ctrl = load_settings(ControllerSettings)
    assert ctrl.pi.kp_mv_per_rad == PIConfig().kp_mv_per_rad and ctrl.pi.ki_mv_per_rad == PIConfig().ki_mv_per_rad
    assert (ctrl.timeouts.startup_s, ctrl.timeouts.lockstep_s, ctrl.timeouts.plant_heartbeat_s, ctrl.timeouts.stale_after_s) == (60.0, 60.0, 1.0, 2.0)
    assert ctrl.timeouts.dsp_deadline_s is None
    clean_env.setenv("RALF_PI", "kp_mv_per_rad=9000,6250")
    clean_env.setenv("RALF_TIMEOUTS", '{"lockstep_s": 30}')
    ctrl = load_settings(ControllerSettings)
    assert ctrl.pi.kp_mv_per_rad == (9000.0, 6250.0) and ctrl.pi.ki_mv_per_rad == (5000.0, 4166.0)
    assert ctrl.timeouts.lockstep_s == 30.0 and ctrl.timeouts.startup_s == 60.0
    again = ControllerSettings(**ctrl.model_dump(mode="json"))  # as a run record stores them
    assert (again.pi, again.timeouts) == (ctrl.pi, ctrl.timeouts)
    assert ControllerSettings(pi=str(ctrl.pi)).pi == ctrl.pi  # the text form reads back


def test_an_older_recordings_timeouts_move_into_the_group() -> None:
    ctrl = ControllerSettings(**upgrade_recorded({"lockstep_timeout_s": 30.0, "stale_after_s": 3.0, "dsp_deadline_s": None}))
    assert (ctrl.timeouts.lockstep_s, ctrl.timeouts.stale_after_s, ctrl.timeouts.startup_s, ctrl.timeouts.dsp_deadline_s) == (30.0, 3.0, 60.0, None)


@pytest.mark.parametrize(
    ("raw", "expected"), [("true", "on"), ("1", "on"), ("on", "on"), ("false", "off"), ("0", "off"), ("off", "off"), ("scenarios", "scenarios")]
)
def test_access_control_reads_a_switch_or_scenarios(clean_env: pytest.MonkeyPatch, raw: str, expected: str) -> None:
    clean_env.setenv("RALF_ZENOH_MODE", "client")  # (a peer with rules needs its certificates: below)
    clean_env.setenv("RALF_ZENOH_ACL", raw)
    assert load_settings(CommonSettings).zenoh_acl == expected
    assert CommonSettings(zenoh_mode="client", zenoh_acl=raw == "true").zenoh_acl == ("on" if raw == "true" else "off")


def test_access_rules_in_peer_mode_need_mutual_tls(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_ZENOH_ACL", "on")
    text = _config_error(DspSettings)
    assert "RALF_ZENOH_ACL=on in peer mode needs mutual TLS" in text and "RALF_ZENOH_TLS_CA" in text, text


RETIRED_NAMES = [
    ("RALF_INJECT_STALL_AT_S", "1.0", "RALF_FAULT_SCENARIO"),
    ("RALF_INJECT_STALL_S", "0.4", "RALF_FAULT_SCENARIO"),
    ("RALF_INJECT_SYNC_DROP_EVERY", "50", "RALF_FAULT_SCENARIO"),
    ("RALF_INJECT_DELAY_S", "0.35", "RALF_FAULT_SCENARIO"),
    ("RALF_POLICY_DEADLINE", "stop", "RALF_POLICIES=deadline="),
    ("RALF_POLICY_CAN_CONFLICT", "warn", "RALF_POLICIES=can_conflict="),
    ("RALF_OATF_FREQUENCY_HZ", "4.4", "RALF_OATF=frequency_hz="),
    ("RALF_OATF_BAND_HZ", "[1, 20]", "RALF_OATF=band_hz="),
    ("RALF_OATF_FALLBACK", "fixed", "RALF_OATF=fallback="),
    ("RALF_DITHER_AMPLITUDE_V", "0.01", "RALF_DITHER=amplitude_v="),
    ("RALF_DITHER_SEED", "3", "RALF_DITHER=seed="),
    ("RALF_RT_PRIORITY", "10", "RALF_REALTIME=priority="),
    ("RALF_CPU_AFFINITY", "1", "RALF_REALTIME=cpus="),
    ("RALF_SEARCH_MAX_HZ", "30", "RALF_SEARCH_BAND_HZ="),
    ("RALF_CAN_MULTICAST_TTL", "1", "RALF_CAN_UDP=ttl="),
    ("RALF_ZENOH_ACL_SCENARIOS", "true", "RALF_ZENOH_ACL=scenarios"),
    ("RALF_STARTUP_TIMEOUT_S", "2", "RALF_TIMEOUTS=startup_s="),
    ("RALF_LOCKSTEP_TIMEOUT_S", "30", "RALF_TIMEOUTS=lockstep_s="),
    ("RALF_PLANT_HEARTBEAT_TIMEOUT_S", "5", "RALF_TIMEOUTS=plant_heartbeat_s="),
    ("RALF_STALE_AFTER_S", "3", "RALF_TIMEOUTS=stale_after_s="),
    ("RALF_DSP_DEADLINE_S", "0.2", "RALF_TIMEOUTS=dsp_deadline_s="),
    ("RALF_SMOOTHING_WINDOW", "9", "RALF_SMOOTHING=window="),
    ("RALF_SMOOTHING_ORDER", "3", "RALF_SMOOTHING=order="),
]


@pytest.mark.parametrize("var,raw,replacement", RETIRED_NAMES, ids=lambda x: x if x.startswith("RALF_") else "")
def test_a_retired_setting_is_refused_naming_its_replacement(clean_env: pytest.MonkeyPatch, var: str, raw: str, replacement: str) -> None:
    clean_env.setenv(var, raw)
    for model in MODELS:  # one environment for all three programs: each refuses it
        lines = _config_error(model).splitlines()
        assert lines[0] == "invalid configuration:" and len(lines) == 2 and lines[1].strip().startswith(var) and replacement in lines[1], lines
    clean_env.delenv(var)
    name = var.removeprefix("RALF_").lower()
    assert replacement in _config_error(ControllerSettings, {name: raw})  # --set and Python overrides alike
    with pytest.raises(ValidationError, match=replacement.split("=")[0].removeprefix("RALF_")):
        ControllerSettings(**{name: raw})


# --- bad values ----------------------------------------------------------------------

BAD_ENV = [
    (CommonSettings, "RALF_RIG_ID", "a/b"),
    (CommonSettings, "RALF_RIG_ID", "ralf*"),
    (CommonSettings, "RALF_RIG_ID", "rig\n"),
    (CommonSettings, "RALF_ZENOH_MODE", "mesh"),
    (CommonSettings, "RALF_ZENOH_MULTICAST_SCOUTING", "maybe"),
    (CommonSettings, "RALF_CAN_PORT", "0"),
    (CommonSettings, "RALF_CAN_PORT", "65536"),
    (CommonSettings, "RALF_CAN_PORT", "http"),
    (CommonSettings, "RALF_NODE_ID", "0"),
    (CommonSettings, "RALF_NODE_ID", "128"),
    (CommonSettings, "RALF_CLOCK", "fast"),
    (CommonSettings, "RALF_SAMPLE_RATE_HZ", "0"),
    (CommonSettings, "RALF_SAMPLE_RATE_HZ", "-200"),
    (CommonSettings, "RALF_SAMPLE_RATE_HZ", "5001"),
    (CommonSettings, "RALF_SAMPLE_RATE_HZ", "fast"),
    (CommonSettings, "RALF_HEALTH_PERIOD_S", "0"),
    (CommonSettings, "RALF_HEALTH_PERIOD_S", "1e-300"),  # accepted once: 128,593 health messages in 19 s
    (CommonSettings, "RALF_HEALTH_PERIOD_S", "0.005"),
    (CommonSettings, "RALF_SAMPLE_RATE_HZ", "1e-300"),
    (CommonSettings, "RALF_LAUNCHER_PID", "-1"),
    (CommonSettings, "RALF_LOG_LEVEL", "CHATTY"),
    (PlantSettings, "RALF_SEED", "-1"),
    (PlantSettings, "RALF_SEED", "1.5"),
    (PlantSettings, "RALF_ADC_BITS", "14"),
    (PlantSettings, "RALF_ADC_BITS", "twelve"),
    (PlantSettings, "RALF_PAYLOAD_ATTACHED", "sometimes"),
    (PlantSettings, "RALF_VALVE_TIME_CONSTANT_S", "0.1"),
    (PlantSettings, "RALF_WATCHDOG_PERIODS", "0"),
    (PlantSettings, "RALF_HEARTBEAT_MS", "-5"),
    (PlantSettings, "RALF_SCENARIO", "abc"),  # refused after the plant's node was on the bus before
    (PlantSettings, "RALF_SCENARIO", '[{"kind": "nope"}]'),
    (ControllerSettings, "RALF_DURATION_S", "0"),
    (ControllerSettings, "RALF_DURATION_S", "abc"),
    (ControllerSettings, "RALF_TIP_SPEED_IN_S", "25"),
    (ControllerSettings, "RALF_TIP_SPEED_IN_S", "1e-300"),  # was "Maximum allowed size exceeded" from the trajectory, no name
    (ControllerSettings, "RALF_TIP_SPEED_IN_S", "0.005"),
    (ControllerSettings, "RALF_TIMEOUTS", "stale_after_s=1e-300"),
    (ControllerSettings, "RALF_TIMEOUTS", "startup=5"),
    (ControllerSettings, "RALF_TIMEOUTS", "lockstep_s=nan"),
    (ControllerSettings, "RALF_PI", "kp_mv_per_rad=-1,6250"),
    (ControllerSettings, "RALF_PI", "kp_mv_per_rad=7500"),
    (ControllerSettings, "RALF_PI", "ki_mv_per_rad=5000,4166,1"),
    (ControllerSettings, "RALF_PI", "kp=7500,6250"),
    (ControllerSettings, "RALF_PI", "ki_mv_per_rad=inf,1"),
    (ControllerSettings, "RALF_OATF", "band_hz=1e-300,20"),
    (ControllerSettings, "RALF_BATCH_SIZE", "0"),
    (ControllerSettings, "RALF_BATCH_SIZE", "4097"),
    (ControllerSettings, "RALF_OATF_MODE", "on"),
    (ControllerSettings, "RALF_OATF", "location=middle"),
    (ControllerSettings, "RALF_OATF", "damping=1"),
    (ControllerSettings, "RALF_OATF", "min_confidence=1.5"),
    (ControllerSettings, "RALF_OATF", "band_hz=[1, 2, 3]"),
    (ControllerSettings, "RALF_OATF", '{"band_hz": [1, "x"]}'),
    (ControllerSettings, "RALF_OATF", "band_hz=20,1"),
    (ControllerSettings, "RALF_OATF", "band_hz=wide"),
    (ControllerSettings, "RALF_OATF", "frequency=4.4"),
    (ControllerSettings, "RALF_OATF", "frequency_hz"),
    (ControllerSettings, "RALF_OATF", "{not json"),
    (ControllerSettings, "RALF_OATF", "damping=nan"),
    (ControllerSettings, "RALF_DITHER", "band_hz=7,2"),
    (ControllerSettings, "RALF_POLICIES", "deadline=panic"),
    (ControllerSettings, "RALF_POLICIES", "deadline=stop,deadline=warn"),
    (ControllerSettings, "RALF_REPEATS", "-1"),
    (DspSettings, "RALF_FFT_WIDTH", "1000"),
    (DspSettings, "RALF_FFT_WIDTH", "8"),
    (DspSettings, "RALF_FFT_WIDTH", "131072"),
    (DspSettings, "RALF_ALPHA", "0"),
    (DspSettings, "RALF_ALPHA", "1e-300"),
    (DspSettings, "RALF_ALPHA", "1.01"),
    (DspSettings, "RALF_AVERAGING", "median"),
    (DspSettings, "RALF_SOLVER", "siso"),
    (DspSettings, "RALF_EMULATED_LATENCY_S", "11"),
    (DspSettings, "RALF_SMOOTHING", "window=-1"),
    (DspSettings, "RALF_SMOOTHING", "order=11"),
    (DspSettings, "RALF_SMOOTHING", "width=9"),
]


def test_a_file_setting_naming_a_fifo_is_refused_at_load_without_opening_it(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """RALF_TRAJECTORY as a FIFO blocked the controller in open() (no writer comes)
    and it ignored SIGTERM for minutes: the type is checked with stat, never opened."""
    fifo = tmp_path / "loop.fifo"
    os.mkfifo(fifo)
    for model, var in (
        (ControllerSettings, "RALF_TRAJECTORY"),
        (ControllerSettings, "RALF_FAULT_SCENARIO"),
        (PlantSettings, "RALF_ZENOH_CREDENTIALS_FILE"),
        (PlantSettings, "RALF_ZENOH_TLS_KEY"),
    ):
        clean_env.setenv(var, str(fifo))
        text = _config_error(model)
        assert var in text and "is a FIFO, not a regular file" in text, text
        clean_env.delenv(var)
    clean_env.setenv("RALF_TRAJECTORY", str(tmp_path))
    assert "is a directory" in _config_error(ControllerSettings)
    clean_env.setenv("RALF_TRAJECTORY", "/dev/zero")
    assert "is a character device" in _config_error(ControllerSettings)
    clean_env.setenv("RALF_TRAJECTORY", str(tmp_path / "absent.json"))
    assert "No such file" in _config_error(ControllerSettings)


def test_a_fifo_swapped_in_after_the_check_does_not_block_the_read(tmp_path: Path) -> None:
    from protocol.files import NotARegularFile, read_regular_text

    fifo = tmp_path / "late.fifo"
    os.mkfifo(fifo)
    with pytest.raises(NotARegularFile, match="FIFO"):
        read_regular_text(fifo)
    assert read_regular_text(LOOP).startswith("{") or read_regular_text(LOOP).lstrip().startswith("{")


def test_a_zenoh_user_without_its_password_is_refused(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_ZENOH_USER", "controller")
    text = _config_error(ControllerSettings)
    assert "RALF_ZENOH_USER is set without RALF_ZENOH_PASSWORD" in text
    clean_env.setenv("RALF_ZENOH_PASSWORD", "s3cret-enough")
    settings = load_settings(ControllerSettings)
    assert settings.zenoh_password.get_secret_value() == "s3cret-enough"
    assert "s3cret-enough" not in repr(settings) + str(settings.model_dump()) + str(settings.model_dump(mode="json"))
    clean_env.delenv("RALF_ZENOH_USER")
    assert "RALF_ZENOH_PASSWORD is set without RALF_ZENOH_USER" in _config_error(ControllerSettings)


def test_a_too_long_password_is_refused_without_showing_it(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_ZENOH_USER", "controller")
    clean_env.setenv("RALF_ZENOH_PASSWORD", "p" * 300)
    text = _config_error(ControllerSettings)
    assert "RALF_ZENOH_PASSWORD" in text and "p" * 300 not in text


def test_mutual_tls_is_all_three_files_and_tls_endpoints_only(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for name in ("ca.pem", "dsp.pem", "dsp.key"):
        (tmp_path / name).write_text("-----BEGIN-----\n")
    clean_env.setenv("RALF_ZENOH_TLS_CA", str(tmp_path / "ca.pem"))
    text = _config_error(DspSettings)
    assert "mutual TLS needs all of" in text and "RALF_ZENOH_TLS_CERTIFICATE, RALF_ZENOH_TLS_KEY not set" in text, text
    clean_env.setenv("RALF_ZENOH_TLS_CERTIFICATE", str(tmp_path / "dsp.pem"))
    clean_env.setenv("RALF_ZENOH_TLS_KEY", str(tmp_path / "dsp.key"))
    clean_env.setenv("RALF_ZENOH_CONNECT", "tls/127.0.0.1:7447,tcp/127.0.0.1:7448")
    assert "every zenoh endpoint must be tls/HOST:PORT, got tcp/127.0.0.1:7448" in _config_error(DspSettings)
    clean_env.setenv("RALF_ZENOH_CONNECT", "tls/127.0.0.1:7447")
    settings = load_settings(DspSettings)
    assert str(tmp_path) not in json.dumps(settings.model_dump(mode="json"))  # where the keys live is not recorded
    for var in ("RALF_ZENOH_TLS_CA", "RALF_ZENOH_TLS_CERTIFICATE", "RALF_ZENOH_TLS_KEY"):
        clean_env.delenv(var)
    assert "tls/ endpoints need RALF_ZENOH_TLS_CA" in _config_error(DspSettings)


def test_zenoh_ids_are_retired_for_certificates(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_ZENOH_NODE_IDS", "dsp:abc")
    assert "RALF_ZENOH_TLS_CA" in _config_error(DspSettings)


@pytest.mark.parametrize("model,var,raw", BAD_ENV, ids=lambda x: x if isinstance(x, str) else x.__name__)
def test_bad_environment_values_name_the_variable(clean_env: pytest.MonkeyPatch, model: type[CommonSettings], var: str, raw: str) -> None:
    clean_env.setenv(var, raw)
    text = _config_error(model)
    assert text.startswith("invalid configuration:")
    assert var in text
    # the name given is the real variable, not a made-up one like RALF_OATF_BAND_HZ_1
    named = [line.strip().split(":")[0] for line in text.splitlines()[1:]]
    assert all(n.split("[")[0] == var for n in named), named


@pytest.mark.parametrize("model,var,raw", BAD_ENV[:12], ids=lambda x: x if isinstance(x, str) else x.__name__)
def test_bad_override_values_name_the_variable(model: type[CommonSettings], var: str, raw: str) -> None:
    assert var in _config_error(model, {var.removeprefix("RALF_").lower(): raw})


def test_config_error_is_a_value_error_without_a_chained_traceback(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_CAN_PORT", "x")
    with pytest.raises(ConfigError) as info:
        load_settings(CommonSettings)
    assert isinstance(info.value, ValueError)
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_every_bad_value_is_listed(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_NODE_ID", "500")
    clean_env.setenv("RALF_CLOCK", "sometimes")
    text = _config_error(CommonSettings, {"log_level": "LOUD"})
    for var in ("RALF_NODE_ID", "RALF_CLOCK", "RALF_LOG_LEVEL"):
        assert var in text


def test_unknown_override_is_rejected() -> None:
    text = _config_error(CommonSettings, {"sample_rate": 100})
    assert "RALF_SAMPLE_RATE" in text and "Extra inputs are not permitted" in text


def test_program_settings_do_not_mix() -> None:
    assert "RALF_FFT_WIDTH" in _config_error(PlantSettings, {"fft_width": 1024})
    assert "RALF_ADC_BITS" in _config_error(DspSettings, {"adc_bits": 16})


def test_search_band_must_be_ordered(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_SEARCH_BAND_HZ", "50,40")
    text = _config_error(DspSettings)
    assert "DspSettings" in text and "the search band's upper edge must exceed its lower edge" in text
    clean_env.setenv("RALF_SEARCH_BAND_HZ", "[1, 2]")
    assert load_settings(DspSettings).search_band_hz == (1.0, 2.0)
    assert load_settings(DspSettings, {"search_band_hz": "1,2"}).search_band_hz == (1.0, 2.0)


def test_element_error_names_the_item() -> None:
    text = _config_error(ControllerSettings, {"oatf": "band_hz=1,x"})
    assert "RALF_OATF[band_hz][1]" in text and "RALF_OATF_BAND_HZ_1" not in text


# --- endpoints -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "raw,expected",
    [
        ("", []),
        (" ", []),
        (",,", []),
        ("tcp/127.0.0.1:7447", ["tcp/127.0.0.1:7447"]),
        (" tcp/a:1 , ,tcp/b:2, ", ["tcp/a:1", "tcp/b:2"]),
        ("udp/[::1]:7447,tcp/h:1", ["udp/[::1]:7447", "tcp/h:1"]),
    ],
)
def test_endpoints(clean_env: pytest.MonkeyPatch, raw: str, expected: list[str]) -> None:
    clean_env.setenv("RALF_ZENOH_CONNECT", raw)
    clean_env.setenv("RALF_ZENOH_LISTEN", "tcp/0.0.0.0:7447")
    s = load_settings(CommonSettings)
    assert s.endpoints("connect") == expected
    assert s.endpoints("listen") == ["tcp/0.0.0.0:7447"]


# --- rig ids and keys ----------------------------------------------------------------

rig_ids = st.from_regex(r"\A[A-Za-z0-9_-]{1,64}\Z")


@settings(max_examples=100, deadline=None)
@given(rig_id=rig_ids)
def test_valid_rig_ids(rig_id: str) -> None:
    assert validate_rig_id(rig_id) == rig_id
    assert Keys(rig_id).root == f"ralf/{rig_id}"
    assert load_settings(CommonSettings, {"rig_id": rig_id}).rig_id == rig_id


BAD_RIG_IDS = ["", "a" * 65, "a/b", "a b", "*", "**", "a*", "$", "rig.1", "rig\n", "\nrig", "rig\r\n", "rïg", "rig#1", "a?b", "/"]


@pytest.mark.parametrize("rig_id", BAD_RIG_IDS, ids=repr)
def test_bad_rig_ids(rig_id: str) -> None:
    with pytest.raises(ValueError, match="rig id"):
        validate_rig_id(rig_id)
    with pytest.raises(ValueError, match="rig id"):
        Keys(rig_id)
    assert "RALF_RIG_ID" in _config_error(CommonSettings, {"rig_id": rig_id})


@settings(max_examples=150, deadline=None)
@given(rig_id=st.text(max_size=70))
def test_rig_id_validation_matches_the_rule(rig_id: str) -> None:
    ok = 1 <= len(rig_id) <= 64 and all(c.isascii() and (c.isalnum() or c in "-_") for c in rig_id)
    try:
        validate_rig_id(rig_id)
    except ValueError:
        assert not ok
    else:
        assert ok


@pytest.mark.parametrize("rig_id", [None, 5, b"rig"], ids=repr)
def test_non_string_rig_ids(rig_id: Any) -> None:
    with pytest.raises(ValueError):
        validate_rig_id(rig_id)
    with pytest.raises(ValueError):
        Keys(rig_id)


def test_key_expressions() -> None:
    keys = Keys("lab1")
    assert keys.root == "ralf/lab1"
    assert keys.batch == "ralf/lab1/dsp/batch"
    assert keys.flag == "ralf/lab1/dsp/flag"
    assert keys.interrupt == "ralf/lab1/dsp/interrupt"
    assert keys.dsp_config == "ralf/lab1/dsp/config"
    assert keys.tf == "ralf/lab1/dsp/tf"
    assert keys.truth == "ralf/lab1/plant/truth"
    assert keys.channel_truth == "ralf/lab1/plant/channels"
    assert keys.scenario == "ralf/lab1/plant/scenario"
    assert keys.plant_events == "ralf/lab1/plant/events"
    assert keys.controller_status == "ralf/lab1/controller/status"
    assert keys.tf_downloads == "ralf/lab1/controller/tf"
    assert keys.params == "ralf/lab1/controller/params"
    assert keys.param_set == "ralf/lab1/controller/param_set"
    assert keys.param_set_tool == "ralf/lab1/controller/param_set_tool"
    assert keys.param_answer == "ralf/lab1/controller/param_answer"
    assert keys.param_changes == "ralf/lab1/controller/param_changes"
    assert keys.health("dsp") == "ralf/lab1/health/dsp"
    assert keys.health_all == "ralf/lab1/health/*"
    assert keys.alive("plant") == "ralf/lab1/alive/plant"
    assert keys.alive_all == "ralf/lab1/alive/*"
    assert Keys().root == "ralf/default"
    assert SERVICES == ("plant", "controller", "dsp")


def _all_keys(keys: Keys) -> list[str]:
    props = [name for name, value in vars(Keys).items() if isinstance(value, property) and not name.endswith("_all") and name != "root"]
    return [getattr(keys, name) for name in props] + [keys.health(s) for s in SERVICES] + [keys.alive(s) for s in SERVICES]


@settings(max_examples=50, deadline=None)
@given(rig_id=rig_ids)
def test_keys_are_distinct_and_live_under_the_rig(rig_id: str) -> None:
    keys = Keys(rig_id)
    exprs = _all_keys(keys)
    assert len(exprs) == len(set(exprs)) == 24 + 2 * len(SERVICES)
    for expr in exprs:
        assert expr.startswith(f"ralf/{rig_id}/")
        assert "*" not in expr and "//" not in expr and not expr.endswith("/")


def test_keys_of_two_rigs_never_collide() -> None:
    a, b = _all_keys(Keys("a")), _all_keys(Keys("a-b"))
    assert not set(a) & set(b)
    assert not any(x.startswith(Keys("a").root + "/") for x in b)


def test_keys_are_valid_zenoh_key_expressions() -> None:
    zenoh = pytest.importorskip("zenoh")
    keys = Keys("lab_1-x")
    for expr in [*_all_keys(keys), keys.health_all, keys.alive_all]:
        assert str(zenoh.KeyExpr(expr)) == expr  # already canonical
    wildcard = zenoh.KeyExpr(keys.health_all)
    assert wildcard.intersects(zenoh.KeyExpr(keys.health("dsp")))
    assert not wildcard.intersects(zenoh.KeyExpr(Keys("other").health("dsp")))


def test_keys_are_frozen_and_hashable() -> None:
    keys = Keys("r")
    with pytest.raises(AttributeError):
        keys.rig_id = "s"  # type: ignore[misc]
    assert Keys("r") == keys and hash(Keys("r")) == hash(keys)


def test_settings_rig_id_feeds_keys(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RALF_RIG_ID", "bench-3")
    assert Keys(load_settings(CommonSettings).rig_id).batch == "ralf/bench-3/dsp/batch"
