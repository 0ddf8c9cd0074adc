"""Configuration of each program: one pydantic-settings model per program,
read from ``RALF_*`` environment variables (and ``--set NAME=VALUE`` on the
command line, which takes precedence). Every field is documented; each
program's ``--help`` prints them.
"""

from __future__ import annotations

import base64
import json
import math
import os
import re
import sys
from typing import Annotated, Any, Literal, get_args

from pydantic import Field, SecretStr, ValidationError, ValidationInfo, field_serializer, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict, SettingsError

from protocol.errors import ConfigError
from protocol.files import NotARegularFile, check_regular_file
from protocol.keys import validate_rig_id
from protocol.param_schedule import parse_param_schedule
from protocol.scenario_setting import parse_channel_faults, parse_scenario, parse_scenario_stimulus
from protocol.setting_groups import (
    DitherTuning,
    InputMonitors,
    OatfTuning,
    PiGains,
    Policies,
    RealtimeMeasures,
    SettingGroup,
    Smoothing,
    Timeouts,
    UdpCanOptions,
    band_text,
    describe_group,
)
from protocol.setting_hints import ANY, unknown_setting, variable
from protocol.stimulus import parse_stimulus

_ENDPOINT = re.compile(r"(?:(?:tcp|udp|tls|quic|ws)/(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(?P<port>\d{1,5})|unixsock-stream/\S+)(?:[?#]\S*)?")
CREDENTIALS_FILE_MASK = "(set; path not recorded)"
"""What a dump of the settings shows for a credentials or key file."""
TLS_FIELDS = ("zenoh_tls_ca", "zenoh_tls_certificate", "zenoh_tls_key")
TLS_INLINE_FIELDS = ("zenoh_tls_ca_base64", "zenoh_tls_certificate_base64", "zenoh_tls_key_base64")
"""Mutual TLS given inline (base64 of each PEM file) instead of as files: a container's
environment, where a mounted owner-only key file is not the container user's to read."""
TLS_INLINE_MAX_CHARS = 16384
"""The longest inline TLS value (base64 of one PEM file: a P-256 key is ~320 characters, a certificate ~900)."""
ACCESS_FIELDS = frozenset(
    {"zenoh_user", "zenoh_password", "zenoh_credentials_file", *TLS_FIELDS, *TLS_INLINE_FIELDS, "zenoh_acl", "zenoh_connect", "zenoh_listen", "launcher_pid"}
)
"""Who a run's sessions were, where they linked and what started them: recorded masked or moot, left out when recorded settings are rebuilt (replay, plots)."""


def _regular_file(value: str) -> str:
    """A setting naming a file to read: it must be a regular file (checked with
    ``stat``, never opened: a FIFO would block the open, a device never end)."""
    if value:
        try:
            check_regular_file(value)
        except NotARegularFile as exc:
            raise ValueError(str(exc)) from None
    return value


def _numeric(annotation: Any) -> bool:
    """Whether a field's type holds numbers (float, int, or containers/unions of them)."""
    if annotation in (float, int):
        return True
    return any(_numeric(arg) for arg in get_args(annotation))


def _is_nan(value: Any) -> bool:
    if isinstance(value, float):
        return math.isnan(value)
    if isinstance(value, str):
        return value.strip().lower() in ("nan", "+nan", "-nan")
    return False


CAN_BITRATES: tuple[int, ...] = (125_000, 250_000, 500_000, 1_000_000)
"""The bit rates ``can_bitrate`` takes beside 0 (``service_kit.can_wire.timing.STANDARD_BITRATES``, tested equal)."""


