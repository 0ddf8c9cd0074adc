"""One FMI 2.0 or 3.0 co-simulation FMU, loaded with FMPy and checked
against its mapping before anything runs.

:func:`open_fmu` reads the model description, refuses what the rig cannot
run (a missing or corrupt file, FMI 1.0, a model-exchange-only FMU, a
mapping naming a variable the FMU lacks or with the wrong causality or
type) with :class:`FmuRefused`, one line naming the file and the variable,
then extracts, instantiates and initializes it. :func:`check_fmu` also
tries one step of the sample period on a throw-away instance, so a step
size the FMU refuses is found before the rig starts.

Per step the instance is driven through FMPy's FMI calls with value
reference and value arrays made once (``fmi2SetReal``/``fmi3SetFloat64``,
``fmi2DoStep``/``fmi3DoStep``, ``fmi2GetReal``/``fmi3GetFloat64``): a
status above warning comes back as a number, never as an exception out of
the step.
"""

from __future__ import annotations

import ctypes
import logging
import shutil
import zipfile
from collections import deque
from pathlib import Path
from typing import Any

from plant_emulator.fmu.mapping import FmuMapping, Scalar
from protocol.errors import ConfigError

__all__ = ["FmuInstance", "FmuRefused", "check_fmu", "open_fmu"]

log = logging.getLogger(__name__)

STATUS_OK = 0
STATUS_DISCARD = 2
STATUS_ERROR = 3
STATUS_FATAL = 4
STATUS_TERMINATED = 5
"""FMI status codes (FMI 2.0 and 3.0 share 0-4); 5 here: FMI 3.0's terminateSimulation."""

_STATUS_NAMES = {1: "warning", 2: "discard", 3: "error", 4: "fatal"}
MAX_LOGGED_MESSAGES = 50
"""An FMU's messages above OK written to the plant's log; later ones are only counted."""

_REALS = {2: ("Real",), 3: ("Float64",)}
_INTEGERS = {2: ("Integer", "Enumeration"), 3: ("Int32", "Int64", "Enumeration")}


class FmuRefused(ConfigError):
    """The FMU or its mapping cannot run on the rig (one line naming the file and the variable)."""


def _fmpy() -> Any:
    try:
        import fmpy
        import fmpy.fmi2
        import fmpy.fmi3
    except ImportError:
        raise FmuRefused("an FMU plant needs FMPy: pip install 'ralf-hil[fmu]'") from None
    return fmpy


