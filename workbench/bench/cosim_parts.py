"""Where a co-simulated tick goes: :func:`workbench.cosim.run_cosim`'s pieces, built
the same way, with the calls the controller service makes into each part
timed by wrappers (no profiler: a profiler's per-call cost would distort a
tick made of many small calls).

Parts: the plant node (``exchange`` and ``poll_frames``, through the wire), the
wire's own work, the controller's :class:`~controller.plant_link.PlantLink`
(frame encode/decode, dispatch; the node's time subtracted), the control law
(``law.tick_compiled``, or ``law.step_row`` where the compiled law is off: engineering, trajectory, OATF, PI, D/A), the
DSP port and core, the DSP link, the run record, and what is left: the
controller service's own per-tick work (``controller/service.py``). The
wrappers cost ~0.3 µs per call; the parts are inclusive wall times, the
service's share the rest of the run's wall time.

``ralf-hil measure cosim-parts [SECONDS]`` prints the table.

The plant side alone (:func:`plant_side`, ``ralf-hil measure cosim-parts
--plant [SECONDS]``): the wire calls of one co-simulation (each ``send`` with
its frame, each ``recv`` with its timeout, and the simulated time of each)
are captured, then replayed into a fresh plant (the same node, application
and wire, so the plant takes the same path through the same states) in a
loop with nothing else in it; CPU time per tick, the best of several rounds.
The run is deterministic, so what changes between two builds is the code.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

NODE = "plant node (exchange + poll_frames)"
WIRE = "DirectCanWire own"
LINK = "PlantLink own (RPDO encode, TPDO decode, dispatch)"
SERVICE = "ControllerService own (controller/service.py)"
LAW = "control law (engineering, trajectory, OATF, PI, D/A)"


def _wrap(obj: Any, name: str, key: str, acc: defaultdict[str, float]) -> None:
    fn: Callable[..., Any] = getattr(obj, name)
    clock = time.perf_counter

    def timed(*args: Any, **kwargs: Any) -> Any:
        t0 = clock()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[key] += clock() - t0

    setattr(obj, name, timed)


def cosim_parts(sim_s: float = 20.0, controller: dict[str, Any] | None = None) -> dict[str, Any]:
    """One co-simulation of ``sim_s`` simulated seconds (adaptive OATF unless
    ``controller`` says otherwise), timed by part; µs per tick and share."""
    from controller.plant_link import PlantLink
    from controller.service import ControllerService
    from dsp_service.core import DspCore
    from plant_emulator.node import CanopenNode
    from plant_emulator.service import PlantApplication, node_config
    from service_kit.clock import SimulatedScheduler
    from workbench.cosim import DirectCanWire, DirectDspPort, settings_for

    cs, ps, ds = settings_for({"oatf_mode": "adaptive", **(controller or {}), "duration_s": sim_s})
    scheduler = SimulatedScheduler()
    app = PlantApplication(ps, clock=scheduler.now)
    node = CanopenNode(app, node_config(ps))
    wire = DirectCanWire(node, scheduler)
    port = DirectDspPort(DspCore(ds))
    acc: defaultdict[str, float] = defaultdict(float)
    for name in ("handle", "exchange", "poll_frames"):  # the wire's entries, and handle (poll runs poll_frames)
        _wrap(node, name, "node", acc)
    for name in ("send", "send_frame", "recv"):  # before the link is built: it keeps the wire's send_frame
        _wrap(wire, name, "wire", acc)
    link = PlantLink(wire, cs.node_id, clock=scheduler.now)  # type: ignore[arg-type]
    ctrl = ControllerService(cs, None, link, port=port, scheduler=scheduler, keep_record=True)  # type: ignore[arg-type,unused-ignore]
    for name in ("send_outputs", "send_output_codes", "send_sync", "wait_tpdo", "poll", "heartbeat_age", "take_conflicts"):
        _wrap(link, name, "link", acc)
    for name in ("step_row", "tick_compiled"):  # the Python per-tick form, or the compiled call (controller/fast_tick.py)
        _wrap(ctrl.law, name, LAW, acc)
    for name in ("send_batch", "send_config", "download_tf", "send_status"):
        _wrap(port, name, "DSP port and core (batch codec, identification)", acc)
    for name in ("add_sample", "take_batch", "check_deadline"):
        _wrap(ctrl.link, name, "DspLink", acc)
    _wrap(ctrl.record, "append_row", "run record append", acc)
    started, cpu = time.perf_counter(), time.process_time()
    try:
        result = ctrl.run(scheduler.stop)
    finally:
        ctrl.close()
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    ticks = max(result.ticks, 1)
    parts = {NODE: acc.pop("node", 0.0), WIRE: acc.pop("wire"), LINK: acc.pop("link")}
    parts[WIRE] -= parts[NODE]
    parts[LINK] -= parts[WIRE] + parts[NODE]
    parts.update(acc)
    parts[SERVICE] = wall - sum(parts.values())
    return {
        "ticks": result.ticks,
        "wall_us_per_tick": wall / ticks * 1e6,
        "cpu_us_per_tick": cpu / ticks * 1e6,
        "parts_us_per_tick": {k: v / ticks * 1e6 for k, v in sorted(parts.items(), key=lambda kv: -kv[1])},
        "parts_share": {k: v / wall for k, v in parts.items()},
    }


def _plant(sim_s: float) -> tuple[Any, Any, Any, Any, Any, Any]:
    from plant_emulator.node import CanopenNode
    from plant_emulator.service import PlantApplication, node_config
    from service_kit.clock import SimulatedScheduler
    from workbench.cosim import DirectCanWire, settings_for

    cs, ps, ds = settings_for({"oatf_mode": "adaptive", "duration_s": sim_s})
    scheduler = SimulatedScheduler()
    app = PlantApplication(ps, clock=scheduler.now)
    node = CanopenNode(app, node_config(ps))
    return cs, ds, scheduler, app, node, DirectCanWire(node, scheduler)


def capture_wire_calls(sim_s: float) -> tuple[list[tuple[bool, float, Any]], int]:
    """One co-simulation of ``sim_s`` s: every call the controller makes on the
    CAN wire, as (is_recv, simulated time, frame sent, ``(cob_id, data)`` given
    to ``send_frame``, or recv timeout); and the ticks."""
    from controller.plant_link import PlantLink
    from controller.service import ControllerService
    from dsp_service.core import DspCore
    from workbench.cosim import DirectDspPort

    cs, ds, scheduler, _app, _node, wire = _plant(sim_s)
    calls: list[tuple[bool, float, Any]] = []
    send, send_frame, recv = wire.send, wire.send_frame, wire.recv
    now = scheduler.now

    def sending(msg: Any, timeout: float | None = None) -> None:
        calls.append((False, now(), msg))
        send(msg, timeout)

    def sending_frame(arbitration_id: int, data: bytes) -> None:
        calls.append((False, now(), (arbitration_id, data)))
        send_frame(arbitration_id, data)

    def receiving(timeout: float | None = None) -> Any:
        calls.append((True, now(), timeout))
        return recv(timeout)

    wire.send, wire.send_frame, wire.recv = sending, sending_frame, receiving
    link = PlantLink(wire, cs.node_id, clock=now)
    ctrl = ControllerService(cs, None, link, port=DirectDspPort(DspCore(ds)), scheduler=scheduler, keep_record=True)  # type: ignore[arg-type,unused-ignore]
    try:
        result = ctrl.run(scheduler.stop)
    finally:
        ctrl.close()
    return calls, result.ticks


def plant_side(sim_s: float = 10.0, rounds: int = 5) -> dict[str, Any]:
    """The plant side of a co-simulated tick (node, application, arm, wire),
    replayed alone: CPU and wall µs per tick of each round, and the best."""
    calls, ticks = capture_wire_calls(sim_s)
    cpu_us: list[float] = []
    wall_us: list[float] = []
    for _ in range(rounds):
        _cs, _ds, scheduler, _app, _node, wire = _plant(sim_s)
        send, send_frame, recv, at = wire.send, wire.send_frame, wire.recv, scheduler.advance_to
        started, cpu = time.perf_counter(), time.process_time()
        for is_recv, t, arg in calls:
            at(t)
            if is_recv:
                recv(arg)
            elif type(arg) is tuple:
                send_frame(*arg)
            else:
                send(arg)
        cpu_us.append((time.process_time() - cpu) / ticks * 1e6)
        wall_us.append((time.perf_counter() - started) / ticks * 1e6)
    return {"ticks": ticks, "calls": len(calls), "cpu_us_per_tick": cpu_us, "wall_us_per_tick": wall_us, "best_cpu_us": min(cpu_us)}


CHILD = """
import cProfile, json, pstats, sys, time
from workbench.bench.cosim_parts import cosim_parts
from workbench.cosim import run_cosim
sim_s = float(sys.argv[1])
cosim_parts(1.0)
repeats = [cosim_parts(sim_s) for _ in range(3)]
out = min(repeats, key=lambda r: r["cpu_us_per_tick"])
out["parts_us_per_tick"] = {k: min(r["parts_us_per_tick"].get(k, 0.0) for r in repeats) for k in out["parts_us_per_tick"]}
counts = []
for seconds in (2.0, 12.0):
    profile = cProfile.Profile()
    profile.enable()
    run = run_cosim(controller={"oatf_mode": "adaptive", "duration_s": seconds})
    profile.disable()
    stats = pstats.Stats(profile)
    counts.append((stats.total_calls, run.result.ticks, {k: (v[1], v[2]) for k, v in stats.stats.items()}))