class CommonSettings(BaseSettings):
    """Settings every program reads."""

    model_config = SettingsConfigDict(env_prefix="RALF_", extra="forbid", validate_default=True)

    rig_id: str = Field("default", description="Namespace of this rig on zenoh: keys live under ralf/<rig_id>/")
    zenoh_mode: Literal["peer", "client", "router"] = Field("peer", description="zenoh session mode")
    zenoh_connect: str = Field("", description="Comma-separated zenoh endpoints to connect to, e.g. tcp/127.0.0.1:7447")
    zenoh_listen: str = Field("", description="Comma-separated zenoh endpoints to listen on")
    zenoh_multicast_scouting: bool = Field(False, description="Discover peers by UDP multicast (off: explicit endpoints)")
    zenoh_lease_ms: int = Field(3000, ge=500, le=60000, description="zenoh link lease: a frozen peer is declared gone (liveliness lost) after this long")
    can_interface: str = Field("udp_multicast", description="python-can interface: udp_multicast, virtual, socketcan, ...")
    can_channel: str = Field("239.74.163.2", description="python-can channel (multicast group, vcan0, ...)")
    can_port: int = Field(43113, ge=1, le=65535, description="UDP port of the udp_multicast interface (one per rig)")
    node_id: int = Field(1, ge=1, le=127, description="CANopen node id of the plant's analog I/O module")
    can_bitrate: int = Field(
        0,
        ge=0,
        le=1_000_000,
        description="CAN bit rate of the wire model: 0 = none (frames take no time), else 125000, 250000, 500000 or 1000000 (simulated time in co-simulation and one-process lockstep; a wire arbiter under ralf-hil up)",
    )
    can_restbus: str = Field("", description="DBC of the rest of the bus sent beside the rig on the wire (needs can_bitrate); empty: none")
    clock: Literal["realtime", "lockstep"] = Field("realtime", description="realtime: wall-clock SYNC; lockstep: one plant step per SYNC, as fast as possible")
    sample_rate_hz: float = Field(200.0, ge=1, le=5000, description="Control and identification sample rate")
    health_period_s: float = Field(1.0, ge=0.01, le=60, description="Period of health messages on ralf/<rig>/health/<service>")
    realtime: Annotated[RealtimeMeasures, NoDecode] = Field(
        RealtimeMeasures(),
        description="Real-time measures of the loop thread, each where permitted, KEY=VALUE,... (unnamed keys keep their defaults; docs/timing.md): "
        + describe_group(RealtimeMeasures),
    )
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = Field("INFO", description="Logging level")
    zenoh_user: str = Field(
        "",
        max_length=64,
        description="zenoh user name (transport/auth/usrpwd): the session's role, controller, dsp, plant, tool or tester (empty: no authentication)",
    )
    zenoh_password: SecretStr = Field(
        SecretStr(""), max_length=256, description="zenoh password of zenoh_user (a secret: shown and recorded as asterisks, never in clear)"
    )
    zenoh_credentials_file: str = Field(
        "",
        description="File of user:password lines: peers must authenticate with one of them (empty: any peer is accepted); its path is not recorded",
    )
    zenoh_acl: Literal["off", "on", "scenarios"] = Field(
        "off",
        description="on: apply the rig's access rules (service_kit/access.py): deny by default, each role sends only on its own exact keys "
        "(a client leaves them to its router); scenarios: the same, and accept scenario commands on the plant's test port from the tester role",
    )
    zenoh_tls_ca: str = Field(
        "",
        description="Mutual TLS (tls/ endpoints): the certificate of the authority every peer's certificate must be signed by "
        "(ralf-hil up makes one per run); its path is not recorded",
    )
    zenoh_tls_certificate: str = Field(
        "", description="Mutual TLS: this session's certificate, its common name the session's role (controller, dsp, plant...); its path is not recorded"
    )
    zenoh_tls_key: str = Field("", description="Mutual TLS: the private key of zenoh_tls_certificate; its path is not recorded")
    zenoh_tls_ca_base64: SecretStr = Field(
        SecretStr(""),
        max_length=TLS_INLINE_MAX_CHARS,
        description="Mutual TLS given inline instead of as files (docker compose: ralf-hil credentials writes them into ralf.env): "
        "the authority's certificate, base64 of its PEM file; not recorded",
    )
    zenoh_tls_certificate_base64: SecretStr = Field(
        SecretStr(""), max_length=TLS_INLINE_MAX_CHARS, description="Mutual TLS inline: this session's certificate, base64 of its PEM file; not recorded"
    )
    zenoh_tls_key_base64: SecretStr = Field(
        SecretStr(""), max_length=TLS_INLINE_MAX_CHARS, description="Mutual TLS inline: its private key, base64 of its PEM file (a secret); not recorded"
    )
    can_udp: Annotated[UdpCanOptions, NoDecode] = Field(
        UdpCanOptions(),
        description="The udp_multicast interface's options, KEY=VALUE,... (unnamed keys keep their defaults): " + describe_group(UdpCanOptions),
    )
    launcher_pid: int = Field(
        0,
        ge=0,
        le=2**22,
        description="End this service (as on SIGTERM) when its launcher, the parent process with this PID, ends by any signal (0 = off; ralf-hil up sets it)",
    )
    ready_file: str = Field(
        "",
        max_length=4096,
        description="Write this file when the service is ready and remove it at exit; a healthcheck reads it (python -m service_kit.readiness FILE)",
    )

    @field_validator("*", mode="before")
    @classmethod
    def _no_nan(cls, value: Any, info: ValidationInfo) -> Any:
        # A NaN passes neither gt nor le, and pydantic would report it as
        # "should be <= 5000": say what it is instead. Only where a number is
        # expected: "NaN" is a fine rig id or file name.
        field = cls.model_fields.get(info.field_name or "")
        if field is not None and not _numeric(field.annotation):
            return value
        if _is_nan(value) or (isinstance(value, (list, tuple)) and any(_is_nan(v) for v in value)):
            raise ValueError("NaN (not a number) is not a valid value; give a finite number")
        return value

    @model_validator(mode="before")
    @classmethod
    def _no_retired(cls, data: Any) -> Any:
        # A retired name given from Python (run_cosim(controller={...}), a sweep's
        # settings) is refused with its replacement, as on the command line.
        if isinstance(data, dict):
            gone = [f"{name}: {retired(name)}" for name in data if isinstance(name, str) and name not in cls.model_fields and retired(name)]
            if gone:
                raise ValueError("; ".join(gone))
        return data

    @field_validator("rig_id")
    @classmethod
    def _rig_id(cls, value: str) -> str:
        return validate_rig_id(value)

    @field_validator("zenoh_acl", mode="before")
    @classmethod
    def _acl_switch(cls, value: Any) -> Any:
        # a plain switch still reads as one: true/false, 1/0, yes/no
        text = str(value).strip().lower()
        if value is True or text in ("true", "1", "yes"):
            return "on"
        if value is False or text in ("false", "0", "no", ""):
            return "off"
        return text

    @field_validator("realtime", "can_udp", mode="before")
    @classmethod
    def _realtime_text(cls, value: Any) -> Any:
        return SettingGroup.coerce(value)

    @field_validator("zenoh_credentials_file", *TLS_FIELDS)
    @classmethod
    def _credentials_file(cls, value: str) -> str:
        return _regular_file(value)

    @field_validator(*TLS_INLINE_FIELDS)
    @classmethod
    def _inline_pem(cls, value: SecretStr) -> SecretStr:
        text = value.get_secret_value()
        if text:
            try:
                pem = base64.b64decode(text, validate=True)
            except ValueError:
                raise ValueError("not base64 (of a PEM file)") from None
            if b"-----BEGIN " not in pem:
                raise ValueError("base64, but not of a PEM file (no -----BEGIN line)")
        return value

    @field_serializer("zenoh_credentials_file", *TLS_FIELDS)
    def _credentials_path_unrecorded(self, value: str) -> str:
        # Settings are dumped into recordings and run records, which users share:
        # where the credentials live is no business of theirs.
        return CREDENTIALS_FILE_MASK if value else ""

    @field_validator("can_bitrate")
    @classmethod
    def _can_bitrate(cls, value: int) -> int:
        if value != 0 and value not in CAN_BITRATES:
            allowed = ", ".join(str(r) for r in CAN_BITRATES)
            raise ValueError(f"{value} bit/s is not a CAN bit rate the wire model runs at: 0 (no wire) or one of {allowed}")
        return value

    @model_validator(mode="after")
    def _restbus_needs_wire(self) -> CommonSettings:
        if self.can_restbus and not self.can_bitrate:
            raise ValueError(f"RALF_CAN_RESTBUS={self.can_restbus} needs RALF_CAN_BITRATE (a restbus takes wire time: 125000, 250000, 500000 or 1000000)")
        return self

    @model_validator(mode="after")
    def _user_has_password(self) -> CommonSettings:
        if self.zenoh_user and not self.zenoh_password.get_secret_value():
            raise ValueError("RALF_ZENOH_USER is set without RALF_ZENOH_PASSWORD: a zenoh user needs its password")
        if self.zenoh_password.get_secret_value() and not self.zenoh_user:
            raise ValueError("RALF_ZENOH_PASSWORD is set without RALF_ZENOH_USER: give the user it belongs to")
        return self

    @model_validator(mode="after")
    def _tls_complete(self) -> CommonSettings:
        files = [name for name in TLS_FIELDS if getattr(self, name)]
        inline = [name for name in TLS_INLINE_FIELDS if getattr(self, name).get_secret_value()]
        if files and inline:
            raise ValueError(
                f"mutual TLS is given both as files ({', '.join(f'RALF_{n.upper()}' for n in files)}) and inline "
                f"({', '.join(f'RALF_{n.upper()}' for n in inline)}): give one of the two"
            )
        group, given = (TLS_INLINE_FIELDS, inline) if inline else (TLS_FIELDS, files)
        names = ", ".join(f"RALF_{n.upper()}" for n in group)
        if given and len(given) < len(group):
            missing = ", ".join(f"RALF_{n.upper()}" for n in group if n not in given)
            raise ValueError(f"mutual TLS needs all of {names}; {missing} not set")
        endpoints = self.endpoints("connect") + self.endpoints("listen")
        if given and any(not e.startswith("tls/") for e in endpoints):
            plain = ", ".join(e for e in endpoints if not e.startswith("tls/"))
            raise ValueError(f"{names} are set, so every zenoh endpoint must be tls/HOST:PORT, got {plain}")
        if not given and any(e.startswith("tls/") for e in endpoints):
            raise ValueError(f"tls/ endpoints need {names} (ralf-hil up writes them into the run's tool.env)")
        if not given and self.zenoh_acl != "off" and self.zenoh_mode == "peer":
            raise ValueError(
                f"RALF_ZENOH_ACL={self.zenoh_acl} in peer mode needs mutual TLS ({names}; ralf-hil up sets them): "
                "a peer knows the sessions it links to by their certificates"
            )
        return self

    def zenoh_tls(self) -> tuple[tuple[str, str, str], bool] | None:
        """This session's mutual TLS: (authority, certificate, key) and whether
        they are inline (base64 of the PEM files) rather than file paths; None without TLS."""
        inline = tuple(getattr(self, name).get_secret_value() for name in TLS_INLINE_FIELDS)
        if all(inline):
            return (inline[0], inline[1], inline[2]), True
        if self.zenoh_tls_ca:
            return (self.zenoh_tls_ca, self.zenoh_tls_certificate, self.zenoh_tls_key), False
        return None

    @field_validator("zenoh_connect", "zenoh_listen")
    @classmethod
    def _endpoints(cls, value: str) -> str:
        for endpoint in (e.strip() for e in value.split(",")):
            if endpoint and not _ENDPOINT.fullmatch(endpoint):
                raise ValueError(f"{endpoint!r} is not a zenoh endpoint PROTOCOL/HOST:PORT (e.g. tcp/127.0.0.1:7447)")
            port = _ENDPOINT.fullmatch(endpoint).group("port") if endpoint else None  # type: ignore[union-attr]
            if port is not None and int(port) > 65535:
                raise ValueError(f"{endpoint!r}: port {port} is above 65535")
        return value

    @property
    def sample_period_s(self) -> float:
        return 1.0 / self.sample_rate_hz

    def endpoints(self, which: Literal["connect", "listen"]) -> list[str]:
        raw = self.zenoh_connect if which == "connect" else self.zenoh_listen
        return [e.strip() for e in raw.split(",") if e.strip()]