class FmuInstance:
    """An instantiated, initialized co-simulation FMU and its mapped value references."""

    def __init__(self, path: Path, mapping: FmuMapping, description: Any, unzip_dir: str, seed: int) -> None:
        fmpy = _fmpy()
        self.path = path
        self.mapping = mapping
        self.description = description
        self.version = description.fmiMajorVersion
        self._unzip_dir = unzip_dir
        self._closed = False
        self._fatal = False
        """A call returned fmiFatal: FMI 2.0 and 3.0 allow no further call of the FMU."""
        self.messages: deque[str] = deque(maxlen=16)
        """The FMU's last warning and error log messages."""
        self.n_messages = 0
        """The FMU's warning and error messages so far (:attr:`messages` keeps the last ones)."""
        self.n_logged = 0
        """Of them, those written to the plant's log (at most :data:`MAX_LOGGED_MESSAGES`)."""
        self._step_mark = 0
        variables = {v.name: v for v in description.modelVariables}
        self.variables = variables
        cs = description.coSimulation
        cls = fmpy.fmi2.FMU2Slave if self.version == 2 else fmpy.fmi3.FMU3Slave
        kwargs = {"guid": description.guid, "unzipDirectory": unzip_dir, "modelIdentifier": cs.modelIdentifier, "instanceName": "plant"}
        try:
            self.fmu = cls(**kwargs)
        except Exception as exc:  # noqa: BLE001 - FMPy raises plain Exception for a missing or unloadable binary
            shutil.rmtree(unzip_dir, ignore_errors=True)
            raise FmuRefused(f"{path}: cannot load its binary ({_one_line(exc)})") from None
        self.fmu_initialized = False
        try:
            self._instantiate_and_initialize(seed)
        except FmuRefused:
            self.close()
            raise
        except Exception as exc:  # noqa: BLE001 - FMPy's FMICallException, or the FMU's own failure
            self.close()
            said = f": {self.last_message}" if self.messages else ""
            raise FmuRefused(f"{path}: initialization failed ({_one_line(exc)}{said})") from None
        self._build_io()

    # -- setup -------------------------------------------------------------------------------
    def _instantiate_and_initialize(self, seed: int) -> None:
        fmu = self.fmu
        # Logging on: an FMU may send nothing to the logger callback without it
        # (pythonfmu's FMI 2.0 wrapper drops even the exception behind a Fatal).
        if self.version == 2:
            fmu.instantiate(callbacks=self._fmi2_callbacks(), loggingOn=True)
            fmu.setupExperiment(startTime=0.0)
        else:
            fmu.instantiate(loggingOn=True, logMessage=self._log_fmi3)
        values: dict[str, Scalar] = {**self.mapping.parameters, **self.mapping.start}
        if self.mapping.seed_variable is not None:
            values[self.mapping.seed_variable] = int(seed)
        for name, value in values.items():
            self._set_scalar(name, value)
        if self.version == 2:
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
        else:
            fmu.enterInitializationMode(startTime=0.0)
            fmu.exitInitializationMode()
        self.fmu_initialized = True

    def _fmi2_callbacks(self) -> Any:
        """FMI 2.0 callbacks whose logger goes to this module's log (FMPy's
        varargs proxy formats the message), kept alive with the instance."""
        fmpy = _fmpy()
        from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
        from fmpy.logging import addLoggerProxy

        def logger(env: Any, instance: bytes, status: int, category: bytes, message: bytes) -> None:
            self._log(status, category, message)

        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        addLoggerProxy(ctypes.byref(callbacks))
        self._callbacks = callbacks
        return callbacks

    def _log_fmi3(self, env: Any, status: int, category: bytes, message: bytes) -> None:
        self._log(status, category, message)

    def _log(self, status: int, category: bytes | None, message: bytes | None) -> None:
        """An FMU's log message into the plant's log at its level (OK: debug;
        warning, discard: warning; error, fatal: error; the first
        :data:`MAX_LOGGED_MESSAGES` above OK, the rest counted), and the last
        few kept for the line that reports a refusal or a fault."""
        text = " ".join((message or b"").decode("utf-8", "replace").split())
        kind = (category or b"").decode("utf-8", "replace")
        where = f"FMU {self.path.name}" + (f" [{kind}]" if kind else "")
        if status < 1:
            log.debug("%s: %s", where, text)
            return
        self.messages.append(text)
        self.n_messages += 1
        if self.n_logged < MAX_LOGGED_MESSAGES:
            self.n_logged += 1
            last = " (further FMU messages counted, not logged)" if self.n_logged == MAX_LOGGED_MESSAGES else ""
            log.log(logging.ERROR if status >= STATUS_ERROR else logging.WARNING, "%s %s: %s%s", where, _STATUS_NAMES.get(status, status), text, last)

    @property
    def last_message(self) -> str:
        """The FMU's last warning or error message ('' if none)."""
        return self.messages[-1] if self.messages else ""

    @property
    def step_message(self) -> str:
        """What the FMU said (warning and up) during the last :meth:`step`, its
        messages joined ('' if nothing): the reason a fault line gives."""
        n = min(self.n_messages - self._step_mark, len(self.messages))
        return "; ".join(list(self.messages)[len(self.messages) - n :]) if n > 0 else ""

    def _set_scalar(self, name: str, value: Scalar) -> None:
        var = self.variables[name]
        vr = [var.valueReference]
        fmu = self.fmu
        if var.type == "Boolean":
            fmu.setBoolean(vr, [bool(value)])
        elif var.type in _INTEGERS[self.version]:
            setter = fmu.setInteger if self.version == 2 else (fmu.setInt64 if var.type == "Int64" else fmu.setInt32)
            setter(vr, [int(value)])
        elif self.version == 2:
            fmu.setReal(vr, [float(value)])
        else:
            fmu.setFloat64(vr, [float(value)])

    def _build_io(self) -> None:
        m = self.mapping
        vr_t = ctypes.c_uint32
        real_t = ctypes.c_double
        inputs = [self.variables[n].valueReference for n in m.inputs]
        reads = [self.variables[ch.variable].valueReference for ch in m.outputs] + [self.variables[n].valueReference for n in m.truth.variables()]
        self._in_vr = (vr_t * 2)(*inputs)
        self._in_val = (real_t * 2)()
        self._out_vr = (vr_t * len(reads))(*reads)
        self._out_val = (real_t * len(reads))()
        self.n_reads = len(reads)
        fmu = self.fmu
        component = fmu.component
        # Functions named after the FMI call they make: a crash inside the FMU
        # (faulthandler's traceback in the plant's log) names the call.
        if self.version == 2:
            set_real, get_real, do_step = fmu.fmi2SetReal, fmu.fmi2GetReal, fmu.fmi2DoStep

            def fmi2SetReal() -> Any:
                return set_real(component, self._in_vr, 2, self._in_val)

            def fmi2GetReal() -> Any:
                return get_real(component, self._out_vr, len(reads), self._out_val)

            def fmi2DoStep(t: float, h: float) -> Any:
                return do_step(component, t, h, 1)

            self._set, self._get, self._step = fmi2SetReal, fmi2GetReal, fmi2DoStep
        else:
            set_f, get_f, do_step3 = fmu.fmi3SetFloat64, fmu.fmi3GetFloat64, fmu.fmi3DoStep
            flags = [ctypes.c_bool(), ctypes.c_bool(), ctypes.c_bool()]
            last = ctypes.c_double()
            refs = [ctypes.byref(f) for f in flags] + [ctypes.byref(last)]
            self._terminate_flag = flags[1]

            def fmi3SetFloat64() -> Any:
                return set_f(component, self._in_vr, 2, self._in_val, 2)

            def fmi3GetFloat64() -> Any:
                return get_f(component, self._out_vr, len(reads), self._out_val, len(reads))

            def fmi3DoStep(t: float, h: float) -> Any:
                return do_step3(component, t, h, True, *refs)

            self._set, self._get, self._step = fmi3SetFloat64, fmi3GetFloat64, fmi3DoStep

    # -- per step ----------------------------------------------------------------------------
    def step(self, t: float, h: float, volts0: float, volts1: float) -> int:
        """Inputs set, one ``doStep`` from ``t`` by ``h``, outputs read into
        :attr:`values`; the FMI status (or :data:`STATUS_TERMINATED`)."""
        self._in_val[0] = volts0
        self._in_val[1] = volts1
        self._step_mark = self.n_messages
        try:
            self._set()
            self._step(t, h)
            if self.version == 3 and self._terminate_flag.value:
                return STATUS_TERMINATED
            self._get()
        except Exception as exc:  # noqa: BLE001 - FMPy's FMICallException carries the status
            status = int(getattr(exc, "status", STATUS_ERROR))
            self._fatal = self._fatal or status == STATUS_FATAL
            return status
        return STATUS_OK

    def read(self) -> list[float]:
        """The mapped outputs then the truth variables, as last read."""
        try:
            self._get()
        except Exception as exc:  # noqa: BLE001
            return [float("nan")] * self.n_reads if getattr(exc, "status", STATUS_ERROR) >= STATUS_ERROR else list(self._out_val)
        return list(self._out_val)

    @property
    def values(self) -> list[float]:
        return list(self._out_val)

    @property
    def closed(self) -> bool:
        """Terminated and freed (:meth:`close` ran)."""
        return self._closed

    def close(self) -> None:
        """Terminate and free the instance, unload its library, remove its files (once)."""
        if self._closed:
            return
        self._closed = True
        fmu = getattr(self, "fmu", None)
        if self._fatal:  # no terminate, no free: the FMU's memory is not to be touched again (its library stays loaded)
            log.info("%s: not terminated or freed after its fatal status (FMI: no further call)", self.path.name)
        elif fmu is not None and fmu.component:
            if self.fmu_initialized:
                try:
                    fmu.terminate()
                except Exception:  # noqa: BLE001, S110 - freed below in any case
                    pass
            try:
                fmu.freeInstance()  # frees the instance and unloads the library
            except Exception:  # noqa: BLE001, S110
                pass
        elif fmu is not None:  # loaded, never instantiated
            try:
                fmu.freeLibrary()
            except Exception:  # noqa: BLE001, S110
                pass
        shutil.rmtree(self._unzip_dir, ignore_errors=True)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def read_description(path: Path) -> Any:
    """The model description, refused in one line if the file is not a co-simulation FMU 2.0/3.0."""
    from plant_emulator.fmu.extract import check_archive

    fmpy = _fmpy()
    check_archive(path)  # a regular file, every member within bounds, before FMPy reads a byte of it
    try:
        description = fmpy.read_model_description(str(path))
    except zipfile.BadZipFile:
        raise FmuRefused(f"{path}: not an FMU (not a ZIP archive)") from None
    except KeyError:
        raise FmuRefused(f"{path}: not an FMU (no modelDescription.xml)") from None
    except Exception as exc:  # noqa: BLE001 - lxml, validation and FMPy's own errors
        raise FmuRefused(f"{path}: unreadable model description ({_one_line(exc)})") from None
    try:
        major = description.fmiMajorVersion
    except Exception:  # noqa: BLE001
        raise FmuRefused(f"{path}: no FMI version in its model description") from None
    if major not in (2, 3):
        raise FmuRefused(f"{path}: FMI {description.fmiVersion} is not supported (FMI 2.0 or 3.0 co-simulation)")
    if description.coSimulation is None:
        raise FmuRefused(f"{path}: model exchange only; the rig steps co-simulation FMUs (export it with co-simulation)")
    return description


