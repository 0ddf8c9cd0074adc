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
fails the test's setup with one line naming it. So does a marker named like
one of these that is none of them (``rig_setting``, a typo), or one of them
given arguments it does not take, in any test, with or without the fixture:
the line names the closest marker. A run whose verdict
(:mod:`workbench.verdict`, ``record.verdict``) is INVALID tested nothing:
a test that passed over it fails at teardown with the run's one-line
summary (ticks, interrupts, verdict), unless marked ``rig_invalid_ok``.

Signal checks (:mod:`workbench.checks`): every :class:`~workbench.checks.CheckResult`
a test makes, in its setup, body or teardown, is kept for its report: a JUnit
property each (``check:<name>`` -> ``PASS measured=... limit=...``, as
``record_property`` writes them) and, when pytest-html writes a report
(``--html``), a figure each in it. The ``checks`` fixture is the test's list of them.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterator
from typing import Any

import pytest

from workbench.checks.collect import collecting
from workbench.checks.result import CheckResult
from workbench.hil import CLOCKS, HilRig, RigSettingError

MARKERS = (
    "rig_clock(name): the clock of the rig fixture: cosim (default), lockstep or realtime",
    "rig_settings(controller=None, plant=None, dsp=None, common=None): settings of the rig fixture, per service",
    "rig_faults(scenario): a link-fault scenario (file path or mapping) for the rig fixture",
    "rig_invalid_ok: the rig fixture lets the test pass although its run is INVALID (no tick, or a dead plant model)",
)


SERVICES = ("controller", "plant", "dsp", "common")
USAGE = {
    "rig_clock": "@pytest.mark.rig_clock(NAME), NAME one of cosim, lockstep, realtime",
    "rig_settings": "@pytest.mark.rig_settings(controller={...}, plant={...}, dsp={...}, common={...})",
    "rig_faults": "@pytest.mark.rig_faults(SCENARIO), a file path or a mapping",
    "rig_invalid_ok": "@pytest.mark.rig_invalid_ok, no arguments",
}
"""The markers and how each is written."""
LOOKALIKE = 0.8
"""A marker name this close to one of :data:`USAGE` (difflib's ratio) is taken for a typo of it, as is every ``rig_*`` name."""


def marker_problem(mark: pytest.Mark) -> str | None:
    """The one line for a marker that is not one of :data:`USAGE` but is named like one, or one of
    them given arguments it does not take; None for a good one or one of another plugin."""
    if mark.name not in USAGE:
        close = difflib.get_close_matches(mark.name, list(USAGE), n=1, cutoff=0.6)
        if not mark.name.startswith("rig_") and not difflib.get_close_matches(mark.name, list(USAGE), n=1, cutoff=LOOKALIKE):
            return None
        hint = f"did you mean @pytest.mark.{close[0]}?" if close else f"the rig markers are {', '.join(USAGE)}"
        return f"@pytest.mark.{mark.name} is not a rig marker; {hint}"
    if mark.name == "rig_settings":
        if mark.args:
            return f"@pytest.mark.rig_settings takes keyword arguments only: {USAGE['rig_settings']}"
        for name in mark.kwargs:
            if name not in SERVICES:
                close = difflib.get_close_matches(name, SERVICES, n=1, cutoff=0.6)
                hint = f"did you mean {close[0]}=?" if close else f"give {', '.join(SERVICES)}"
                return f"@pytest.mark.rig_settings has no argument {name}=; {hint}"
        return None
    if mark.name == "rig_invalid_ok":
        return f"@pytest.mark.rig_invalid_ok takes no arguments: {USAGE[mark.name]}" if mark.args or mark.kwargs else None
    if len(mark.args) != 1 or mark.kwargs:
        given = ", ".join([repr(a) for a in mark.args] + [f"{k}=" for k in mark.kwargs]) or "nothing"
        return f"@pytest.mark.{mark.name} takes one argument, got {given}: {USAGE[mark.name]}"
    return None


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("ralf-hil", "ralf-hil rig fixture")
    group.addoption("--rig-clock", choices=CLOCKS, default=None, help="default clock of the rig fixture (default: cosim; a rig_clock marker wins)")


def pytest_configure(config: pytest.Config) -> None:
    for line in MARKERS:
        config.addinivalue_line("markers", line)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """A test with a mistyped or misused rig marker fails in its setup, before any fixture."""
    for mark in item.iter_markers():
        if problem := marker_problem(mark):
            pytest.fail(f"rig marker: {problem}", pytrace=False)


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


CHECK_RESULTS = pytest.StashKey[list[CheckResult]]()
"""The check results of the test running (its setup, body and teardown)."""
CHECKS_REPORTED = pytest.StashKey[int]()
"""How many of them the test's reports already carry."""


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Any:
    """Collect every check result the test makes, from its setup to its teardown."""
    with collecting() as results:
        item.stash[CHECK_RESULTS] = results
        item.stash[CHECKS_REPORTED] = 0
        return (yield)


@pytest.fixture
def checks(request: pytest.FixtureRequest) -> list[CheckResult]:
    """The check results the test has made so far (each also goes into its report)."""
    return request.node.stash.setdefault(CHECK_RESULTS, [])


def _property_name(item: pytest.Item, result: CheckResult) -> str:
    taken = {name for name, _ in item.user_properties}
    name, n = f"check:{result.name}", 1
    while name in taken:
        n += 1
        name = f"check:{result.name} #{n}"
    return name


def _html_report(config: pytest.Config) -> bool:
    """pytest-html is installed and writes a report in this session."""
    return config.pluginmanager.hasplugin("html") and bool(config.getoption("htmlpath", None))


def _figures(results: list[CheckResult]) -> list[dict[str, Any]]:
    """pytest-html extras: one PNG figure (base64) per result."""
    import base64

    from pytest_html import extras

    try:
        from workbench.checks.figure import png
    except ImportError as exc:  # matplotlib missing: say so in the report, once
        return [extras.text(f"check figures need matplotlib (pip install 'ralf-hil[rig]'): {exc}", name="check figures")]
    return [extras.png(base64.b64encode(png(r.figure())).decode("ascii"), name=f"{r.name} {r.level}") for r in results]


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Any:
    """Note whether the test's own body passed (the rig fixture judges its run only then);
    put the check results of this phase in its report: JUnit properties, HTML figures."""
    results = item.stash.get(CHECK_RESULTS, [])
    done = item.stash.get(CHECKS_REPORTED, 0)
    new = results[done:]
    item.stash[CHECKS_REPORTED] = len(results)
    for result in new:  # before the report is made: it copies the properties
        item.user_properties.append((_property_name(item, result), result.property_value()))
    report = yield
    if call.when == "call":
        item.rig_call_passed = report.passed  # type: ignore[attr-defined]
    if new and _html_report(item.config):
        report.extras = [*getattr(report, "extras", []), *_figures(new)]
    return report