class PlantSettings(CommonSettings):
    """The plant emulator (``ralf-plant``)."""

    seed: int = Field(0, ge=0, lt=2**32, description="Seed of the sensor-noise generator")
    payload_attached: bool = Field(False, description="Start with the 15.65 lb payload at the tip")
    adc_bits: Literal[12, 16, 20] = Field(12, description="A/D resolution (the thesis's rig: 12 bits)")
    sensor_noise_scale: float = Field(
        1.0, ge=0, le=100, description="Scale of every sensor's analog noise std (1 = the thesis's rig, 0 = noiseless; quantization stays)"
    )
    valve_time_constant_s: float = Field(0.01, ge=0.001, le=0.05, description="Valve-to-cylinder-velocity lag")
    truth_rate_hz: float = Field(20.0, ge=0, le=1000, description="Rate of ground truth on the test port (0 = off)")
    watchdog_periods: int = Field(5, ge=1, le=10000, description="SYNC periods without SYNC before the valves are held")
    heartbeat_ms: int = Field(100, ge=0, le=65535, description="CANopen heartbeat producer period (0 = off)")
    scenario: str = Field(
        "",
        description='Scenario commands applied at their simulated times, JSON list, e.g. [{"kind": "payload", "at_sim_time_s": 30, "payload_attached": false}]; '
        "or an object with sections commands (that list), channel_faults (faults on the A/D and D/A channels, docs/fault-insertion.md) "
        "and stimulus (profiles on the payload and the links' disturbance forces, docs/stimulus.md)",
    )
    truth_record: str = Field(
        "", description="Write the ground truth at truth_rate_hz to PATH.truth.npz when the plant stops (the plant's only file; empty = none)"
    )

    @field_validator("scenario", mode="before")
    @classmethod
    def _scenario_as_json(cls, value: Any) -> Any:
        """A list or mapping (a YAML scenario file's ``settings: {plant: {scenario: ...}}``, a dict in Python) as its JSON text."""
        return json.dumps(value) if isinstance(value, list | dict) else value

    @field_validator("scenario")
    @classmethod
    def _scenario_commands(cls, value: str) -> str:
        try:
            parse_scenario(value)
            parse_channel_faults(value)
            parse_scenario_stimulus(value)
        except ConfigError as exc:
            raise ValueError(str(exc).removeprefix("RALF_SCENARIO ")) from None
        return value

    @model_validator(mode="after")
    def _channel_faults_fit_the_converter(self) -> PlantSettings:
        parse_channel_faults(self.scenario).check_resolution(self.adc_bits)
        return self

    model: str = Field(
        "ralf",
        max_length=4096,
        description="The plant behind the node: ralf (the built-in RALF arm) or fmu:PATH (an FMI 2.0/3.0 co-simulation FMU, docs/fmu-plant.md)",
    )
    fmu_mapping: str = Field("", max_length=4096, description="With model=fmu:PATH: the YAML file that maps the node's I/O to the FMU's variables")
    xcp_udp_port: int = Field(0, ge=0, le=65535, description="Serve the plant over XCP (its state, its parameters; docs/xcp.md) on this UDP port (0 = off)")
    xcp_tcp_port: int = Field(0, ge=0, le=65535, description="Serve the plant over XCP on this TCP port (0 = off)")
    xcp_host: str = Field("127.0.0.1", min_length=1, max_length=255, description="The address the plant's XCP ports bind to")
    xcp_a2l: str = Field("", max_length=4096, description="Where the plant writes its A2L (empty = ralf-RIG_ID-plant.a2l in the temporary directory)")
    xcp_can: bool = Field(False, description="Serve the plant over XCP on the rig's CAN bus, on xcp_can_id_master/xcp_can_id_slave")
    xcp_can_id_master: int = Field(0x7E2, ge=1, le=0x7FF, description="The plant's XCP on CAN: the master's identifier (master -> slave)")
    xcp_can_id_slave: int = Field(0x7E3, ge=1, le=0x7FF, description="The plant's XCP on CAN: the slave's identifier (slave -> master)")
    param_schedule: str = Field(
        "",
        max_length=1_000_000,
        description="Scripted changes of the plant's parameters, a JSON list, e.g. "
        '[{"name": "plant.payload", "value": 1, "at_s": 2}] (each at the first SYNC at or after at_s; docs/calibration.md; empty = none)',
    )
    param_commands: bool = Field(
        False,
        description="Answer `ralf-hil param` (list, get) for the plant's parameters and take changes from param_write_roles (docs/calibration.md)",
    )
    param_write_roles: str = Field(
        "tester",
        pattern=r"^(|tester|tool|tester,tool|tool,tester)$",
        description="With param_commands: the roles whose changes of the plant's parameters are taken (tester, tool; empty = none)",
    )

    @field_validator("param_schedule", mode="before")
    @classmethod
    def _schedule_as_json(cls, value: Any) -> Any:
        """A list (a YAML file's, Python's) as its JSON text."""
        return json.dumps(value) if isinstance(value, list | tuple) else value

    @field_validator("param_schedule")
    @classmethod
    def _param_steps(cls, value: str) -> str:
        try:
            parse_param_schedule(value)
        except ConfigError as exc:
            raise ValueError(str(exc).removeprefix("param_schedule").lstrip(": ")) from None
        return value

    @field_validator("model")
    @classmethod
    def _model(cls, value: str) -> str:
        if value == "ralf":
            return value
        path = value.removeprefix("fmu:").strip()
        if not value.startswith("fmu:") or not path:
            raise ValueError(f"{value!r} is neither ralf nor fmu:PATH")
        if os.path.lexists(path):  # absent: the FMU loader names it; anything but a regular file is named here
            try:
                check_regular_file(path, max_bytes=sys.maxsize)  # its size is the loader's to bound (plant_emulator/fmu/extract.py)
            except NotARegularFile as exc:
                raise ValueError(f"FMU {exc}") from None
        return value

    @field_validator("fmu_mapping")
    @classmethod
    def _fmu_mapping_file(cls, value: str) -> str:
        return _regular_file(value)

    @model_validator(mode="after")
    def _fmu_needs_mapping(self) -> PlantSettings:
        if self.model.startswith("fmu:") and not self.fmu_mapping.strip():
            raise ValueError("model=fmu:PATH needs fmu_mapping=MAP.yaml (docs/fmu-plant.md)")
        return self

    @field_validator("adc_bits", mode="before")
    @classmethod
    def _adc_bits_text(cls, value: Any) -> Any:
        # RALF_ADC_BITS and --set adc_bits=16 arrive as text; an int Literal does not coerce it.
        if isinstance(value, str) and value.strip().isdigit():
            return int(value.strip())
        return value