def check_mapping(path: Path, mapping: FmuMapping, description: Any) -> None:
    """Every variable the mapping names exists with the causality and type its role needs."""
    version = description.fmiMajorVersion
    variables = {v.name: v for v in description.modelVariables}
    reals = _REALS[version]

    def need(name: str, role: str, causalities: tuple[str, ...], types: tuple[str, ...]) -> Any:
        var = variables.get(name)
        if var is None:
            raise FmuRefused(f"{path}: no variable {name!r} ({role} in the mapping)")
        if var.causality not in causalities:
            raise FmuRefused(f"{path}: variable {name!r} has causality {var.causality!r}; as {role} it must be {' or '.join(causalities)}")
        if var.type not in types:
            raise FmuRefused(f"{path}: variable {name!r} is {var.type}; as {role} it must be {' or '.join(types)}")
        if getattr(var, "shape", None):
            raise FmuRefused(f"{path}: variable {name!r} is an array; as {role} it must be a scalar")
        return var

    for i, name in enumerate(mapping.inputs):
        need(name, f"input of D/A channel {i}", ("input",), reals)
    for i, ch in enumerate(mapping.outputs):
        need(ch.variable, f"output of A/D channel {i}", ("output",), reals)
    for name in mapping.truth.variables():
        need(name, "ground truth", ("output", "local"), reals)
    scalar_types = (*reals, *_INTEGERS[version], "Boolean")
    settable = ("parameter", "input", "local", "output")
    for group, values in (("parameter", mapping.parameters), ("start value", mapping.start)):
        for name, value in values.items():
            causalities = ("parameter", "structuralParameter") if group == "parameter" else settable
            var = need(name, group, causalities, scalar_types)
            if var.variability == "constant":
                raise FmuRefused(f"{path}: variable {name!r} is a constant; it takes no {group}")
            _check_value(path, name, var.type, value, version)
    if mapping.seed_variable is not None:
        need(mapping.seed_variable, "seed variable", ("parameter", "structuralParameter"), _INTEGERS[version])


