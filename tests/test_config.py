"""Configuration loading and validation."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest

from evperc.config import DEFAULT_PATH, RULES, default_config, dumps, load_config
from evperc.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "user.toml"
    path.write_text(text)
    return path


def test_packaged_default_is_the_repo_file() -> None:
    assert DEFAULT_PATH.resolve() == (REPO / "configs" / "default.toml").resolve()


def test_defaults_are_valid_and_carry_the_paper_values() -> None:
    config = load_config()
    assert config["grid"]["cell_size_m"] == 0.5
    assert config["sensor"]["mu_free"] == 0.7
    assert config["sensor"]["mu_occupied"] == 0.8
    assert math.isnan(config["input"]["origin_lat_deg"])


def test_every_rule_names_an_existing_key() -> None:
    config = default_config()
    for dotted in RULES:
        node = config
        for part in dotted.split("."):
            assert part in node, dotted
            node = node[part]


def test_every_numeric_key_has_a_range_rule() -> None:
    # a number outside what a key can mean (a negative count, a negative speed) is a user
    # mistake named at load time; only the sensor's mounting offsets and angles take any value
    free = {f"input.extrinsic.{k}" for k in ("x_m", "y_m", "z_m", "roll_deg", "pitch_deg",
                                              "yaw_deg")}
    unruled = []

    def walk(node: dict, prefix: str) -> None:
        for key, value in node.items():
            dotted = f"{prefix}.{key}" if prefix else key
            if dotted == "map.road_width_m":  # an open table: its own check
                continue
            if isinstance(value, dict):
                walk(value, dotted)
            elif (isinstance(value, (int, float)) and not isinstance(value, bool)
                  and dotted not in RULES and dotted not in free):
                unruled.append(dotted)
    walk(default_config(), "")
    assert unruled == []


def test_a_negative_count_or_speed_of_the_split_is_refused(tmp_path: Path) -> None:
    path = write(tmp_path, "[objects]\nsplit_min_overlap_cells = -1\n"
                           "split_speed_difference_m_per_s = -0.5\n"
                           "moving_min_cluster_cells = -2\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    for key in ("split_min_overlap_cells = -1", "split_speed_difference_m_per_s = -0.5",
                "moving_min_cluster_cells = -2"):
        assert f"objects.{key} is outside" in message


def test_every_default_key_has_a_comment() -> None:
    for line in DEFAULT_PATH.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith("#"):
            assert "#" in line or line.split("=")[0].strip() in {
                "x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg"} or \
                line.split("=")[0].strip() in default_config()["map"]["road_width_m"], line


def test_user_file_overrides(tmp_path: Path) -> None:
    path = write(tmp_path, "[fusion]\nzeta_increment = 0.2\n[grid]\nwindow_size_m = 50\n")
    config = load_config(path)
    assert config["fusion"]["zeta_increment"] == 0.2
    assert config["grid"]["window_size_m"] == 50.0
    assert isinstance(config["grid"]["window_size_m"], float)
    assert config["fusion"]["zeta_decrement"] == default_config()["fusion"]["zeta_decrement"]


def test_unknown_key_is_named(tmp_path: Path) -> None:
    path = write(tmp_path, "[fusion]\nzeta_incremnt = 0.2\n")
    with pytest.raises(ConfigError, match=r"user.toml: unknown key fusion.zeta_incremnt"):
        load_config(path)


def test_every_failing_key_is_listed(tmp_path: Path) -> None:
    path = write(tmp_path, '[sensor]\nmu_free = 1.5\n[fusion]\ndiscount = "fancy"\n'
                           '[grid]\ncell_size_m = "big"\n')
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert "grid.cell_size_m must be float" in message
    assert "sensor.mu_free = 1.5 is outside" in message  # type and range errors together
    assert "\n" not in message
    path = write(tmp_path, '[sensor]\nmu_free = 1.5\n[fusion]\ndiscount = "fancy"\n')
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert "sensor.mu_free = 1.5 is outside [0.0, 1.0]" in message
    assert "fusion.discount = 'fancy' is not one of contextual, classical" in message


def test_open_table_accepts_new_classes(tmp_path: Path) -> None:
    path = write(tmp_path, "[map.road_width_m]\nbusway = 5\n")
    assert load_config(path)["map"]["road_width_m"]["busway"] == 5.0


def test_bad_toml_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[fusion\n"))
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.toml")


def test_dump_round_trips() -> None:
    config = load_config()
    again = tomllib.loads(dumps(config))
    assert again["fusion"] == config["fusion"]
    assert math.isnan(again["input"]["origin_lat_deg"])


# --- conservative free space, widened buildings, the kurdej2013 preset (issue 20) ---------

#: SPEC §3-§6 values, typed from /work/shared/SPEC.md (not read from any evperc file)
SPEC = {
    ("grid", "cell_size_m"): 0.5, ("sensor", "mu_free"): 0.7, ("sensor", "mu_occupied"): 0.8,
    ("sensor", "ground_threshold_m"): 0.3, ("map", "beta_building"): 0.9,
    ("map", "beta_road"): 0.9, ("map", "beta_other"): 0.8,
    ("fusion", "prior_where"): "observed", ("fusion", "discount"): "contextual",
    ("fusion", "discount_free"): 0.1, ("fusion", "discount_moving"): 0.1,
    ("fusion", "discount_stopped"): 0.02, ("fusion", "discount_unmapped"): 0.01,
    ("fusion", "discount_infrastructure"): 0.0, ("fusion", "residual_conflict"): "omega",
    ("fusion", "stopped_target"): "stopped", ("fusion", "zeta_increment"): 0.1,
    ("fusion", "zeta_decrement"): 0.5, ("fusion", "gamma_occupied"): 0.6,
    ("fusion", "gamma_conflict"): 0.2, ("decision", "min_betp"): 0.5,
    ("decision", "max_ignorance"): 0.5,
    # evperc's additions, off in the paper's method
    ("sensor", "free_margin_m"): 0.0, ("sensor", "free_erosion_m"): 0.0,
    ("sensor", "ground_chain"): False, ("sensor", "foot_lift_m"): 0.0,
    ("map", "building_margin_m"): 0.0, ("map", "fit_to_scans"): False,
}


@pytest.mark.parametrize("key", ["sensor.free_margin_m", "sensor.free_erosion_m",
                                 "sensor.foot_lift_m", "map.building_margin_m"])
def test_new_margins_are_validated(tmp_path: Path, key: str) -> None:
    table, name = key.split(".")
    with pytest.raises(ConfigError, match=rf"user.toml: {key} = -0.5 is outside \[0.0, "):
        load_config(write(tmp_path, f"[{table}]\n{name} = -0.5\n"))
    with pytest.raises(ConfigError, match=rf"{key} must be float, got str"):
        load_config(write(tmp_path, f'[{table}]\n{name} = "wide"\n'))
    assert load_config(write(tmp_path, f"[{table}]\n{name} = 1\n"))[table][name] == 1.0


def test_preset_kurdej2013_is_the_spec() -> None:
    config = load_config(preset="kurdej2013")
    for (table, key), value in SPEC.items():
        assert config[table][key] == value, f"{table}.{key}"


def test_preset_is_applied_under_the_user_file(tmp_path: Path) -> None:
    path = write(tmp_path, "[fusion]\nzeta_increment = 0.3\n")
    config = load_config(path, preset="kurdej2013")
    assert config["fusion"]["zeta_increment"] == 0.3          # the user's file wins
    assert config["fusion"]["zeta_decrement"] == 0.5          # the preset's (SPEC) value
    assert config["sensor"]["free_margin_m"] == 0.0


def test_unknown_preset_names_the_shipped_ones() -> None:
    with pytest.raises(ConfigError, match="--preset paper: unknown preset .shipped: kurdej2013"):
        load_config(preset="paper")


@pytest.mark.parametrize("name", ["kurdej2013", "hdl64", "ibeo4", "vlp16"])
def test_packaged_preset_is_the_repo_file(name: str) -> None:
    from evperc.config import preset_path

    assert preset_path(name).resolve() == (REPO / "configs" / f"{name}.toml").resolve()


# the sensor presets' keys, written out here from docs/method.md and docs/evaluation.md (what
# was measured as configs/hdl64.toml, configs/ibeo4.toml and configs/vlp16.toml), not read
# from the files
SENSOR_PRESETS = {
    "hdl64": {("fusion", "gate_rehit_revokes"): "recent_returns",
              ("objects", "centroid"): "returns", ("objects", "centroid_max_cells"): 8,
              ("objects", "centroid_sigma_m"): 0.1,
              # as measured in 2026-12-06 (fifth session): any count of returns, one floor
              ("objects", "centroid_min_returns"): 0,
              ("objects", "centroid_returns_sigma_m"): 0.0},
    "ibeo4": {("objects", "moving_min_cluster_cells"): 3,
              ("objects", "moving_min_height_m"): 0.0,
              # as measured (2026-12-03): the cell centres' means
              ("objects", "centroid"): "cells"},
    "vlp16": {("objects", "growth_reach_cells"): 1, ("objects", "growth_early"): True,
              # as measured in 2026-12-06 (eleventh session): the cell centres' means
              ("objects", "centroid"): "cells",
              # 2026-12-07 (eleventh session): the chain's gap capped on the mapped road
              ("sensor", "ground_chain_gap_m"): 2.0,
              ("sensor", "ground_chain_gap_road_only"): True},
}


@pytest.mark.parametrize("name", sorted(SENSOR_PRESETS))
def test_sensor_preset_changes_its_keys_and_nothing_else(name: str) -> None:
    def flat(node, prefix=()):
        for k, v in node.items():
            yield from flat(v, (*prefix, k)) if isinstance(v, dict) else [((*prefix, k), v)]

    def same(a, b):  # NaN (an unset origin) equals NaN
        return a == b or (isinstance(a, float) and isinstance(b, float) and a != a and b != b)

    defaults, config = dict(flat(load_config())), dict(flat(load_config(preset=name)))
    changed = {key for key, value in config.items() if not same(value, defaults[key])}
    expected = SENSOR_PRESETS[name]
    assert changed == {key for key, value in expected.items() if defaults[key] != value}
    for key, value in expected.items():
        assert config[key] == value, key


@pytest.mark.parametrize("name", ["kurdej2013", "hdl64", "ibeo4", "vlp16"])
@pytest.mark.parametrize("user_text", [
    None,
    # a key of the hdl64 and vlp16 presets, a key of none, and an open table's own key
    "[objects]\ncentroid = \"cells\"\ngrowth_reach_cells = 2\n[grid]\nwindow_size_m = 60.0\n"
    "[map.road_width_m]\nfootway = 2.5\n",
])
def test_a_preset_put_under_a_loaded_user_file_is_the_preset_loaded_with_it(
        tmp_path: Path, name: str, user_text: str | None) -> None:
    # the sensor preset a run chooses once the log is open (evperc.runner) goes between the
    # defaults and the user's file, as --preset does: the file's keys win
    from evperc.config import with_preset

    path = write(tmp_path, user_text) if user_text is not None else None
    got = with_preset(load_config(path), name, path)
    assert dumps(got) == dumps(load_config(path, preset=name))
    if user_text is not None:
        assert got["objects"]["centroid"] == "cells" and got["objects"][
            "growth_reach_cells"] == 2
        assert got["map"]["road_width_m"]["footway"] == 2.5


def test_a_preset_under_a_user_file_keeps_keys_set_since() -> None:
    # evperc batch sets fusion.threads after loading: the preset, which does not set it,
    # leaves it; the input is not changed
    from evperc.config import with_preset

    config = load_config()
    config["fusion"]["threads"] = 1
    got = with_preset(config, "hdl64")
    assert got["fusion"]["threads"] == 1 and got["fusion"]["gate_rehit_revokes"] == (
        "recent_returns")
    assert config["fusion"]["gate_rehit_revokes"] == "block"


@pytest.mark.parametrize(("line", "match"), [
    ('seeds = "everything"', r"objects.seeds"),
    ("vacated_share = 0.0", r"objects.vacated_share = 0.0 is outside"),
    ("motion_evidence_frames = -1", r"objects.motion_evidence_frames = -1 is outside"),
    ("footprint_frames = -1", r"objects.footprint_frames = -1 is outside"),
    ("arrival_share = 1.5", r"objects.arrival_share = 1.5 is outside"),
    ("arrival_min_cells = -1", r"objects.arrival_min_cells = -1 is outside"),
    ("arrival_min_cells = 2.5", r"objects.arrival_min_cells"),
    ("ego_clearance_m = -1.0", r"objects.ego_clearance_m = -1.0 is outside"),
    ("fragment_gap_cells = -1", r"objects.fragment_gap_cells = -1 is outside"),
    ("fragment_extent_m = 0.0", r"objects.fragment_extent_m = 0.0 is outside"),
    ("box_length_m = -4.4", r"objects.box_length_m = -4.4 is outside"),
    ("box_width_m = 200.0", r"objects.box_width_m = 200.0 is outside"),
    ('box_min_length_m = "long"', r"objects.box_min_length_m"),
    ("box_min_width_m = -1.0", r"objects.box_min_width_m = -1.0 is outside"),
    ("single_conflict_max_cells = -1", r"objects.single_conflict_max_cells = -1 is outside"),
    ("single_conflict_max_cells = 1.5", r"objects.single_conflict_max_cells"),
    ("growth_kept_share = 1.5", r"objects.growth_kept_share = 1.5 is outside"),
    ("growth_kept_share = -0.1", r"objects.growth_kept_share = -0.1 is outside"),
    ("growth_more_cells = -1", r"objects.growth_more_cells = -1 is outside"),
    ("growth_more_cells = 2.5", r"objects.growth_more_cells"),
    ("growth_min_cells = -1", r"objects.growth_min_cells = -1 is outside"),
    ("growth_min_cells = 2.5", r"objects.growth_min_cells"),
    ("growth_reach_cells = -1", r"objects.growth_reach_cells = -1 is outside"),
    ('growth_early = "yes"', r"objects.growth_early"),
])
def test_object_evidence_keys_are_validated(tmp_path: Path, line: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_config(write(tmp_path, f"[objects]\n{line}\n"))


def test_object_evidence_keys_are_read(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, '[objects]\nseeds = "moving"\nfill_moving = false\n'))
    assert config["objects"]["seeds"] == "moving" and config["objects"]["fill_moving"] is False


def test_the_local_ground_step_is_validated(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"sensor.ground_local_raise_m = -0.1 is outside"):
        load_config(write(tmp_path, "[sensor]\nground_local_raise_m = -0.1\n"))
    with pytest.raises(ConfigError, match=r"sensor.ground_local_raise_m"):
        load_config(write(tmp_path, '[sensor]\nground_local_raise_m = "high"\n'))
    assert load_config(write(tmp_path, "[sensor]\nground_local_raise_m = 0.3\n"))[
        "sensor"]["ground_local_raise_m"] == 0.3


def test_the_range_dependent_centroid_noise_is_validated(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"objects.centroid_sigma_per_m = -0.01 is outside"):
        load_config(write(tmp_path, "[objects]\ncentroid_sigma_per_m = -0.01\n"))
    assert load_config(write(tmp_path, "[objects]\ncentroid_sigma_per_m = 0.02\n"))[
        "objects"]["centroid_sigma_per_m"] == 0.02
