"""The co-simulation's floor: the models alone, fed what they were fed in a run.

One co-simulation is run with its three models' calls recorded (the plant
model's ``advance``, valve and sample calls from its construction on, the
control law's ``tick_compiled`` and the calls that change it, the DSP core's
``admit``/``process``/``release`` and configuration); the recorded calls, with
their arguments, are then replayed into a fresh instance of each model in a
tight loop with nothing else in it. The run is deterministic, so the replay
takes each model through the states it went through in the run.

The floor of a co-simulated tick is the sum of the three models' replay time
per tick (the DSP's step amortized over the ticks of its batches); the
co-simulation's own wall time per tick over that sum is what the rig adds
(CAN codecs, the node, the service's bookkeeping, the record). Replays and
timed co-simulations alternate round by round, so both see the same host; the
best round of each is kept.

For an FMU plant, :func:`fmpy_inputs` gives the valve voltages the FMU
received, as FMPy's input table, so ``fmpy.simulate_fmu`` of the same FMU can
be timed on the same input (:mod:`workbench.bench.fmu_plant`).
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Recorded", "CallLog", "floor_report", "fmpy_floor", "fmpy_inputs", "record_run", "replay_dsp", "replay_law", "replay_plant"]

PLANT_CALLS = (
    "advance",
    "set_valve_voltages",
    "set_valve_values",
    "sample_codes",
    "sample_volts",
    "set_tip_forces",
    "attach_payload",
    "set_adc_bits",
    "reseed",
)
"""What the plant application calls on its model (:class:`plant_emulator.plant_model.PlantModel`)."""
LAW_CALLS = ("tick_compiled", "apply_interrupt", "set_degraded", "set_pi_gain")
"""What the controller service calls on its control law that changes it (:class:`controller.loop.ControlLaw`)."""
DSP_CALLS = ("admit", "process", "release", "apply_config", "snapshot")
"""What the co-simulation's DSP port calls on the DSP core (:class:`dsp_service.core.DspCore`)."""


class CallLog:
    """The calls made on some methods of one object, in order, with their
    arguments; each call still goes to the method. A call a recorded method
    makes on another recorded method of the same object is not recorded (the
    replay makes it again through the outer call)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, tuple[Any, ...], dict[str, Any]]] = []
        self._depth = 0

    def wrap(self, obj: Any, names: Sequence[str]) -> Any:
        for name in names:
            method = getattr(obj, name, None)
            if callable(method):
                setattr(obj, name, self._recording(name, method))
        return obj

    def _recording(self, name: str, method: Any) -> Any:
        calls = self.calls

        def recorded(*args: Any, **kwargs: Any) -> Any:
            if self._depth == 0:
                calls.append((name, args, kwargs))
            self._depth += 1
            try:
                return method(*args, **kwargs)
            finally:
                self._depth -= 1

        return recorded

    def count(self, name: str) -> int:
        return sum(1 for call in self.calls if call[0] == name)


@dataclass
class Recorded:
    """One co-simulation's model calls, and what building fresh models needs."""

    ticks: int
    settings: tuple[Any, Any, Any]
    """The controller's, the plant's and the DSP's settings of the run."""
    plant: CallLog = field(default_factory=CallLog)
    law: CallLog = field(default_factory=CallLog)
    dsp: CallLog = field(default_factory=CallLog)
    wall_time_s: float = float("nan")


@contextmanager
def _recording_plant(log: CallLog) -> Iterator[None]:
    """:func:`workbench.cosim.run_cosim` building its plant model with every call recorded."""
    import workbench.cosim as cosim

    build = cosim.build_plant_model

    def recorded_build(settings: Any) -> Any:
        return log.wrap(build(settings), PLANT_CALLS)

    cosim.build_plant_model = recorded_build
    try:
        yield
    finally:
        cosim.build_plant_model = build