def _check_value(path: Path, name: str, vtype: str, value: Scalar, version: int) -> None:
    if vtype == "Boolean":
        if not isinstance(value, bool):
            raise FmuRefused(f"{path}: variable {name!r} is Boolean; the mapping gives {value!r}")
    elif vtype in _INTEGERS[version]:
        if isinstance(value, bool) or not float(value).is_integer():
            raise FmuRefused(f"{path}: variable {name!r} is {vtype}; the mapping gives {value!r}")
    elif isinstance(value, bool):
        raise FmuRefused(f"{path}: variable {name!r} is {vtype}; the mapping gives {value!r}")


def open_fmu(path: str | Path, mapping: FmuMapping, seed: int = 0) -> FmuInstance:
    """Check, extract, instantiate and initialize the FMU at ``path`` for ``mapping``."""
    _fmpy()  # FMPy present, or one line saying how to install it
    p = Path(path)
    description = read_description(p)
    check_mapping(p, mapping, description)
    from plant_emulator.fmu.extract import extract_fmu

    try:
        unzip_dir = extract_fmu(p)  # bounded, no link or path out of its folder (plant_emulator/fmu/extract.py)
    except ConfigError:  # its ArchiveRefused line
        raise
    except Exception as exc:  # noqa: BLE001
        raise FmuRefused(f"{p}: cannot be extracted ({_one_line(exc)})") from None
    return FmuInstance(p, mapping, description, str(unzip_dir), seed)


def check_step(instance: FmuInstance, sample_period_s: float) -> None:
    """Refuse a sample period the FMU says it cannot step (FMI 3.0's fixed
    internal step not dividing it), or that its first ``doStep`` refuses."""
    cs = instance.description.coSimulation
    fixed = getattr(cs, "fixedInternalStepSize", None)
    if fixed:
        ratio = sample_period_s / float(fixed)
        if abs(ratio - round(ratio)) > 1e-9 * max(1.0, ratio):
            raise FmuRefused(
                f"{instance.path}: its fixed internal step {float(fixed) * 1e3:g} ms does not divide the sample period {sample_period_s * 1e3:g} ms"
            )
    status = instance.step(0.0, sample_period_s, 0.0, 0.0)
    if status != STATUS_OK:
        label = {STATUS_DISCARD: "discard", STATUS_ERROR: "error", 4: "fatal", STATUS_TERMINATED: "terminate"}.get(status, f"status {status}")
        said = f": {instance.last_message}" if instance.last_message else ""
        raise FmuRefused(f"{instance.path}: refuses a step of {sample_period_s * 1e3:g} ms (doStep returned {label}{said})")


def check_fmu(path: str | Path, mapping: FmuMapping, sample_period_s: float, seed: int = 0) -> None:
    """Everything :func:`open_fmu` checks, plus one step of the sample period
    on a throw-away instance (freed again): what the launcher runs before any
    service starts."""
    instance = open_fmu(path, mapping, seed)
    try:
        check_step(instance, sample_period_s)
    finally:
        instance.close()
