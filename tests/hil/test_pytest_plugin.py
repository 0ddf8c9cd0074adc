"""The ``rig`` fixture (workbench/pytest_plugin.py), tested as users meet it: test files
run by pytest's own ``pytester`` with the plugin loaded from its ``pytest11`` entry point."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]


def test_plugin_is_registered_by_its_entry_point(pytester: pytest.Pytester) -> None:
    result = pytester.runpytest("--markers")
    result.stdout.fnmatch_lines(["@pytest.mark.rig_clock(name)*", "@pytest.mark.rig_settings(*", "@pytest.mark.rig_faults(scenario)*"])
    assert "ralf_hil" in {name for name, _ in pytester.parseconfig().pluginmanager.list_name_plugin()}


def test_cosim_rig_with_settings_and_a_payload_command(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        """
        import pytest

        @pytest.mark.rig_settings(controller={"oatf_mode": "adaptive"}, plant={"truth_rate_hz": 50.0})
        def test_run(rig):
            assert rig.clock == "cosim"
            rig.plant.payload(attached=True, at_s=1.0)
            record = rig.run(duration_s=3.0)
            assert record.error is None and record.ticks == 600
            assert [e.kind for e in record.events if e.kind == "payload"] == ["payload"]
            assert not record.truth[0].payload_attached and record.truth[-1].payload_attached
            assert len(record.truth) == 150
            assert record.interrupts and record.interrupts[-1].batch_seq >= 15
            assert record.recording.exists()
            with pytest.raises(Exception, match="no CAN bus"):
                rig.can.remote_node()
        """
    )
    pytester.runpytest_subprocess().assert_outcomes(passed=1)


def test_unknown_setting_is_one_clear_error(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        """
        import pytest

        @pytest.mark.rig_settings(controller={"oatf_mod": "adaptive"})
        def test_typo(rig):
            rig.run(duration_s=1.0)

        @pytest.mark.rig_settings(dsp={"fft_width": 3})
        def test_bad_value(rig):
            rig.run(duration_s=1.0)

        @pytest.mark.rig_clock("wallclock")
        def test_bad_clock(rig):
            pass

        @pytest.mark.rig_settings(common={"clock": "lockstep"})
        def test_plumbing(rig):
            pass

        @pytest.mark.rig_settings(controller={"policy_deadline": "stop"})
        def test_retired(rig):
            pass
        """
    )
    result = pytester.runpytest_subprocess()
    result.assert_outcomes(errors=5)
    result.stdout.fnmatch_lines(
        [
            "*rig fixture: 'oatf_mod' is not a setting of the controller; did you mean 'oatf_mode' or 'oatf'?*",
            "*rig fixture: dsp: invalid configuration: RALF_FFT_WIDTH: Input should be greater than or equal to 32*",
            "*rig fixture: unknown rig clock 'wallclock' (cosim, lockstep, realtime)*",
            "*rig fixture: common.clock is chosen by the rig fixture*",
            "*rig fixture: controller.policy_deadline: the policies are one setting: RALF_POLICIES=deadline=VALUE*",
        ]
    )
    assert "Traceback" not in result.stdout.str()


def test_rig_clock_option_and_marker(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        """
        import pytest

        def test_default(rig):
            assert rig.clock == "lockstep"

        @pytest.mark.rig_clock("cosim")
        def test_marker_wins(rig):
            assert rig.clock == "cosim"
        """
    )
    pytester.runpytest_subprocess("--rig-clock", "lockstep").assert_outcomes(passed=2)


def test_realtime_rig_can_bus_canopen_node_and_live_test_port(pytester: pytest.Pytester) -> None:
    """While the one-process rig runs in real time: a stock canopen master reads the plant's
    device type over SDO, the test's own bus sees SYNCs and TPDO1s, the test port's truth and
    the DSP's interrupts arrive live, and a payload command published mid-run is applied."""
    pytester.makepyfile(
        """
        import time
        import pytest

        @pytest.mark.rig_clock("realtime")
        @pytest.mark.rig_settings(plant={"truth_rate_hz": 20.0})
        def test_live(rig):
            rig.start(duration_s=4.0)
            node = rig.can.remote_node()
            assert node.sdo[0x1000].raw == 0x000C0191
            seen = set()
            deadline = time.monotonic() + 30
            while not {0x80, 0x181} <= seen and time.monotonic() < deadline:
                msg = rig.can.recv(0.5)
                if msg is not None:
                    seen.add(msg.arbitration_id)
            assert {0x80, 0x181} <= seen
            rig.plant.payload(attached=True, at_s=0.0)
            record = rig.wait(120)
            assert record.error is None and record.clock == "realtime"
            assert record.truth and record.interrupts
            assert record.truth[-1].payload_attached
            assert any(e.kind == "payload" for e in record.events)
        """
    )
    pytester.runpytest_subprocess("-p", "no:cacheprovider").assert_outcomes(passed=1)


