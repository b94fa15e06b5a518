"""Scenario files: typed loading, unknown keys named by their dotted path, `--set` overrides, and
errors as ConfigError."""

import dataclasses
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from diagrams.gv_landing_config import GvLandingConfig
from diagrams.runner import DIAGRAM_MODULES, _diagrams, load_scenario
from diagrams.scenario import (
    SCENARIO_DIR,
    load_typed,
    normalise,
    parse_yaml,
    read_scenario,
    scenario_names,
    scenario_path,
    set_override,
)
from diagrams.stewart_run import Scenario
from systems.config import ConfigError


def write_yaml(tmp_path, data, name="scenario.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return path


def test_the_named_scenarios_are_the_yaml_files():
    names = scenario_names()
    assert {"stewart-hover", "stewart-dynamic"} <= set(names)
    assert names == sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))
    assert scenario_path("stewart-hover") == SCENARIO_DIR / "stewart-hover.yaml"


@pytest.mark.parametrize("name", scenario_names())
def test_every_named_scenario_loads_and_validates(name):
    loaded_name, scenario = load_scenario(name)
    raw = read_scenario(SCENARIO_DIR / f"{name}.yaml")  # with its base's
    assert loaded_name == name
    assert dataclasses.is_dataclass(scenario) and scenario.diagram == raw.get("diagram", "stewart_scene")
    assert scenario.duration_s == raw["duration_s"] and scenario.seed == raw["seed"]


def test_fields_the_file_sets_are_loaded_and_the_rest_keep_their_defaults(tmp_path):
    path = write_yaml(tmp_path, {"duration_s": 3.5, "platform": {"motion": "sinusoid", "roll_amplitude_deg": [4.0, 1.0],
                                                                 "roll_frequency_hz": [0.1, 0.3]},
                                 "camera": {"pixel_noise_std": 1.5}})
    name, scenario = load_scenario(config_path=path)
    defaults = Scenario()
    assert name == "scenario"
    assert scenario.duration_s == 3.5
    assert scenario.platform.roll_amplitude_deg == [4.0, 1.0]
    assert scenario.camera.pixel_noise_std == 1.5
    assert scenario.camera.fx == defaults.camera.fx and scenario.tof == defaults.tof and scenario.hover == defaults.hover


def test_unknown_key_names_its_dotted_path_and_suggests_the_right_one(tmp_path):
    path = write_yaml(tmp_path, {"platform": {"motion": "sinusoid", "rol_amplitude_deg": [8.0]}})
    with pytest.raises(ConfigError) as error:
        load_scenario(config_path=path)
    message = str(error.value)
    assert "'platform.rol_amplitude_deg'" in message
    assert "'platform.roll_amplitude_deg'" in message


@pytest.mark.parametrize("data, named, suggested", [
    ({"durations_s": 2.0}, "durations_s", "duration_s"),
    ({"camera": {"fxx": 400.0}}, "camera.fxx", "camera.fx"),
    ({"tof": {"noise_std": 0.01}}, "tof.noise_std", "tof.noise_std_m"),
    ({"hover": {"zzz": 1}}, "hover.zzz", None),
])
def test_unknown_keys_at_any_depth(tmp_path, data, named, suggested):
    with pytest.raises(ConfigError) as error:
        load_scenario(config_path=write_yaml(tmp_path, data))
    assert f"'{named}'" in str(error.value)
    if suggested:
        assert f"did you mean '{suggested}'" in str(error.value)
    else:
        assert "did you mean" not in str(error.value)


def test_unknown_key_given_by_set_is_named_too():
    with pytest.raises(ConfigError, match=r"'platform\.rol_amplitude_deg'.*'platform\.roll_amplitude_deg'"):
        load_scenario("stewart-dynamic", overrides=["platform.rol_amplitude_deg=8"])


def test_set_overrides_a_list_field_with_a_scalar():
    _, scenario = load_scenario("stewart-hover", overrides=["platform.motion=sinusoid", "platform.roll_amplitude_deg=8",
                                                            "platform.roll_frequency_hz=0.1"])
    assert scenario.platform.roll_amplitude_deg == [8.0]
    assert isinstance(scenario.platform.roll_amplitude_deg[0], float)
    assert scenario.platform.roll_frequency_hz == [0.1]
    _, default = load_scenario("stewart-hover")
    assert default.platform.roll_amplitude_deg == []


