"""Sweep specs: expansion, resolution against the settings models, keys, files (no runs)."""

from __future__ import annotations

from pathlib import Path

import pytest

from plant_emulator.model import PlantConfig
from plant_emulator.plant_factory import plant_config
from protocol.settings import ControllerSettings, PlantSettings
from workbench.campaign.spec import SpecError, SweepSpec, expand, load_spec, resolve, run_key

BASE = {"controller.duration_s": 2.0}


def test_grid_points_and_seeds_multiply() -> None:
    spec = SweepSpec(
        base=BASE,
        grid={"plant.adc_bits": [12, 16, 20], "controller.oatf_mode": ["fixed", "adaptive"]},
        points=[{"label": "slow", "dsp.fft_width": 2048}, {"label": "fast", "dsp.fft_width": 512}],
        seeds=2,
    )
    runs = expand(spec)
    assert len(runs) == 2 * 3 * 2 * 2
    assert len({r.key for r in runs}) == len(runs)
    assert {r.settings["plant"]["adc_bits"] for r in runs} == {12, 16, 20}
    assert {r.settings["dsp"]["fft_width"] for r in runs} == {512, 2048}
    assert {r.axes["point"] for r in runs} == {"slow", "fast"}
    assert len({r.seed for r in runs}) == 2
    assert all(r.rig_id == f"sw-{r.key}" for r in runs)


def test_derived_seeds_are_reproducible_and_depend_on_the_base_seed() -> None:
    a = SweepSpec(base=BASE, seeds=3, seed=1).seed_list()
    assert a == SweepSpec(base=BASE, seeds=3, seed=1).seed_list()
    assert a != SweepSpec(base=BASE, seeds=3, seed=2).seed_list()
    assert SweepSpec(base=BASE, seeds=[5, 7]).seed_list() == [5, 7]


def test_bare_and_common_names_reach_every_service_that_has_them() -> None:
    _, s = resolve({"batch_size": 20, "common.sample_rate_hz": 100.0, "controller.duration_s": 1.0})
    assert s["controller"]["batch_size"] == 20 and s["dsp"]["batch_size"] == 20
    assert all(s[x]["sample_rate_hz"] == 100.0 for x in ("controller", "plant", "dsp"))


def test_resolution_fills_the_models_defaults_and_ignores_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RALF_ADC_BITS", "20")
    monkeypatch.setenv("RALF_OATF_MODE", "adaptive")
    _, s = resolve(BASE)
    assert s["plant"]["adc_bits"] == 12
    assert s["controller"]["oatf_mode"] == "off"
    assert s["controller"]["tip_speed_in_s"] == ControllerSettings.model_fields["tip_speed_in_s"].default


def test_bundle_axis_sets_several_settings_and_is_labelled() -> None:
    spec = SweepSpec(base=BASE, grid={"identifier": [{"label": "thesis", "dsp.fft_width": 2048, "dsp.alpha": 0.1}, {"dsp": {"fft_width": 512, "alpha": 0.05}}]})
    runs = expand(spec)
    assert [(r.settings["dsp"]["fft_width"], r.settings["dsp"]["alpha"]) for r in runs] == [(2048, 0.1), (512, 0.05)]
    assert runs[0].axes["identifier"] == "thesis"
    assert "fft_width" in runs[1].axes["identifier"]


@pytest.mark.parametrize(
    ("assignments", "message"),
    [
        ({"plant.adc_bit": 12}, "did you mean 'adc_bits'"),
        ({"plant.adc_bits": 14}, "adc_bits"),
        ({"dsp.fft_width": 1000}, "power of two"),
        ({"valve.gain": 1}, "unknown service"),
        ({"no_such_setting": 1}, "'no_such_setting' is not a setting of any service"),
    ],
)
def test_bad_settings_fail_the_spec_with_the_name(assignments: dict, message: str) -> None:
    with pytest.raises(SpecError, match=message):
        expand(SweepSpec(base={**BASE, **assignments}))


def test_a_run_that_never_ends_and_an_unknown_mode_are_refused() -> None:
    with pytest.raises(SpecError, match="never ends"):
        expand(SweepSpec())
    with pytest.raises(SpecError, match="unknown run mode"):
        expand(SweepSpec(base=BASE, mode="warp"))


def test_the_key_is_the_resolved_identity_without_plumbing() -> None:
    _, s = resolve(BASE)
    key = run_key("lockstep", s)
    _, explicit = resolve({**BASE, "plant.adc_bits": 12, "rig_id": "elsewhere", "can_port": 40000, "run_record": "x.npz"})
    assert run_key("lockstep", explicit) == key  # defaults spelled out and plumbing change nothing
    _, other = resolve({**BASE, "plant.adc_bits": 16})
    assert run_key("lockstep", other) != key
    assert run_key("onrig", s) != key
    assert len(key) == 16 and int(key, 16) >= 0


def test_duplicate_points_run_once() -> None:
    spec = SweepSpec(base=BASE, points=[{"plant.adc_bits": 12}, {}])
    assert len(expand(spec)) == 1


def test_yaml_and_toml_specs_give_the_same_runs(tmp_path: Path) -> None:
    (tmp_path / "s.yaml").write_text(
        "name: t\nbase:\n  controller.duration_s: 2\n  batch_size: 20\ngrid:\n  plant.adc_bits: [12, 20]\n  identifier:\n    - {label: fast, dsp.fft_width: 512}\nseeds: [3]\n",
        encoding="utf-8",
    )
    (tmp_path / "s.toml").write_text(
        'name = "t"\nseeds = [3]\n[base]\ncontroller.duration_s = 2\nbatch_size = 20\n[grid]\nplant.adc_bits = [12, 20]\nidentifier = [{label = "fast", dsp.fft_width = 512}]\n',
        encoding="utf-8",
    )
    a, b = expand(load_spec(tmp_path / "s.yaml")), expand(load_spec(tmp_path / "s.toml"))
    assert [r.key for r in a] == [r.key for r in b] and len(a) == 2
    (tmp_path / "bad.yaml").write_text("name: t\ngrid: {plant.adc_bits: []}\n", encoding="utf-8")
    with pytest.raises(SpecError, match="no values"):
        load_spec(tmp_path / "bad.yaml")
    (tmp_path / "s.json").write_text("{}", encoding="utf-8")
    with pytest.raises(SpecError, match="yaml"):
        load_spec(tmp_path / "s.json")


def test_sensor_noise_scale_scales_the_thesis_noise_stds() -> None:
    ref = PlantConfig()
    for scale in (0.0, 0.25, 4.0):
        cfg = plant_config(PlantSettings(sensor_noise_scale=scale))
        assert cfg.deflection_noise_std_in == pytest.approx(tuple(scale * x for x in ref.deflection_noise_std_in))
        assert cfg.extension_noise_std_in == pytest.approx(tuple(scale * x for x in ref.extension_noise_std_in))
    assert plant_config(PlantSettings()).deflection_noise_std_in == ref.deflection_noise_std_in