def record_run(controller: dict[str, Any], plant: dict[str, Any] | None = None, dsp: dict[str, Any] | None = None) -> Recorded:
    """One co-simulation (:func:`workbench.cosim.run_cosim`) with its models' calls recorded."""
    from workbench.cosim import run_cosim, settings_for

    holder: dict[str, Any] = {}
    plant_log, law_log, dsp_log = CallLog(), CallLog(), CallLog()

    def on_start(ctrl: Any) -> None:
        law_log.wrap(ctrl.law, LAW_CALLS)
        dsp_log.wrap(ctrl.port.core, DSP_CALLS)
        holder["dsp_settings"] = ctrl.port.core.settings
        holder["controller_settings"] = ctrl.settings

    with _recording_plant(plant_log):
        run = run_cosim(controller=controller, plant=plant, dsp=dsp, on_start=on_start)
    if run.result.error:
        raise RuntimeError(f"the recorded co-simulation ended with {run.result.error}")
    _, ps, _ = settings_for(controller, plant, dsp)
    return Recorded(
        ticks=run.result.ticks,
        settings=(holder["controller_settings"], ps, holder["dsp_settings"]),
        plant=plant_log,
        law=law_log,
        dsp=dsp_log,
        wall_time_s=run.wall_time_s,
    )


def _timed(target: Any, calls: list[tuple[str, tuple[Any, ...], dict[str, Any]]]) -> float:
    bound = [(getattr(target, name), args, kwargs) for name, args, kwargs in calls]
    clock = time.perf_counter
    started = clock()
    for method, args, kwargs in bound:
        method(*args, **kwargs)
    return clock() - started


def replay_plant(rec: Recorded) -> float:
    """Seconds the plant model takes for the run's calls, alone (a fresh model of the same settings)."""
    from plant_emulator.plant_factory import build_plant_model

    model = build_plant_model(rec.settings[1])
    try:
        return _timed(model, rec.plant.calls)
    finally:
        model.close()


def replay_law(rec: Recorded) -> float:
    """Seconds the control law takes for the run's ticks and changes, alone (a fresh law of the same settings)."""
    from controller.config import build_trajectory, law_config
    from controller.loop import ControlLaw

    cs = rec.settings[0]
    return _timed(ControlLaw(law_config(cs), build_trajectory(cs)), rec.law.calls)


def replay_dsp(rec: Recorded) -> float:
    """Seconds the DSP core takes for the run's batches and changes, alone (a fresh core of the same settings).
    Each ``process`` gets the admission the fresh core's ``admit`` gave."""
    from dsp_service.bank_file import load_bank
    from dsp_service.core import DspCore

    core = DspCore(rec.settings[2])
    load_bank(core.identifier, rec.settings[2])
    admission: Any = None
    clock = time.perf_counter
    spent = 0.0
    for name, args, kwargs in rec.dsp.calls:
        method = getattr(core, name)
        started = clock()
        if name == "admit":
            admission = method(*args, **kwargs)
        elif name == "process":
            method(args[0], admission)
        else:
            method(*args, **kwargs)
        spent += clock() - started
    return spent