class ControllerSettings(CommonSettings):
    """The controller (``ralf-controller``), the emulated MVME CPU."""

    duration_s: float | None = Field(None, ge=0.01, le=1e7, description="Stop after this much simulated time (default: after `repeats` passes)")
    trajectory: str = Field("", description="Trajectory way-point JSON file (default: the thesis's inspection loop)")
    tip_speed_in_s: float = Field(5.0, ge=0.01, le=20, description="Tip speed along the trajectory (thesis: 4 or 5 in/s)")
    repeats: int = Field(0, ge=0, le=100000, description="Passes around the trajectory before stopping (0 = until stopped)")
    batch_size: int = Field(
        30, ge=1, le=4096, description="Samples per batch sent to the DSP (l); its period (150 ms) must exceed the DSP's latency (thesis: 20-50)"
    )
    oatf_mode: Literal["off", "fixed", "adaptive"] = Field("off", description="OATF input shaping: off, fixed, adaptive")
    oatf: Annotated[OatfTuning, NoDecode] = Field(
        OatfTuning(),
        description="OATF tuning, KEY=VALUE,... (unnamed keys keep their defaults): " + describe_group(OatfTuning),
    )
    dither: Annotated[DitherTuning, NoDecode] = Field(
        DitherTuning(),
        description="Valve dither for the identifier, KEY=VALUE,... (unnamed keys keep their defaults; docs/identification.md): "
        + describe_group(DitherTuning),
    )
    pi: Annotated[PiGains, NoDecode] = Field(
        PiGains(), description="The joints' PI gains, KEY=VALUE,... each a pair JOINT1,JOINT2 (unnamed keys keep their defaults): " + describe_group(PiGains)
    )
    tf_download_samples: int = Field(1000, ge=0, le=10**7, description="Download transfer functions every this many samples (0 = never)")
    timeouts: Annotated[Timeouts, NoDecode] = Field(
        Timeouts(), description="The controller's timeouts, KEY=VALUE,... (unnamed keys keep their defaults; docs/timing.md): " + describe_group(Timeouts)
    )
    run_record: str = Field(
        "",
        description="Write the run record to PATH.npz and PATH.json, with PATH.timing.*, PATH.tf.npz (and PATH.hops.npz in real time) beside it (empty = none)",
    )
    policies: Annotated[Policies, NoDecode] = Field(
        Policies(),
        description="What the controller does on each monitored event, KEY=VALUE,... of count, warn, degrade or stop (unnamed keys keep their defaults): "
        + describe_group(Policies),
    )
    input_monitors: Annotated[InputMonitors, NoDecode] = Field(
        InputMonitors(),
        description="Plausibility checks on the A/D inputs, KEY=VALUE,... (all off unless named; docs/fault-insertion.md): " + describe_group(InputMonitors),
    )
    xcp_udp_port: int = Field(0, ge=0, le=65535, description="Serve XCP (measurement and calibration, docs/xcp.md) on this UDP port (0 = off)")
    xcp_tcp_port: int = Field(0, ge=0, le=65535, description="Serve XCP on this TCP port (0 = off)")
    xcp_host: str = Field("127.0.0.1", min_length=1, max_length=255, description="The address the XCP ports bind to")
    xcp_a2l: str = Field(
        "", max_length=4096, description="Where the running controller writes its A2L, named by XCP GET_ID (empty = ralf-RIG_ID.a2l in the temporary directory)"
    )
    xcp_can: bool = Field(False, description="Serve XCP on the rig's CAN bus as well, on xcp_can_id_master/xcp_can_id_slave (docs/xcp.md)")
    xcp_can_id_master: int = Field(0x7E0, ge=1, le=0x7FF, description="XCP on CAN: the master's identifier (master -> slave, 11 bit)")
    xcp_can_id_slave: int = Field(0x7E1, ge=1, le=0x7FF, description="XCP on CAN: the slave's identifier (slave -> master: answers, DAQ)")
    fault_scenario: str = Field(
        "",
        max_length=100_000,
        description="Faults (link faults on CAN and zenoh, loop stalls; the DSP reads its dsp_delay_s): a scenario file (YAML/JSON) or inline JSON, docs/timing-faults.md (empty = none)",
    )

    stimulus: str = Field(
        "",
        max_length=1_000_000,
        description="Stimulus profiles on the set-points and valves, a JSON list, e.g. "
        '[{"input": "valve.u1", "shape": "step", "size": 2, "at_s": 1, "for_s": 0.5}] (docs/stimulus.md; empty = none)',
    )

    param_schedule: str = Field(
        "",
        max_length=1_000_000,
        description="Scripted parameter changes, a JSON list, e.g. "
        '[{"name": "controller.kp1", "value": 8000, "at_s": 2}] (each at the first tick at or after at_s; docs/calibration.md; empty = none)',
    )
    param_commands: bool = Field(
        False,
        description="Answer `ralf-hil param` (list, get) and the live view's parameter panel, and take changes from param_write_roles (docs/calibration.md)",
    )
    param_write_roles: str = Field(
        "tester",
        pattern=r"^(|tester|tool|tester,tool|tool,tester)$",
        description="With param_commands: the roles whose parameter changes are taken (tester, tool: also tools and the live view; empty = none)",
    )

    @field_validator("oatf", "dither", "pi", "timeouts", "policies", "input_monitors", mode="before")
    @classmethod
    def _group_text(cls, value: Any) -> Any:
        return SettingGroup.coerce(value)

    @field_validator("stimulus", "param_schedule", mode="before")
    @classmethod
    def _stimulus_as_json(cls, value: Any) -> Any:
        """A list (a YAML file's, Python's) as its JSON text."""
        return json.dumps(value) if isinstance(value, list | tuple) else value

    @field_validator("stimulus")
    @classmethod
    def _stimulus_profiles(cls, value: str) -> str:
        try:
            parse_stimulus(value, "controller")
        except ConfigError as exc:
            raise ValueError(str(exc).removeprefix("stimulus ")) from None
        return value

    @field_validator("param_schedule")
    @classmethod
    def _param_steps(cls, value: str) -> str:
        try:
            parse_param_schedule(value)
        except ConfigError as exc:
            raise ValueError(str(exc).removeprefix("param_schedule").lstrip(": ")) from None
        return value

    @field_validator("run_record")
    @classmethod
    def _not_a_truth_name(cls, value: str) -> str:
        stem = value.removesuffix(".npz").removesuffix(".json")
        if stem.endswith(".truth"):
            raise ValueError(f"{value!r}: a name ending in .truth is the plant's ground truth (RALF_TRUTH_RECORD writes PATH.truth.npz); choose another")
        return value

    @field_validator("trajectory")
    @classmethod
    def _trajectory_file(cls, value: str) -> str:
        return _regular_file(value)

    @field_validator("fault_scenario")
    @classmethod
    def _fault_scenario_file(cls, value: str) -> str:
        return value if value.lstrip()[:1] in ("{", "[") else _regular_file(value)


