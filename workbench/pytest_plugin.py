"""pytest plugin for users' own HIL tests: the ``rig`` fixture.

Installed with the package (entry point ``pytest11``: ``ralf_hil``), so any
test file can ask for ``rig``::

    @pytest.mark.rig_settings(controller={"oatf_mode": "adaptive"})
    def test_shaping_keeps_deflection_small(rig):
        record = rig.run(duration_s=10.0)
        assert record.error is None
        assert record.max_abs_deflection_in < 0.5

Markers (the closest wins; settings of several markers merge):

``@pytest.mark.rig_clock("lockstep")``
    the clock: ``cosim`` (default: one thread, fast and deterministic),
    ``lockstep`` or ``realtime`` (the one-process rig with a CAN bus);
    ``--rig-clock`` sets the default for a whole session.
``@pytest.mark.rig_settings(controller={...}, plant={...}, dsp={...}, common={...})``
    settings per service (names as in ``ralf-controller --help``, without ``RALF_``).
``@pytest.mark.rig_faults("scenario.yaml")`` or ``rig_faults({...})``
    a link-fault scenario (docs/timing-faults.md).

``@pytest.mark.rig_invalid_ok``
    the test expects an INVALID run (no tick, or a dead plant model).

The fixture is a :class:`workbench.hil.HilRig`; an unknown setting or clock
fails the test's setup with one line naming it. A run whose verdict
(:mod:`workbench.verdict`, ``record.verdict``) is INVALID tested nothing:
a test that passed over it fails at teardown with the run's one-line
summary (ticks, interrupts, verdict), unless marked ``rig_invalid_ok``.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from workbench.hil import CLOCKS, HilRig, RigSettingError

MARKERS = (
    "rig_clock(name): the clock of the rig fixture: cosim (default), lockstep or realtime",
    "rig_settings(controller=None, plant=None, dsp=None, common=None): settings of the rig fixture, per service",
    "rig_faults(scenario): a link-fault scenario (file path or mapping) for the rig fixture",
    "rig_invalid_ok: the rig fixture lets the test pass although its run is INVALID (no tick, or a dead plant model)",
)


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("ralf-hil", "ralf-hil rig fixture")
    group.addoption("--rig-clock", choices=CLOCKS, default=None, help="default clock of the rig fixture (default: cosim; a rig_clock marker wins)")


def pytest_configure(config: pytest.Config) -> None:
    for line in MARKERS:
        config.addinivalue_line("markers", line)


def _settings(node: pytest.Item) -> dict[str, dict[str, Any]]:
    merged: dict[str, dict[str, Any]] = {"controller": {}, "plant": {}, "dsp": {}, "common": {}}
    for mark in reversed(list(node.iter_markers("rig_settings"))):  # outermost first, the test's own last
        if mark.args:
            raise RigSettingError("rig_settings takes keyword arguments: controller={...}, plant={...}, dsp={...}, common={...}")
        for service, values in mark.kwargs.items():
            if service not in merged:
                raise RigSettingError(f"rig_settings: unknown service {service!r} (controller, plant, dsp, common)")
            if not isinstance(values, dict):
                raise RigSettingError(f"rig_settings: {service}= takes a dict of settings, got {type(values).__name__}")
            merged[service].update(values)
    return merged


@pytest.fixture
def rig(request: pytest.FixtureRequest, tmp_path: Any) -> Iterator[HilRig]:
    """A rig in the clock, settings and fault scenario the test's markers ask for (not yet running:
    ``rig.run(duration_s)``, or ``rig.start``/``rig.wait``); closed after the test."""
    node = request.node
    clock_mark = node.get_closest_marker("rig_clock")
    faults_mark = node.get_closest_marker("rig_faults")
    problem = None
    try:
        clock = clock_mark.args[0] if clock_mark is not None and clock_mark.args else request.config.getoption("--rig-clock") or "cosim"
        s = _settings(node)
        hil = HilRig(
            clock=clock,  # type: ignore[arg-type]  # checked by HilRig (one clear line)
            controller=s["controller"],
            plant_settings=s["plant"],
            dsp_settings=s["dsp"],
            common=s["common"],
            faults=faults_mark.args[0] if faults_mark is not None and faults_mark.args else None,
            workdir=tmp_path,
        )
    except RigSettingError as exc:
        problem = f"rig fixture: {exc}"
    if problem is not None:  # outside the except: one line, no chained traceback
        pytest.fail(problem, pytrace=False)
    try:
        yield hil
    finally:
        hil.close()
    record = hil.record
    passed = getattr(node, "rig_call_passed", False)
    if record is not None and record.verdict is not None and record.verdict.level == "INVALID" and passed and node.get_closest_marker("rig_invalid_ok") is None:
        pytest.fail(f"rig fixture: the run tested nothing: {record.summary()} (mark the test rig_invalid_ok if it expects that)", pytrace=False)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Any:
    """Note whether the test's own body passed (the rig fixture judges its run only then)."""
    report = yield
    if call.when == "call":
        item.rig_call_passed = report.passed  # type: ignore[attr-defined]
    return report