def test_a_run_that_tested_nothing_fails_the_test_that_passed_over_it(pytester: pytest.Pytester, tmp_path: Path) -> None:
    """A plant model that dies mid-run (the example FMU's doStep returns Error at step 100): the
    run is INVALID; a test that passed over it fails at teardown with the run's summary, one
    marked rig_invalid_ok passes, and a sound run's record says what it covered and PASS."""
    from plant_emulator.fmu.build import EXAMPLE_SOURCE, build_c_fmu
    from tests.plant.fmu.support import write_mapping

    fmu = build_c_fmu(EXAMPLE_SOURCE, tmp_path / "two_mode_plant.fmu")
    mapping = write_mapping(tmp_path, parameters={"fault_step": 100, "fault_kind": 2})
    pytester.makepyfile(
        f"""
        import pytest

        DEAD = dict(plant={{"model": "fmu:{fmu}", "fmu_mapping": "{mapping}"}})

        @pytest.mark.rig_settings(**DEAD)
        def test_blind(rig):
            assert rig.run(duration_s=2.0).ticks > 0

        @pytest.mark.rig_invalid_ok
        @pytest.mark.rig_settings(**DEAD)
        def test_expected(rig):
            record = rig.run(duration_s=2.0)
            assert record.verdict.level == "INVALID" and record.error.startswith("plant model dead")

        def test_sound(rig):
            record = rig.run(duration_s=2.0)
            assert record.verdict.level == "PASS" and record.verdict.findings["control_ticks"] == 400
            assert record.summary().startswith("cosim run: 400 ticks (2.00 s simulated), ")
            assert record.summary().endswith("; PASS: nothing went wrong")
        """
    )
    result = pytester.runpytest_subprocess()
    result.assert_outcomes(passed=3, errors=1)
    result.stdout.fnmatch_lines(["*ERROR at teardown of test_blind*", "*rig fixture: the run tested nothing: cosim run: 10? ticks*INVALID: plant model dead*"])


def test_a_mistyped_or_misused_rig_marker_fails_the_setup_naming_the_closest(pytester: pytest.Pytester) -> None:
    """Without the fixture too: a typo of a marker no longer runs the default rig (or no rig) with
    only a warning; a test whose markers are right runs."""
    pytester.makepyfile(
        """
        import pytest

        @pytest.mark.rig_setting(controller={"oatf_mode": "adaptive"})
        def test_typo(rig):
            rig.run(duration_s=1.0)

        @pytest.mark.rigclock("lockstep")
        def test_lookalike():
            pass

        @pytest.mark.rig_settings(controler={"oatf_mode": "adaptive"})
        def test_unknown_service(rig):
            pass

        @pytest.mark.rig_clock("lockstep", speed=2)
        def test_extra_argument():
            pass

        @pytest.mark.rig_faults()
        def test_no_scenario():
            pass

        @pytest.mark.rig_settings({"oatf_mode": "adaptive"})
        def test_positional_settings():
            pass

        @pytest.mark.rig_clock("cosim")
        @pytest.mark.parametrize("n", [1])
        def test_right(n):
            pass
        """
    )
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, errors=6)
    result.stdout.fnmatch_lines(
        [
            "*rig marker: @pytest.mark.rig_setting is not a rig marker; did you mean @pytest.mark.rig_settings?",
            "*rig marker: @pytest.mark.rigclock is not a rig marker; did you mean @pytest.mark.rig_clock?",
            "*rig marker: @pytest.mark.rig_settings has no argument controler=; did you mean controller=?",
            "*rig marker: @pytest.mark.rig_clock takes one argument, got 'lockstep', speed=: @pytest.mark.rig_clock(NAME), NAME one of cosim, lockstep, realtime",
            "*rig marker: @pytest.mark.rig_faults takes one argument, got nothing: @pytest.mark.rig_faults(SCENARIO), a file path or a mapping",
            "*rig marker: @pytest.mark.rig_settings takes keyword arguments only: *",
        ],
        consecutive=False,
    )
    assert "Traceback" not in result.stdout.str()


@pytest.mark.parametrize("clock", ["realtime", "lockstep"])
def test_a_failing_test_stops_its_running_rig_at_teardown(pytester: pytest.Pytester, clock: str) -> None:
    """A test that fails early in a long run: the teardown stops the rig (its
    run thread and its services' threads are gone when the next test begins),
    it does not wait for the run's end."""
    pytester.makepyfile(
        f"""
        import threading
        import pytest

        @pytest.mark.rig_clock("{clock}")
        def test_fails_early(rig):
            rig.start(duration_s=3600.0)
            assert rig.plant.truth  # the rig runs
            raise AssertionError("the test failed mid-run")

        def test_next():
            left = [t.name for t in threading.enumerate() if t.name in ("hil-rig", "plant", "dsp")]
            assert not left, left
        """
    )
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-p", "no:randomly")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*the test failed mid-run*"])


def test_can_errors_on_the_simulated_wire_from_the_markers(pytester: pytest.Pytester) -> None:
    """A fault scenario's can_errors through the fixture's markers, on the co-simulation's wire
    (docs/can-errors.md "In the simulated rig"): the plant's bus off and recovery reach the record."""
    pytester.makepyfile(
        """
        import pytest

        @pytest.mark.rig_settings(common={"can_bitrate": 1000000}, controller={"tf_download_samples": 0})
        @pytest.mark.rig_faults({"seed": 3, "can_errors": [{"identifier": 0x181, "from_s": 0.5, "to_s": 0.506}]})
        def test_run(rig):
            record = rig.run(duration_s=1.0)
            assert record.counters["plant_can_bus_off_recoveries"] == 1
            assert record.can_bus["errors"]["nodes"]["plant"]["bus_off"] == 1
        """
    )
    pytester.runpytest_subprocess().assert_outcomes(passed=1)