class DspSettings(CommonSettings):
    """The DSP service (``ralf-dsp``), the emulated C40 board."""

    fft_width: int = Field(2048, ge=32, le=65536, description="FFT width N (history length per channel)")
    batch_size: int = Field(30, ge=1, le=4096, description="Expected batch size l (sets the default compute budget; any size is accepted)")
    alpha: float = Field(0.1, ge=1e-4, le=1, description="Exponential averaging weight [2-9]")
    averaging: Literal["exponential", "rls"] = Field("exponential", description="Spectral averaging method")
    identifier: Literal["etfe", "etfe-welch", "etfe-transient", "arx"] = Field(
        "etfe",
        description="Poles from the ETFE peak search (the thesis), the ETFE with Welch segments and fitted damping, the ETFE with the transient-aware damping fit, or the recursive QR-form ARX model (see docs/identification.md)",
    )
    arx_regime_bank: int = Field(
        0,
        ge=0,
        le=8,
        description="With identifier arx: regimes the model remembers on line (0 = off); after a change into a regime seen before it switches to the remembered model within ~0.5 s (docs/identification.md section 5c)",
    )
    arx_regime_bank_file: str = Field(
        "",
        description="With arx_regime_bank > 0: an .npz file of remembered regimes carried across runs, loaded when the board starts "
        "(if it exists; a bank of another model structure is refused) and written when it stops, so a change into a regime an "
        "earlier run has shown is followed within ~0.5 s from the first (docs/identification.md section 5d); "
        "{rig_id} in the path is replaced by each served rig's id",
    )
    solver: Literal["mimo", "uncorrelated"] = Field("mimo", description="2x2 solve [2-21..2-24] or the uncorrelated shortcut [2-25..2-28]")
    smoothing: Annotated[Smoothing, NoDecode] = Field(
        Smoothing(), description="Savitzky-Golay smoothing across bins, KEY=VALUE,... (unnamed keys keep their defaults): " + describe_group(Smoothing)
    )
    emulated_latency_s: float = Field(0.1, ge=0, le=10, description="C40 compute latency to emulate (the thesis: ~100 ms)")
    budget_s: float | None = Field(None, ge=0.001, le=60, description="Compute-time budget per batch (default: the batch period)")
    search_band_hz: Annotated[tuple[Annotated[float, Field(ge=0, le=2500)], Annotated[float, Field(ge=0.01, le=2500)]], NoDecode] = Field(
        (0.5, 40.0), description="Band of the peak search, LOW,HIGH (Hz; above Nyquist the search stops at Nyquist)"
    )
    fault_scenario: str = Field(
        "", max_length=100_000, description="Faults: the scenario's dsp_delay_s slows this board (the same file as the controller's, docs/timing-faults.md)"
    )
    serve_rigs: str = Field(
        "", description="Further rig ids this one DSP process serves besides rig_id, comma-separated (each its own board: identifier, queue and thread)"
    )

    @field_validator("fault_scenario")
    @classmethod
    def _fault_scenario_file(cls, value: str) -> str:
        return value if value.lstrip()[:1] in ("{", "[") else _regular_file(value)

    @field_validator("smoothing", mode="before")
    @classmethod
    def _group_text(cls, value: Any) -> Any:
        return SettingGroup.coerce(value)

    @field_validator("serve_rigs")
    @classmethod
    def _serve_rigs(cls, value: str) -> str:
        ids = [r.strip() for r in value.split(",") if r.strip()]
        for rig in ids:
            validate_rig_id(rig)
        if len(set(ids)) != len(ids):
            raise ValueError(f"serve_rigs lists a rig twice: {value!r}")
        return ",".join(ids)

    @property
    def rig_ids(self) -> tuple[str, ...]:
        """Every rig this process serves: ``rig_id`` first, then ``serve_rigs``."""
        extra = [r for r in self.serve_rigs.split(",") if r and r != self.rig_id]
        return (self.rig_id, *extra)

    @field_validator("arx_regime_bank_file")
    @classmethod
    def _bank_file(cls, value: str) -> str:
        if "{rig_id}" in value:
            return value  # one file per rig: checked when each board opens its own
        return _regular_file(value) if value and os.path.lexists(value) else value  # absent: written at the stop

    @field_validator("search_band_hz", mode="before")
    @classmethod
    def _band_text(cls, value: Any) -> Any:
        return band_text(value)

    @field_validator("fft_width")
    @classmethod
    def _power_of_two(cls, value: int) -> int:
        if value & (value - 1):
            raise ValueError(f"fft_width must be a power of two, got {value}")
        return value

    @model_validator(mode="after")
    def _checks(self) -> DspSettings:
        if self.search_band_hz[1] <= self.search_band_hz[0]:
            raise ValueError("the search band's upper edge must exceed its lower edge")
        if self.arx_regime_bank_file:
            if self.identifier != "arx" or self.arx_regime_bank == 0:
                raise ValueError("arx_regime_bank_file needs identifier 'arx' and arx_regime_bank > 0")
            if len(self.rig_ids) > 1 and "{rig_id}" not in self.arx_regime_bank_file:
                raise ValueError("arx_regime_bank_file must contain {rig_id} when the process serves several rigs (one bank per rig)")
        return self

    def regime_bank_path(self) -> str:
        """:attr:`arx_regime_bank_file` for this board's rig (``{rig_id}`` replaced); empty when unset."""
        return self.arx_regime_bank_file.replace("{rig_id}", self.rig_id)


