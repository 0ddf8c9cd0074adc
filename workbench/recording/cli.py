"""``ralf-hil record``, ``replay``, ``plot``, ``doctor`` and ``export`` (MF4: :mod:`workbench.recording.mf4_cli`)."""

from __future__ import annotations

import argparse
import json
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

from rich.console import Console

console = Console(stderr=True)


def _parse_sets(items: list[str]) -> dict[str, Any]:
    from protocol.settings import DspSettings
    from workbench.recording.replay import identifier_fields

    out: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip().lower().removeprefix("ralf_").removeprefix("dsp.")
        if not sep or name not in identifier_fields():
            raise SystemExit(f"ralf-hil replay: --set {item!r}: expected NAME=VALUE with NAME one of {', '.join(identifier_fields())}")
        field = DspSettings.model_fields[name]
        try:
            out[name] = json.loads(value) if field.annotation is not str else value
        except json.JSONDecodeError:
            out[name] = value
    return out


def cmd_record(args: argparse.Namespace) -> int:
    """Record a rig whose services run on their own (``ralf-plant`` etc.)."""
    from protocol.errors import ConfigError
    from protocol.settings import CommonSettings, load_settings
    from service_kit.transport import open_zenoh
    from workbench.recording.recorder import Recorder
    from workbench.recording.tap import Tap, open_tap_bus, resolve_settings_here, run_metadata

    overrides: dict[str, Any] = {}
    if args.rig_id:
        overrides["rig_id"] = args.rig_id
    if args.connect:
        overrides["zenoh_connect"] = args.connect
    if args.can_port:
        overrides["can_port"] = args.can_port
    overrides["zenoh_listen"] = ""  # a tap listens on nothing: it connects to the services
    try:
        settings = load_settings(CommonSettings, overrides)
    except ConfigError as exc:
        console.print(f"[red]{exc}[/red]")
        return 2
    env = {k: v for k, v in os.environ.items() if k.startswith("RALF_")}
    resolved = resolve_settings_here({name: env for name in ("dsp", "plant", "controller")})  # no threads yet
    recorder = Recorder(args.path, sample_rate_hz=settings.sample_rate_hz, node_id=settings.node_id, can_log=args.can_log)
    for name, values in run_metadata(settings.rig_id, resolved, settings_source="the recorder's RALF_* environment", can_port=settings.can_port).items():
        recorder.add_metadata(name, values)
    session = open_zenoh(settings)
    bus = open_tap_bus(settings)
    tap = Tap(recorder, settings.rig_id, session=session, bus=bus)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print(
        f"recording rig {settings.rig_id!r} (zenoh {settings.zenoh_connect or 'peers'}, CAN {settings.can_interface}:{settings.can_channel} port {settings.can_port}) into {args.path}; Ctrl-C stops",
        flush=True,
    )
    started = time.monotonic()
    try:
        while not stop.is_set() and (args.duration is None or time.monotonic() - started < args.duration):
            stop.wait(0.2)
    finally:
        tap.close()
        bus.shutdown()
        stats = recorder.close()
        session.close()
    print(json.dumps({"path": args.path, **stats.as_dict()}))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from workbench.recording.reader import Recording
    from workbench.recording.replay import compare, export_can_log, play_can, recorded_can_messages, report_markdown

    needs_can = bool(args.can or args.export_can)
    rec = Recording.load(args.path, only=None if needs_can else ("dsp/config", "dsp/batch", "dsp/interrupt", "plant/truth"))
    if rec.cut:
        console.print(f"{args.path}: {rec.cut}; replaying what it holds")
    did = False
    if args.export_can:
        n = export_can_log(rec, args.export_can)
        console.print(f"{n} CAN frames written to {args.export_can}")
        did = True
    if args.can:
        import can

        kwargs: dict[str, Any] = {"interface": args.interface, "channel": args.channel}
        if args.interface == "udp_multicast":
            kwargs["port"] = args.port or int(rec.metadata.get("ralf.run", {}).get("can_port", 43113))
        messages = recorded_can_messages(rec, direction=args.direction)
        with can.Bus(**kwargs) as bus:
            where = f"{args.interface}:{args.channel}" + (f" port {kwargs['port']}" if "port" in kwargs else "")
            console.print(f"playing {len(messages)} CAN frames onto {where}; Ctrl-C stops", highlight=False)
            sent = play_can(
                messages, bus, ignore_timestamps=args.ignore_timestamps, gap_s=args.gap, skip_s=args.skip, limit=args.limit, max_wall_s=args.max_wall
            )
        console.print(f"{sent} of {len(messages)} CAN frames replayed on {args.interface}:{args.channel}")
        if not messages:
            console.print(f"[red]{args.path}: no CAN frames to replay{' in direction ' + args.direction if args.direction else ''}[/red]")
            return 1
        did = True
    if args.identify or not did:
        overrides = _parse_sets(args.set)
        comparison, replayed = compare(rec, overrides)
        text = report_markdown(comparison)
        print(text)
        if args.out:
            out = Path(args.out)
            out.mkdir(parents=True, exist_ok=True)
            (out / "replay.md").write_text(text)
            (out / "replay.json").write_text(json.dumps(comparison.as_dict(), indent=2))
            _plot_tracks(rec, comparison, out / "replay_tracks.png")
            console.print(f"report: {out / 'replay.md'}")
        if comparison.too_few:
            console.print(f"[red]{args.path}: nothing to compare ({comparison.compared} batches; a replay needs at least one recorded interrupt)[/red]")
            return 1
        if args.require_identical and not comparison.identical:
            console.print(f"[red]replay differs from the recorded run in batches {comparison.mismatched[:10]}[/red]")
            return 1
    return 0