def floor_report(controller: dict[str, Any], rounds: int = 3, plant: dict[str, Any] | None = None, dsp: dict[str, Any] | None = None) -> dict[str, Any]:
    """The co-simulation's wall time per tick beside its models' own (replayed), alternating round by round.

    Returns µs per tick: ``cosim_us`` (best timed co-simulation, wall time
    including its start-up), ``plant_us``, ``law_us``, ``dsp_us`` (each model's
    best replay), ``models_us`` (their sum), and ``ratio`` = cosim / models;
    every round's figures under ``rounds``."""
    from workbench.cosim import run_cosim

    rec = record_run(controller, plant, dsp)
    ticks = rec.ticks
    if ticks <= 0 or not rec.plant.calls or not rec.law.calls:
        raise RuntimeError(f"the recorded co-simulation made {ticks} ticks, {len(rec.plant.calls)} plant and {len(rec.law.calls)} law calls")
    per: dict[str, list[float]] = {"cosim_us": [], "plant_us": [], "law_us": [], "dsp_us": []}
    for _ in range(max(1, rounds)):
        run = run_cosim(controller=controller, plant=plant, dsp=dsp)
        if run.result.ticks != ticks:
            raise RuntimeError(f"the timed co-simulation made {run.result.ticks} ticks, the recorded one {ticks}")
        per["cosim_us"].append(run.wall_time_s / ticks * 1e6)
        per["plant_us"].append(replay_plant(rec) / ticks * 1e6)
        per["law_us"].append(replay_law(rec) / ticks * 1e6)
        per["dsp_us"].append(replay_dsp(rec) / ticks * 1e6)
    best = {key: min(values) for key, values in per.items()}
    models = best["plant_us"] + best["law_us"] + best["dsp_us"]
    return {
        "ticks": ticks,
        **best,
        "models_us": models,
        "ratio": best["cosim_us"] / models,
        "rounds": per,
        "calls": {"plant": len(rec.plant.calls), "law": len(rec.law.calls), "dsp": len(rec.dsp.calls), "batches": rec.dsp.count("process")},
    }


def fmpy_inputs(rec: Recorded, names: Sequence[str] = ("u1", "u2")) -> tuple[np.ndarray, float]:
    """The valve voltages the plant model received in ``rec``, as an FMPy input
    table (``time`` and the two inputs ``names``; each voltage held from the model time it
    was set at, a step at every change), and the model time the run reached."""
    t = 0.0
    rows: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)]
    for name, args, _ in rec.plant.calls:
        if name == "advance":
            t += float(args[0])
        elif name in ("set_valve_values", "set_valve_voltages"):
            u1, u2 = (float(args[0]), float(args[1])) if name == "set_valve_values" else (float(args[0][0]), float(args[0][1]))
            if (u1, u2) != rows[-1][1:]:
                rows.append((t, *rows[-1][1:]))  # held up to t, then the step
                rows.append((t, u1, u2))
    table = np.array(rows, dtype=[("time", np.float64), (names[0], np.float64), (names[1], np.float64)])
    return table, t


def fmpy_floor(fmu: Path, mapping_path: Path, controller: dict[str, Any], rounds: int = 2) -> dict[str, Any]:
    """The co-simulation with the FMU plant against ``fmpy.simulate_fmu`` of the
    same FMU over the same time with the same valve inputs (the run's, as an
    input table), alternating round by round; the best wall time of each (s),
    and ``ratio`` = co-simulation / FMPy. FMPy's time includes its own
    extraction and instantiation of the FMU, as the co-simulation's includes
    its start-up."""
    import fmpy

    from plant_emulator.fmu.mapping import load_mapping
    from workbench.cosim import run_cosim

    plant = {"model": f"fmu:{fmu}", "fmu_mapping": str(mapping_path)}
    rec = record_run(controller, plant)
    mapping = load_mapping(mapping_path)
    table, stop = fmpy_inputs(rec, mapping.inputs)
    start: dict[str, Any] = {**mapping.parameters, **mapping.start}
    if mapping.seed_variable:
        start[mapping.seed_variable] = rec.settings[1].seed
    outputs = [ch.variable for ch in mapping.outputs]
    period = rec.settings[0].sample_period_s
    times: dict[str, list[float]] = {"cosim_s": [], "fmpy_s": []}
    for _ in range(max(1, rounds)):
        run = run_cosim(controller=controller, plant=plant)
        times["cosim_s"].append(run.wall_time_s)
        started = time.perf_counter()
        out = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", start_values=start, input=table, output=outputs, output_interval=period, stop_time=stop)
        times["fmpy_s"].append(time.perf_counter() - started)
        if len(out) < 2:
            raise RuntimeError("fmpy.simulate_fmu returned no output")
    best = {key: min(values) for key, values in times.items()}
    return {"ticks": rec.ticks, "sim_s": stop, **best, "ratio": best["cosim_s"] / best["fmpy_s"], "rounds": times, "input_rows": len(table)}