def settings_models() -> tuple[type[CommonSettings], ...]:
    """Every program's settings model."""
    return (PlantSettings, ControllerSettings, DspSettings)


def known_variables() -> set[str]:
    """Every ``RALF_*`` variable some program reads."""
    return {f"RALF_{name.upper()}" for model in settings_models() for name in model.model_fields}


_FAULTS = "docs/timing-faults.md"
_TIMEOUTS: dict[str, str] = {
    "startup_timeout_s": "startup_s",
    "lockstep_timeout_s": "lockstep_s",
    "plant_heartbeat_timeout_s": "plant_heartbeat_s",
    "stale_after_s": "stale_after_s",
    "dsp_deadline_s": "dsp_deadline_s",
}
"""The controller's timeouts before they became keys of RALF_TIMEOUTS."""
RETIRED: dict[str, str] = {
    "record": "RALF_RECORD named two files (the plant's truth and the controller's record, the last to stop overwrote the other): "
    "set RALF_RUN_RECORD (the controller's run record) and/or RALF_TRUTH_RECORD (the plant's ground truth) instead",
    "inject_stall_at_s": f'faults are scripted in RALF_FAULT_SCENARIO: a loop stall is {{"stalls": [{{"at_s": T, "wall_s": S}}]}} ({_FAULTS})',
    "inject_stall_s": f'faults are scripted in RALF_FAULT_SCENARIO: a loop stall is {{"stalls": [{{"at_s": T, "wall_s": S}}]}} ({_FAULTS})',
    "inject_sync_drop_every": "faults are scripted in RALF_FAULT_SCENARIO: lost SYNC frames are a can fault on kind sync "
    f'with drop or outage, e.g. {{"faults": [{{"link": "can", "kinds": ["sync"], "outage": {{"every_s": 0.25, "length_s": 0.005}}}}]}} ({_FAULTS})',
    "inject_delay_s": f'faults are scripted in RALF_FAULT_SCENARIO: a slowed DSP board is {{"dsp_delay_s": S}} ({_FAULTS})',
    **{
        f"policy_{key}": f"the policies are one setting: RALF_POLICIES={key}=VALUE (KEY=VALUE,...; unnamed keys keep their defaults)"
        for key in Policies.model_fields
    },
    **{
        f"oatf_{key}": f"the OATF tuning is one setting: RALF_OATF={key}=VALUE (KEY=VALUE,...; unnamed keys keep their defaults)"
        for key in OatfTuning.model_fields
    },
    **{
        f"dither_{key}": f"the dither is one setting: RALF_DITHER={key}=VALUE (KEY=VALUE,...; unnamed keys keep their defaults)"
        for key in DitherTuning.model_fields
    },
    **{
        old: f"the real-time measures are one setting: RALF_REALTIME={key}=VALUE (KEY=VALUE,...; unnamed keys keep their defaults)"
        for old, key in (("rt_priority", "priority"), ("cpu_affinity", "cpus"), ("rt_cpu_latency_us", "cpu_latency_us"))
    },
    "can_multicast_ttl": "the udp_multicast options are one setting: RALF_CAN_UDP=ttl=VALUE (KEY=VALUE,...; unnamed keys keep their defaults)",
    "can_own_frame_filter": "the udp_multicast options are one setting: RALF_CAN_UDP=own_frame_filter=VALUE (KEY=VALUE,...; unnamed keys keep their defaults)",
    "zenoh_acl_scenarios": "access control is one setting: RALF_ZENOH_ACL=scenarios (the rules, and scenario commands from the tester role)",
    **{
        old: f"the controller's timeouts are one setting: RALF_TIMEOUTS={key}=VALUE (KEY=VALUE,...; unnamed keys keep their defaults)"
        for old, key in _TIMEOUTS.items()
    },
    **{
        f"smoothing_{key}": f"the smoothing is one setting: RALF_SMOOTHING={key}=VALUE (KEY=VALUE,...; unnamed keys keep their defaults)"
        for key in Smoothing.model_fields
    },
    **{
        old: "in peer mode a node knows the others by their certificates now: set RALF_ZENOH_TLS_CA, RALF_ZENOH_TLS_CERTIFICATE and "
        "RALF_ZENOH_TLS_KEY (ralf-hil up does, and writes a tool's into the run's tool.env)"
        for old in ("zenoh_id", "zenoh_node_ids")
    },
    "search_min_hz": "the peak search's band is one setting: RALF_SEARCH_BAND_HZ=LOW,HIGH",
    "search_max_hz": "the peak search's band is one setting: RALF_SEARCH_BAND_HZ=LOW,HIGH",
}
"""Settings no program reads any more, each with what replaces it (a retired name is refused, never ignored)."""