def _plot_tracks(rec: Any, c: Any, path: Path) -> None:
    from workbench.experiments.report import new_figure

    fig = new_figure(8, 4.5)
    ax = fig.add_subplot()
    truth = rec.truth()
    if truth:
        ax.plot(truth["sim_time_s"], truth["modal_frequencies_hz"][:, 0], color="k", lw=1.0, label="true f1")
    for name, track, marker, colour in (("recorded", c.recorded, ".", "tab:blue"), ("replayed", c.replayed, "x", "tab:orange")):
        label = f"{name}: {track.median_abs_error_pct:.1f} % median error, lag {track.lag_s:.2f} s"
        ax.plot(track.times_s, track.f1_hz, marker, ms=3, color=colour, label=label)
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("first mode (Hz)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Identified first mode: recorded vs replayed " + (", ".join(f"{k}={v}" for k, v in c.overrides.items()) or "(same settings)"))
    fig.savefig(path)


def cmd_plot(args: argparse.Namespace) -> int:
    from workbench.recording.plot import plot_all

    out = Path(args.out) if args.out else Path(args.path).with_suffix("")
    paths = plot_all(args.path, out)
    for p in paths:
        print(p)
    if args.foxglove_layout:
        from workbench.recording.foxglove import write_layout
        from workbench.recording.reader import Recording

        print(write_layout(args.foxglove_layout, Recording.load(args.path).rig_id))
    return 0


def cmd_doctor(args: argparse.Namespace) -> int:
    from workbench.recording.doctor import examine

    status = 0
    for path in args.paths:
        found = examine(path)
        problems = found.problems
        print(f"{path}: {'ok' if not problems else f'{len(problems)} problem(s)'} ({found.line()})")
        for line in problems[: args.max_problems]:
            print(f"  {line}")
        status = status or (1 if problems else 0)
    return status