def test_set_accepts_yaml_values_and_later_settings_win():
    _, scenario = load_scenario("stewart-hover", overrides=[
        "platform.motion=sinusoid", "platform.x_amplitude_m=[0.1, 0.02]", "platform.x_frequency_hz=[0.1, 0.5]",
        "camera.rate_hz=10", "camera.rate_hz=25", "hover.offset_xy_m=[0.2, -0.1]", "seed=9"],
        duration_s=1.5)
    assert scenario.platform.motion == "sinusoid"
    assert scenario.platform.x_amplitude_m == [0.1, 0.02]
    assert scenario.camera.rate_hz == 25.0 and isinstance(scenario.camera.rate_hz, float)
    assert scenario.hover.offset_xy_m == [0.2, -0.1]
    assert scenario.duration_s == 1.5 and scenario.seed == 9


def test_duration_and_seed_arguments_that_a_set_contradicts_are_a_config_error():
    with pytest.raises(ConfigError, match=r"^--seed 11 and --set seed=9 differ: give one$"):
        load_scenario("stewart-hover", overrides=["seed=9"], seed=11)
    with pytest.raises(ConfigError, match=r"^--duration 0\.05 and --set duration_s=0\.1 differ: give one$"):
        load_scenario("stewart-hover", overrides=["duration_s=0.1"], duration_s=0.05)
    _, scenario = load_scenario("stewart-hover", overrides=["seed=9", "duration_s=1"], duration_s=1.0, seed=9)
    assert scenario.seed == 9 and scenario.duration_s == 1.0  # the same value twice: no conflict


def test_set_override_edits_nested_raw_data():
    raw = {"camera": {"fx": 1.0}}
    set_override(raw, "camera.fy=2.5")
    set_override(raw, "tof.noise_std_m=0.01")
    set_override(raw, "description=a b c")
    assert raw == {"camera": {"fx": 1.0, "fy": 2.5}, "tof": {"noise_std_m": 0.01}, "description": "a b c"}


def test_set_lays_a_mapping_over_the_group_key_by_key_as_a_base_does():
    raw = {"camera": {"fx": 1.0, "lens": {"k1": 0.1, "k2": 0.2}}, "seeds": [1, 2]}
    set_override(raw, "camera={fy: 2.5, lens: {k2: 0.3}}")
    set_override(raw, "seeds=[3]")  # any other value replaces the field's
    assert raw == {"camera": {"fx": 1.0, "fy": 2.5, "lens": {"k1": 0.1, "k2": 0.3}}, "seeds": [3]}
    _, scenario = load_scenario("stewart-hardware", overrides=["camera={pixel_noise_std: 1.5}"])
    _, file = load_scenario("stewart-hardware")
    assert file.camera.full_well_e > 0 and any(file.camera.distortion)  # the file's sensor noise and lens ...
    assert scenario.camera == dataclasses.replace(file.camera, pixel_noise_std=1.5)  # ... kept


@pytest.mark.parametrize("assignment", ["platform.roll_amplitude_deg", "=3", "camera.rate_hz=[1, 2"])
def test_malformed_set_is_a_config_error(assignment):
    with pytest.raises(ConfigError):
        set_override({}, assignment)


def test_set_into_a_value_that_is_not_a_group_is_a_config_error():
    with pytest.raises(ConfigError, match="seed"):
        set_override({"seed": 3}, "seed.x=1")


@pytest.mark.parametrize("assignment", ["camera.width=[512]", "platform.roll_amplitude_deg={a: 1}", "hover.roll_deg=yes"])
def test_type_errors_are_config_errors(assignment):
    with pytest.raises(ConfigError):
        load_scenario("stewart-dynamic", overrides=[assignment])