_FOLDED: dict[str, tuple[str, str]] = {
    **{f"policy_{key}": ("policies", key) for key in Policies.model_fields},
    **{f"oatf_{key}": ("oatf", key) for key in OatfTuning.model_fields},
    **{f"dither_{key}": ("dither", key) for key in DitherTuning.model_fields},
    "rt_priority": ("realtime", "priority"),
    "cpu_affinity": ("realtime", "cpus"),
    "rt_cpu_latency_us": ("realtime", "cpu_latency_us"),
    "can_multicast_ttl": ("can_udp", "ttl"),
    "can_own_frame_filter": ("can_udp", "own_frame_filter"),
    **{old: ("timeouts", key) for old, key in _TIMEOUTS.items()},
    **{f"smoothing_{key}": ("smoothing", key) for key in Smoothing.model_fields},
}
"""Retired names that became one key of a structured setting."""


def upgrade_recorded(values: dict[str, Any]) -> dict[str, Any]:
    """Settings as an older recording stored them, in today's names: a retired
    name that became a key of a structured setting moves into it, the search
    edges become ``search_band_hz``; the retired fault injections are dropped
    (a recording's faults are in its own metadata)."""
    out = {k: v for k, v in values.items() if not retired(k)}
    for name, value in values.items():
        if name in _FOLDED and value is not None:
            group, key = _FOLDED[name]
            keys = out.setdefault(group, {})
            if isinstance(keys, dict):  # (a recording has either the old names or the group)
                keys[key] = value
    if "search_band_hz" not in values and ("search_min_hz" in values or "search_max_hz" in values):
        default = DspSettings.model_fields["search_band_hz"].default
        out["search_band_hz"] = (values.get("search_min_hz", default[0]), values.get("search_max_hz", default[1]))
    return out