def register(subparsers: Any) -> None:
    """Add ``record``, ``replay``, ``plot``, ``doctor`` and ``export`` to ``ralf-hil``."""
    from workbench.recording import mf4_cli

    p = subparsers.add_parser(
        "record",
        help="record a rig whose services run on their own into an MCAP file",
        description="A tap on ralf/<rig>/** and the rig's CAN bus, written to RUN.mcap until Ctrl-C or --duration. "
        "zenoh and CAN settings come from RALF_* (as for the services) and the options below; "
        "the services' settings in the metadata are those the same RALF_* environment gives. "
        "For `ralf-hil up` use `up --record RUN.mcap` instead.",
    )
    p.add_argument("path", metavar="RUN.mcap")
    p.add_argument("--rig-id", default=None)
    p.add_argument("--connect", default=None, metavar="ENDPOINT[,ENDPOINT...]", help="zenoh endpoints of the services (default: RALF_ZENOH_CONNECT)")
    p.add_argument("--can-port", type=int, default=None, help="udp_multicast port (default: RALF_CAN_PORT)")
    p.add_argument("--can-log", default=None, metavar="BUS.blf", help="also write the CAN side in python-can's format for this suffix (.blf, .asc, .log)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many wall-clock seconds")
    p.set_defaults(func=cmd_record)

    p = subparsers.add_parser(
        "replay",
        help="re-run the DSP identification over a recording (other settings, comparison), or replay its CAN side",
        description="Default: re-identify the recorded batches at the recorded DSP settings plus --set overrides and compare "
        "with the on-line run and the recorded truth. --can plays the CAN frames onto a bus; --export-can writes them as .blf/.asc.",
    )
    p.add_argument("path", metavar="RUN.mcap")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="identifier setting (fft_width, alpha, averaging, solver, smoothing, ...)")
    p.add_argument("--out", default=None, metavar="DIR", help="write replay.md, replay.json and replay_tracks.png here")
    p.add_argument("--identify", action="store_true", help="re-identify even with --can/--export-can")
    p.add_argument("--require-identical", action="store_true", help="exit 1 unless the replay equals the recorded run bit for bit")
    p.add_argument("--export-can", default=None, metavar="BUS.blf", help="write the recorded CAN frames in python-can's format for this suffix")
    p.add_argument("--can", action="store_true", help="play the recorded CAN frames onto a bus (python-can player semantics)")
    p.add_argument("--interface", default="udp_multicast", help="python-can interface for --can (default udp_multicast)")
    p.add_argument("--channel", default="239.74.163.2", help="python-can channel for --can")
    p.add_argument("--port", type=int, default=None, help="udp_multicast port for --can (default: the recorded rig's)")
    p.add_argument("--direction", choices=("controller->plant", "plant->controller"), default=None, help="only the frames of one direction")
    p.add_argument("--ignore-timestamps", action="store_true", help="send --gap apart instead of at the recorded gaps")
    p.add_argument("--gap", type=float, default=0.0001, help="seconds between frames with --ignore-timestamps (default 0.0001)")
    p.add_argument("--skip", type=float, default=60.0, help="shorten recorded pauses longer than this (s)")
    p.add_argument("--limit", type=int, default=None, help="stop after this many frames")
    p.add_argument("--max-wall", type=float, default=None, help="stop after this many wall-clock seconds")
    p.set_defaults(func=cmd_replay)

    p = subparsers.add_parser("plot", help="PNG figures of a recording (deflections, joints, modes, TF spectrogram, timing)")
    p.add_argument("path", metavar="RUN.mcap")
    p.add_argument("--out", default=None, metavar="DIR", help="output directory (default: RUN/ beside the file)")
    p.add_argument("--foxglove-layout", default=None, metavar="LAYOUT.json", help="also write a Foxglove layout for the recording's rig id")
    p.set_defaults(func=cmd_plot)

    p = subparsers.add_parser("doctor", help="check a recording's structure (CRCs, declarations, chunk ranges, statistics); exit 1 on a problem")
    p.add_argument("paths", nargs="+", metavar="RUN.mcap")
    p.add_argument("--max-problems", type=int, default=20, help="problems printed per file (default 20)")
    p.set_defaults(func=cmd_doctor)

    mf4_cli.register(subparsers)