ticks = counts[1][1] - counts[0][1]
out["calls_per_tick"] = (counts[1][0] - counts[0][0]) / ticks
short, long = counts[0][2], counts[1][2]
per = {k: ((nc - short.get(k, (0, 0.0))[0]) / ticks, (tt - short.get(k, (0, 0.0))[1]) / ticks * 1e6) for k, (nc, tt) in long.items()}
rows = sorted(per.items(), key=lambda kv: -kv[1][1])[:20]
out["profile"] = [[f"{f.rsplit('/', 2)[-2]}/{f.rsplit('/', 1)[-1]}:{line} {name}" if "/" in f else name, nc, tt] for (f, line, name), (nc, tt) in rows]
print("RESULT " + json.dumps(out))
"""
"""What each tree's child process runs: one warm-up, the parts three times (the run of least CPU time,
each part's least time: what the host's other load added least), and the Python calls per tick and
the profile per function (cProfile of a 12 s run less a 2 s run's, over the ticks between: the start-up cancels out)."""


def _tree_parts(tree: Path, sim_s: float) -> dict[str, Any]:
    """:func:`cosim_parts` of the sources in ``tree`` (their ``workbench`` package first on the path), in a child process."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, "-c", CHILD, str(sim_s)], cwd=tree, env=env, capture_output=True, text=True, timeout=600, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"cosim parts in {tree} failed (exit {done.returncode}): {done.stderr.strip().splitlines()[-1:] or 'no output'}")
    result: dict[str, Any] = json.loads(lines[-1][len("RESULT ") :])
    return result


def compare(before: Path, after: Path, rounds: int = 3, sim_s: float = 20.0) -> dict[str, Any]:
    """The parts of two source trees, alternating child processes round by
    round (before, after, before, ...) so both see the same host; per tree
    the median of the rounds, and the machine and its load around them."""
    from workbench.hostinfo import host_info

    load_before = os.getloadavg()
    runs: dict[str, list[dict[str, Any]]] = {"before": [], "after": []}
    for _ in range(max(1, rounds)):
        for name, tree in (("before", before), ("after", after)):
            runs[name].append(_tree_parts(tree, sim_s))
    return {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": host_info(),
        "load_before": load_before,
        "load_after": os.getloadavg(),
        "sim_s": sim_s,
        "rounds": rounds,
        "trees": {"before": str(before), "after": str(after)},
        "before": _median_parts(runs["before"]),
        "after": _median_parts(runs["after"]),
        "after_profile": runs["after"][-1].get("profile", []),
    }


def _median_parts(runs: list[dict[str, Any]]) -> dict[str, Any]:
    def med(values: list[float]) -> float:
        return float(statistics.median(values))

    names = list(dict.fromkeys(name for run in runs for name in run["parts_us_per_tick"]))
    return {
        "ticks": runs[0]["ticks"],
        "wall_us_per_tick": med([r["wall_us_per_tick"] for r in runs]),
        "cpu_us_per_tick": med([r["cpu_us_per_tick"] for r in runs]),
        "calls_per_tick": med([r["calls_per_tick"] for r in runs]),
        "parts_us_per_tick": {n: med([r["parts_us_per_tick"].get(n, 0.0) for r in runs]) for n in names},
        "rounds_wall_us_per_tick": [r["wall_us_per_tick"] for r in runs],
    }


def markdown(result: dict[str, Any], command: str) -> str:
    """The comparison as the generated page ``docs/results/cosim-parts.md``."""
    before, after = result["before"], result["after"]
    machine = result["machine"]
    cpu = machine.get("cpu_model") or "?"
    lines = [
        "# Where a co-simulated tick goes: before and after",
        "",
        f"Generated by `{command}` on {result['date']}: {cpu}, {machine.get('cpus') or os.cpu_count()} cores,",
        f"load average {result['load_before'][0]:.2f} before and {result['load_after'][0]:.2f} after. Each tree's parts",
        f"(`ralf-hil measure cosim-parts`, {result['sim_s']:g} s simulated, adaptive OATF; in each process the least of three",
        f"runs) in its own process, the two trees alternating for {result['rounds']} rounds; the median of the rounds. On a shared",
        "host the CPU time is the steadier figure. Python function calls per tick: cProfile's count of a 12 s co-simulation",
        "less a 2 s one's, per tick between (start-up cancels; the host's load does not move it). Before: the sources as",
        "they were; after: with the changes",
        "described in [timing.md](../timing.md#where-a-co-simulated-tick-goes).",
        "",
        "| part | before µs per tick | after µs per tick | after / before |",
        "| --- | ---: | ---: | ---: |",
    ]
    for name in after["parts_us_per_tick"]:
        b, a = before["parts_us_per_tick"].get(name, 0.0), after["parts_us_per_tick"][name]
        lines.append(f"| {name} | {b:.1f} | {a:.1f} | {a / b if b else float('nan'):.2f} |")
    for key, label in (("wall_us_per_tick", "wall time per tick (instrumented)"), ("cpu_us_per_tick", "CPU time per tick (instrumented)")):
        lines.append(f"| **{label}** | {before[key]:.1f} | {after[key]:.1f} | {after[key] / before[key]:.2f} |")
    lines.append(
        f"| Python function calls per tick | {before['calls_per_tick']:.1f} | {after['calls_per_tick']:.1f} | {after['calls_per_tick'] / before['calls_per_tick']:.2f} |"
    )
    profile = result.get("after_profile") or []
    if profile:
        lines += [
            "",
            "## What holds the rest: the after tree's profile",
            "",
            "cProfile of the co-simulations above (after; 12 s less 2 s), the 20 functions of most own time: calls and own time per tick.",
            "The profiler's cost per call inflates every row alike; the shares, not the µs, are the figure.",
            "",
            "| function | calls per tick | own µs per tick (profiled) |",
            "| --- | ---: | ---: |",
        ]
        lines += [f"| `{name}` | {calls:.1f} | {own:.2f} |" for name, calls, own in profile]
    lines += [
        "",
        "Wall time per tick of each round: before "
        + ", ".join(f"{v:.1f}" for v in before["rounds_wall_us_per_tick"])
        + "; after "
        + ", ".join(f"{v:.1f}" for v in after["rounds_wall_us_per_tick"])
        + " µs.",
        "",
    ]
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    if args.compare is not None:
        before, here = Path(args.compare), Path(__file__).resolve().parents[2]
        if not (before / "workbench" / "bench" / "cosim_parts.py").is_file():
            print(f"ralf-hil measure cosim-parts: {before} holds no ralf-hil source tree (workbench/bench/cosim_parts.py)", file=sys.stderr)
            return 2
        result = compare(before, here, args.rounds, args.seconds if args.seconds is not None else 20.0)
        text = markdown(result, f"ralf-hil measure cosim-parts --compare BEFORE_TREE --rounds {args.rounds} --write {args.write or '-'}")
        if args.write:
            Path(args.write).write_text(text, encoding="utf-8")
        print(text)
        return 0
    if args.plant:
        out = plant_side(args.seconds if args.seconds is not None else 10.0)
        rounds = ", ".join(f"{c:.1f}" for c in out["cpu_us_per_tick"])
        print(f"plant side (node + application + arm + wire), {out['ticks']} ticks, {out['calls']} wire calls replayed")
        print(f"  CPU µs per tick: best {out['best_cpu_us']:.1f} (rounds {rounds}); wall best {min(out['wall_us_per_tick']):.1f}")
        return 0
    sim_s = args.seconds if args.seconds is not None else 20.0
    cosim_parts(1.0)  # warm-up: imports, compiled kernels
    out = cosim_parts(sim_s)
    print(f"{out['ticks']} ticks: {out['wall_us_per_tick']:.0f} µs wall, {out['cpu_us_per_tick']:.0f} µs CPU per tick (instrumented)")
    for name, us in out["parts_us_per_tick"].items():
        print(f"  {us:7.1f} µs  {out['parts_share'][name] * 100:5.1f} %  {name}")
    return 0


if __name__ == "__main__":
    from service_kit.moved import exit_moved

    exit_moved("python -m workbench.bench.cosim_parts", "ralf-hil measure cosim-parts")