def retired(name: str) -> str | None:
    """Why the setting ``name`` (``RALF_NAME`` or ``name``) is refused, when it is a retired one."""
    return RETIRED.get(name.strip().lower().removeprefix("ralf_"))


def unknown_variables(environ: dict[str, str] | None = None) -> list[str]:
    """``RALF_*`` variables of ``environ`` that no program reads, each with
    the closest valid name: a misspelt setting is an error, never ignored.
    (Checked against every program, since ``ralf-hil up`` and compose give one
    environment to all three services.)"""
    env = os.environ if environ is None else environ
    known = sorted(known_variables())
    problems = []
    for name in sorted(env):
        upper = name.upper()
        if not upper.startswith("RALF_") or upper in known:
            continue
        if retired(upper):
            problems.append(f"  {name}: {retired(upper)}")
            continue
        problems.append(f"  {unknown_setting(upper, ANY, variable)}")
    return problems


def load_settings(model: type[CommonSettings], overrides: dict[str, Any] | None = None) -> Any:
    """Read settings from the environment plus ``overrides``; a bad value
    or an unknown ``RALF_*`` variable raises :class:`ConfigError` naming it."""
    unknown = unknown_variables()
    if unknown:
        raise ConfigError("invalid configuration:\n" + "\n".join(unknown))
    gone = [f"  {name}: {retired(name)}" for name in overrides or {} if retired(name)]
    if gone:
        raise ConfigError("invalid configuration:\n" + "\n".join(gone))
    try:
        return model(**(overrides or {}))
    except ValidationError as exc:
        lines = [f"  {_where(model, err['loc'])}: {err['msg']}" for err in exc.errors()]
        raise ConfigError("invalid configuration:\n" + "\n".join(lines)) from None
    except SettingsError as exc:
        # pydantic-settings fails before validation when a complex value
        # (e.g. the tuple oatf_band_hz) is not JSON.
        match = re.search(r'field "(\w+)"', str(exc))
        name = f"RALF_{match.group(1).upper()}" if match else model.__name__
        raise ConfigError(f"invalid configuration:\n  {name}: cannot parse the value (expected JSON, e.g. [1.0, 20.0]): {exc}") from None


def _where(model: type[CommonSettings], loc: tuple[Any, ...]) -> str:
    """The variable an error location refers to: ``RALF_FIELD``, with any
    item index as a suffix (``RALF_OATF_BAND_HZ[1]``), never a made-up name."""
    if not loc:
        return model.__name__
    return f"RALF_{str(loc[0]).upper()}" + "".join(f"[{part}]" for part in loc[1:])


def describe(model: type[CommonSettings]) -> list[tuple[str, str, str]]:
    """(environment variable, default, description) for every field."""
    rows = []
    for name, field in model.model_fields.items():
        default = field.default if field.default is not None else "-"
        rows.append((f"RALF_{name.upper()}", str(default), field.description or ""))
    return rows