@pytest.mark.parametrize("assignment, field", [
    ("camera.rate_hz=fast", "camera.rate_hz"),
    ("seed=1.5", "seed"),
    ("platform.motion=[1, 2]", "platform.motion"),
    ("platform.roll_amplitude_deg=[1, x]", "platform.roll_amplitude_deg"),
    ("tof.bias_m=.nan", "tof.bias_m"),  # accepted before: every reading NaN, silently invalid
    ("platform.roll_amplitude_deg=[1.0, .nan]", "platform.roll_amplitude_deg"),
    ("camera.pixel_noise_std=.inf", "camera.pixel_noise_std"),  # accepted before: a range check is x >= 0
    ("imu.rate_hz=.inf", "imu.rate_hz"),
    # true and false are ints to Python: unchecked here, Drake's loader refused them naming only 'rate_hz', 'width'
    ("camera.rate_hz=true", "camera.rate_hz must be a number, got True"),
    ("camera.width=false", "camera.width must be a whole number, got False"),
])
def test_a_type_error_names_the_field(assignment, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_scenario("stewart-dynamic", overrides=[assignment])


@pytest.mark.parametrize("assignment, message", [
    ("manoeuvres=[[0.3, .nan, 0, 0, 0]]", "manoeuvres must be a finite number, got .nan"),  # accepted before
    ("manoeuvres=[[0.3, 1, 0, 0, 0], 2]", "manoeuvres must be a list of lists, got 2 in it"),
])
def test_items_of_a_list_of_lists_are_checked(assignment, message):
    with pytest.raises(ConfigError, match=f"^{message}$"):
        load_scenario("rqrlp-maneuvers", overrides=[assignment])


@pytest.mark.parametrize("scenario", ["gv-landing", "deck-landing", "rqrlp-maneuvers"])
def test_a_vertical_acceleration_limit_beyond_gravity_is_named_once_by_its_section(scenario):
    """The flight controller's one check, with the scenario's key (before: gv and deck said it without the
    numbers, rqrlp-maneuvers only when its diagram was built, as flight_controller.max_vertical_accel_m_s2)."""
    with pytest.raises(ConfigError, match=r"^controller\.max_vertical_accel_m_s2 \(9\.9 m/s\^2\) must be below "
                                          r"quadrotor\.gravity_m_s2 \(9\.81 m/s\^2\)$"):
        load_scenario(scenario, overrides=["controller.max_vertical_accel_m_s2=9.9"])


def test_a_group_given_a_scalar_is_a_config_error():
    with pytest.raises(ConfigError, match="hover"):
        load_scenario("stewart-hover", overrides=["hover=3"])


def test_a_group_given_a_scalar_is_named_without_a_trailing_dot():
    with pytest.raises(ConfigError) as error:
        load_scenario("stewart-hover", overrides=["hover=3"])
    assert str(error.value).startswith("hover must be ") and "hover." not in str(error.value)


@pytest.mark.parametrize("assignment, field", [
    ("camera.rate_hz=-1", "camera.rate_hz"),
    ("platform.tag_size_m=2", "platform.tag_size_m"),
    ("platform.motion=wobble", "platform.motion"),
    ("tof.max_range_m=0.01", "tof.max_range_m"),
    ("hover.height_above_deck_m=0.05", "hover.height_above_deck_m"),
    ("hover.height_above_deck_m=0.1", "hover.height_above_deck_m must exceed 0.1 m"),  # the bound itself
    ("imu.rate_hz=0", "imu.rate_hz"),
    ("duration_s=0", "duration_s"),
    ("duration_s=.inf", "duration_s must be a finite number"),
    ("duration_s=1" + "0" * 400, "duration_s must be a finite number, got a whole number of 401 digits"),  # no float
    ("camera.width=4294967297", "camera.width must lie in -2147483648 to 2147483647"),  # Drake's camera takes an int
    ("platform.tag_id=-2147483649", "platform.tag_id must lie in -2147483648 to 2147483647"),
    ("estimators=[crhf, atda, crhf]", "estimators: each may be listed once, got crhf more than once"),
])
def test_values_out_of_range_name_the_field(assignment, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_scenario("stewart-hover", overrides=[assignment])


def test_a_stewart_deck_motion_beyond_the_legs_stroke_is_refused():
    """A 0.5 m heave takes the legs (0.5 to 0.85 m long) beyond their stroke: the scenario, not the run, says so."""
    with pytest.raises(ConfigError, match="stroke"):
        load_scenario("stewart-hardware", overrides=["platform.z_amplitude_m=[0.5]"])


def test_whole_numbers_beyond_a_cpp_int_are_refused_in_lists_and_taken_for_seeds():
    with pytest.raises(ConfigError, match=r"platform\.markers\.ids must lie in -2147483648 to 2147483647"):
        load_scenario("gv-landing", overrides=["platform.markers.ids=[0, 1, 2, 3, 2147483648]"])
    assert load_scenario("stewart-hover", seed=2**64)[1].seed == 2**64  # numpy's generators take any size


@pytest.mark.parametrize("sign", [1, -1])
def test_a_whole_number_for_a_float_is_taken_up_to_the_largest_float_and_refused_past_it(sign):
    """A float setting written as a whole number: up to the largest finite float (its own value, a whole number)
    taken; a 400-digit one, which no float holds (an overflow), refused by name, negative as well as positive."""
    @dataclasses.dataclass
    class Length:
        x_m: float = 0.0

    largest = sign * int(sys.float_info.max)
    assert float(normalise({"x_m": largest}, Length)["x_m"]) == sign * sys.float_info.max
    assert float(normalise({"x_m": sign * 10**20}, Length)["x_m"]) == sign * 1e20
    with pytest.raises(ConfigError, match="x_m must be a finite number, got a whole number of 401 digits"):
        normalise({"x_m": sign * 10**400}, Length)


def test_whole_numbers_at_a_cpp_ints_limits_are_accepted_and_one_beyond_refused():
    """The range's ends are a 32-bit int's own (numpy's int32 limits), both included."""
    @dataclasses.dataclass
    class Counts:
        n: int = 0

    int32 = np.iinfo(np.int32)
    for value in (int(int32.max), int(int32.min)):
        assert normalise({"n": value}, Counts) == {"n": value}
    for value in (int(int32.max) + 1, int(int32.min) - 1):
        with pytest.raises(ConfigError, match=rf"^n must lie in {int32.min} to {int32.max} .*got {value}$"):
            normalise({"n": value}, Counts)


@pytest.mark.parametrize("name", ["gv-landing", "deck-landing", "rqrlp-maneuvers"])
def test_an_integration_scheme_these_diagrams_cannot_run_is_refused(name):
    """cenic integrates a MultibodyPlant, and none of them has one (it failed at the first step)."""
    with pytest.raises(ConfigError, match=r"integration\.scheme 'cenic' is not one of .*runge_kutta5"):
        load_scenario(name, overrides=["integration.scheme=cenic"])
    load_scenario(name, overrides=["integration.scheme=radau3"])


def test_every_gv_section_has_a_row_in_the_docs_table():
    """docs/scenarios.md's gv field table (the one with the `vehicle` row) names every section of GvLandingConfig;
    `distractors`, `bridge` and `hybrid` had none."""
    doc = (Path(__file__).parent.parent / "docs" / "scenarios.md").read_text()
    row = doc.index("| `vehicle` |")
    table = doc[doc.rindex("\n\n", 0, row):doc.index("\n\n", row)]
    rows = set(re.findall(r"^\| `([a-z_]+)` \|", table, re.M))
    sections = {f.name for f in dataclasses.fields(GvLandingConfig)
                if f.default_factory is not dataclasses.MISSING and dataclasses.is_dataclass(f.default_factory())}
    assert {"vehicle", "distractors", "bridge", "hybrid"} <= sections
    assert sections - rows == set()


def test_unknown_scenario_lists_the_known_ones():
    with pytest.raises(ConfigError) as error:
        load_scenario("stewart-hoover")
    assert "'stewart-hoover'" in str(error.value)
    for name in scenario_names():
        assert name in str(error.value)


@pytest.mark.parametrize("text, fragment", [
    ("platform: [1, 2\n", r"not valid YAML: expected ',' or '\]', but got '<stream end>' \(line 2, column 1\)$"),
    ("- 1\n- 2\n", "mapping"),
    ("[]\n", "mapping"), ("0\n", "mapping"), ("false\n", "mapping"), ("''\n", "mapping"),  # not an empty file
    ("diagram: no_such_diagram\n", "no_such_diagram"),
    ("diagram: [1]\n", r"unknown diagram \[1\]"),
    ("camera:\n  fx: 400.0\nduration_s: 1.0\ncamera:\n  pixel_noise_std: 0.0\n",
     r"key 'camera' is given twice in one mapping \(lines 1 and 4\)$"),  # PyYAML kept the second: fx lost
    ("platform:\n  motion: static\n  motion: sinusoid\n", r"key 'motion' is given twice .* \(lines 2 and 3\)"),
    # a list as a key: PyYAML's own error, not a TypeError from the check for a repeated key; its problem and
    # where, not its first line alone ("while constructing a mapping")
    ("? [a, b]\n: 1\n", r"is not valid YAML: found unhashable key \(line 1, column 3\)$"),
])
def test_bad_files_are_config_errors(tmp_path, text, fragment):
    with pytest.raises(ConfigError, match=fragment):
        load_scenario(config_path=write_yaml(tmp_path, text))


def test_a_merge_key_is_no_repeated_key():
    assert parse_yaml("a: &x {b: 1, c: 2}\nd:\n  <<: *x\n  b: 3\n") == {"a": {"b": 1, "c": 2}, "d": {"b": 3, "c": 2}}


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_scenario(config_path=tmp_path / "nope.yaml")


def test_an_empty_file_is_the_defaults(tmp_path):
    _, scenario = load_scenario(config_path=write_yaml(tmp_path, ""))
    assert scenario == Scenario()


@pytest.mark.parametrize("diagram", sorted(DIAGRAM_MODULES))
def test_every_field_of_every_scenario_can_be_set_to_its_default(diagram):
    """Each field given its default value in a file, as a user copying it would: a type the loader does not check
    (hybrid.classical.strip_distance_range was a bare tuple) would pass to Drake's loader and fail there."""
    schema = _diagrams()[diagram].Scenario
    raw = parse_yaml(yaml.safe_dump(dataclasses.asdict(schema())))
    assert load_typed(normalise(raw, schema), schema, diagram) == schema()


def test_a_field_of_a_type_no_scenario_sets_is_named():
    @dataclasses.dataclass
    class Odd:
        pair: tuple = (0.0, 1.0)

    with pytest.raises(ConfigError, match=r"^pair cannot be set: its type, tuple, is none a scenario sets"):
        normalise({"pair": [0.0, 2.0]}, Odd)


def test_the_hybrid_detectors_strip_distance_range_can_be_set():
    key = "hybrid.classical.strip_distance_range"
    assert load_scenario("ugv-hybrid", overrides=[f"{key}=[0.5, 2.0]"])[1].hybrid.classical.strip_distance_range == [
        0.5, 2.0]
    with pytest.raises(ConfigError, match=re.escape(f"{key} must be [low, high]")):
        load_scenario("ugv-hybrid", overrides=[f"{key}=[1, 2, 3]"])


def test_normalise_wraps_scalars_for_list_fields_only():
    out = normalise({"duration_s": 2, "platform": {"x_amplitude_m": 0.1, "motion": "static"}}, Scenario)
    assert out == {"duration_s": 2, "platform": {"x_amplitude_m": [0.1], "motion": "static"}}


def test_numbers_are_read_as_yaml_1_2_reads_them(tmp_path):
    # PyYAML (YAML 1.1) reads 1e9 as text; a user writing it means a number.
    _, scenario = load_scenario("stewart-dynamic", overrides=["camera.rate_hz=2.5e1", "tof.noise_std_m=1E-3"])
    assert scenario.camera.rate_hz == 25.0 and scenario.tof.noise_std_m == 0.001
    _, scenario = load_scenario("stewart-dynamic", overrides=["camera.rate_hz=.25e2", "tof.noise_std_m=+.5E-3"])
    assert scenario.camera.rate_hz == 25.0 and scenario.tof.noise_std_m == 0.0005
    assert parse_yaml("-.5e-1") == -0.05
    _, scenario = load_scenario(config_path=write_yaml(tmp_path, "diagram: stewart_scene\nduration_s: 3e1\n"))
    assert scenario.duration_s == 30.0
    with pytest.raises(ConfigError, match="camera.rate_hz"):
        load_scenario("stewart-dynamic", overrides=["camera.rate_hz=1e"])  # still text, and named


def test_integers_are_read_as_yaml_1_2_reads_them():
    # YAML 1.1 (PyYAML) reads 045 as octal 37 and 1:30 as sexagesimal 90.
    _, scenario = load_scenario("stewart-dynamic", overrides=["seed=045", "camera.width=0x280"])
    assert scenario.seed == 45 and scenario.camera.width == 640
    assert [parse_yaml(text) for text in ("-007", "0o17", "1:30", "1:30.0", "0b11", "1_000")] == [
        -7, 15, "1:30", "1:30.0", "0b11", "1_000"]
    with pytest.raises(ConfigError, match=r"^camera\.rate_hz must be a number, got '1:30'$"):
        load_scenario("stewart-dynamic", overrides=["camera.rate_hz=1:30"])
    with pytest.raises(ConfigError, match=r"^--set seed: cannot parse the value '!!int 0b11': '0b11' is not a YAML "
                                          r"1\.2 integer \(line 1, column 1\)$"):  # tagged by hand
        load_scenario("stewart-dynamic", overrides=["seed=!!int 0b11"])


def test_a_value_that_is_no_yaml_names_its_problem_and_where():
    with pytest.raises(ConfigError, match=r"^--set camera\.fx: cannot parse the value '\[1, 2': expected ',' or "
                                          r"'\]', but got '<stream end>' \(line 1, column 6\)$"):
        load_scenario("stewart-dynamic", overrides=["camera.fx=[1, 2"])


def test_a_scenario_starts_from_its_base_and_replaces_what_it_sets(tmp_path):
    path = write_yaml(tmp_path, {"base": "stewart-dynamic", "duration_s": 5.0,
                                 "camera": {"full_well_e": 6000.0}, "platform": {"roll_amplitude_deg": [4.0]}})
    _, scenario = load_scenario(config_path=path)
    _, base = load_scenario("stewart-dynamic")
    assert scenario.duration_s == 5.0 and scenario.camera.full_well_e == 6000.0
    assert scenario.camera.pixel_noise_std == base.camera.pixel_noise_std == 2.0  # the base's, beside the new key
    assert scenario.platform.roll_amplitude_deg == [4.0]  # a list replaces the base's whole
    assert scenario.platform.pitch_amplitude_deg == base.platform.pitch_amplitude_deg
    assert scenario.estimators == base.estimators


@pytest.mark.parametrize("base, named", [("no-such-scenario", "no-such-scenario"), (["deck-landing"], "base must be")])
def test_a_bad_base_is_a_config_error(tmp_path, base, named):
    path = write_yaml(tmp_path, {"base": base, "duration_s": 1.0})
    with pytest.raises(ConfigError, match=named):
        load_scenario(config_path=path)


def test_bases_that_lead_back_are_a_config_error(tmp_path, monkeypatch):
    monkeypatch.setattr("diagrams.scenario.SCENARIO_DIR", tmp_path)
    write_yaml(tmp_path, {"base": "b", "duration_s": 1.0}, "a.yaml")
    write_yaml(tmp_path, {"base": "a"}, "b.yaml")
    with pytest.raises(ConfigError, match="base 'a' leads back"):
        load_scenario("a")


def test_deck_landing_hardware_has_stewart_hardwares_sensors():
    _, deck = load_scenario("deck-landing-hardware")
    _, stewart = load_scenario("stewart-hardware")
    _, plain = load_scenario("deck-landing")
    assert deck.camera == stewart.camera and deck.camera.distortion != plain.camera.distortion
    assert deck.tof == stewart.tof and deck.crhf.range_filter == stewart.crhf.range_filter
    assert deck.estimate_latency_frames == stewart.estimate_latency_frames == 1
    assert deck.platform == plain.platform and deck.landing == plain.landing  # deck-landing's deck and descent
