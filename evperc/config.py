"""Configuration: defaults from ``configs/default.toml``, optionally a preset, a user file on
top, validation.

A *preset* is a shipped TOML file (``configs/<name>.toml``, listed in :data:`PRESETS`, packaged
as ``evperc/presets/<name>.toml``) applied between the defaults and the user's file:
``--preset kurdej2013`` is the paper's method as docs/method.md reads it (every mechanism evperc
adds switched off, every value the untuned one); ``--preset hdl64``, ``--preset ibeo4`` and
``--preset vlp16`` are the sensor files of configs/ (64-layer scanners such as KITTI's HDL-64E;
4-layer scanners; 16-layer scanners), so that an installed evperc has them without the
repository.

The default file is the schema: a user key must exist there (except in open tables such as
``map.road_width_m``) and have the same type. Ranges and choices are declared in
:data:`RULES`. Every failing key is reported at once, each with the bound it broke.
"""

from __future__ import annotations

import copy
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomli_w

from evperc.errors import ConfigError

DEFAULT_PATH = Path(__file__).with_name("default.toml")
PRESET_DIR = Path(__file__).with_name("presets")

#: shipped presets (``evperc run --preset NAME``), each ``PRESET_DIR/NAME.toml``
PRESETS = ("kurdej2013", "hdl64", "ibeo4", "vlp16")
#: ``--preset none``: configs/default.toml's values alone, whatever the lidar (no sensor
#: preset chosen from its layers)
NO_PRESET = "none"
#: (fewest, most layers, preset): the shipped preset tuned for a lidar of so many layers
#: (16: configs/vlp16.toml; 64 and denser: configs/hdl64.toml), which `evperc run` and
#: `evperc batch` take without --preset (:func:`preset_for_layers`, :func:`with_preset`);
#: none for fewer than 12 (the defaults were tuned on 4) nor for 25-47 (on a simulated
#: 32-layer scanner configs/hdl64.toml cost a held-out city 0.05 of moving precision:
#: docs/evaluation.md § History, eighth session of 2026-12-07)
LAYER_PRESETS = ((12, 24, "vlp16"), (48, 128, "hdl64"))

#: Tables whose keys are free (a user may add classes); values must be numbers.
OPEN_TABLES = {"map.road_width_m"}

_UNIT_INTERVAL = (0.0, 1.0)

#: key -> ("range", lo, hi, lo_open, hi_open) or ("choice", values...)
RULES: dict[str, tuple] = {
    "grid.cell_size_m": ("range", 0.01, 100.0, False, False),
    "grid.window_size_m": ("range", 1.0, 10_000.0, False, False),
    "sensor.mu_free": ("range", *_UNIT_INTERVAL, False, False),
    "sensor.mu_occupied": ("range", *_UNIT_INTERVAL, False, False),
    "sensor.min_range_m": ("range", 0.0, 1e4, False, False),
    "sensor.max_range_m": ("range", 0.0, 1e4, True, False),
    "sensor.azimuth_resolution_deg": ("range", 0.01, 45.0, False, False),
    "sensor.ground_threshold_m": ("range", 0.0, 10.0, False, False),
    "sensor.max_obstacle_height_m": ("range", 0.0, 100.0, True, False),
    "sensor.sensor_height_m": ("range", 0.0, 100.0, False, False),
    "sensor.ground_fallback": ("choice", "prior", "scan"),
    "sensor.ground_local_raise_m": ("range", 0.0, 10.0, False, False),
    "sensor.foot_lift_m": ("range", 0.0, 10.0, False, False),
    "sensor.ground_chain_gap_m": ("range", 0.0, 1e4, False, False),
    "sensor.ground_chain_gap_road_reach_m": ("range", 0.0, 100.0, False, False),
    "sensor.free_margin_m": ("range", 0.0, 10.0, False, False),
    "sensor.free_erosion_m": ("range", 0.0, 10.0, False, False),
    "map.beta_building": ("range", *_UNIT_INTERVAL, False, False),
    "map.beta_road": ("range", *_UNIT_INTERVAL, False, False),
    "map.beta_other": ("range", *_UNIT_INTERVAL, False, False),
    "map.tile_size_cells": ("range", 8, 8192, False, False),
    "map.default_road_width_m": ("range", 0.0, 200.0, False, False),
    "map.building_margin_m": ("range", 0.0, 20.0, False, False),
    "fusion.prior_where": ("choice", "observed", "everywhere"),
    "fusion.discount": ("choice", "contextual", "classical"),
    "fusion.discount_period_s": ("range", 0.0, 3600.0, True, False),
    "fusion.discount_free": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.discount_infrastructure": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.discount_unmapped": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.discount_stopped": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.discount_moving": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.discount_classical": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.residual_conflict": ("choice", "omega", "empty", "normalise"),
    "fusion.stopped_target": ("choice", "stopped", "empty"),
    "fusion.zeta_increment": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.zeta_decrement": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.gamma_occupied": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.gamma_conflict": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.threads": ("range", 0, 256, False, False),
    "fusion.motion_gate": ("choice", "ever_free", "none"),
    "fusion.gate_closed_target": ("choice", "occupied", "static"),
    "fusion.building_conflict": ("choice", "infrastructure", "moving"),
    "fusion.gate_free_s": ("range", 0.0, 3600.0, False, False),
    "fusion.gate_min_free": ("range", *_UNIT_INTERVAL, False, False),
    "fusion.gate_revoke_s": ("range", 0.0, 1e6, False, False),
    "fusion.gate_gap_s": ("range", 0.0, 3600.0, False, False),
    "fusion.gate_rehit_s": ("range", 0.0, 3600.0, False, False),
    "fusion.gate_rehit_gap": ("choice", "any", "seen_free"),
    "fusion.gate_rehit_revokes": ("choice", "block", "recent_returns"),
    "decision.min_betp": ("range", *_UNIT_INTERVAL, False, False),
    "decision.max_ignorance": ("range", *_UNIT_INTERVAL, False, False),
    "objects.min_cluster_cells": ("range", 1, 1_000_000, False, False),
    "objects.isolated_min_cells": ("range", 0, 1_000_000, False, False),
    "objects.isolated_clearance_m": ("range", 0.0, 100.0, False, False),
    "objects.isolated_min_height_m": ("range", 0.0, 100.0, False, False),
    "objects.small_conflict_min_cells": ("range", 0, 1_000_000, False, False),
    "objects.moving_min_cluster_cells": ("range", 0, 1_000_000, False, False),
    "objects.split_min_overlap_cells": ("range", 0, 1_000_000, False, False),
    "objects.split_speed_difference_m_per_s": ("range", 0.0, 100.0, False, False),
    "objects.off_buildings_small_m": ("range", 0.0, 1e4, False, False),
    "objects.off_buildings_max_height_m": ("range", 0.0, 1e3, False, False),
    "objects.max_cluster_extent_m": ("range", 0.0, 1e4, True, False),
    "objects.seed_conflict_fo": ("range", *_UNIT_INTERVAL, False, False),
    "objects.gate_m": ("range", 0.0, 1e3, True, False),
    "objects.confirm_frames": ("range", 1, 10_000, False, False),
    "objects.max_missed_frames": ("range", 0, 10_000, False, False),
    "objects.history_frames": ("range", 2, 1_000, False, False),
    "objects.moving_speed_m_per_s": ("range", 0.0, 100.0, False, False),
    "objects.motion_test": ("range", 0.0, 1e6, False, False),
    "objects.centroid_sigma_m": ("range", 0.0, 100.0, True, False),
    "objects.centroid_sigma_per_m": ("range", 0.0, 1.0, False, False),
    "objects.seeds": ("choice", "occupied", "moving"),
    "objects.cluster_on": ("choice", "first_returns", "all_returns", "all_returns_join"),
    "objects.centroid": ("choice", "cells", "returns"),
    "objects.centroid_max_cells": ("range", 0, 1_000_000, False, False),
    "objects.centroid_min_returns": ("range", 0, 1_000_000, False, False),
    "objects.centroid_depth_m": ("range", 0.0, 10.0, False, False),
    "objects.centroid_returns_sigma_m": ("range", 0.0, 100.0, False, False),
    "objects.backfill_candidate_frames": ("range", -1, 1_000_000, False, False),
    "objects.motion_evidence_frames": ("range", 0, 10_000, False, False),
    "objects.conflict_cells": ("range", 1, 1_000_000, False, False),
    "objects.single_conflict_max_cells": ("range", 0, 1_000_000, False, False),
    "objects.vacated_frames": ("range", 1, 1_000, False, False),
    "objects.vacated_share": ("range", *_UNIT_INTERVAL, True, False),
    "objects.growth_kept_share": ("range", *_UNIT_INTERVAL, False, False),
    "objects.growth_more_cells": ("range", 0, 1_000_000, False, False),
    "objects.growth_min_cells": ("range", 0, 1_000_000, False, False),
    "objects.growth_reach_cells": ("range", 0, 100, False, False),
    "objects.point_reach_cells": ("range", 0, 100, False, False),
    "objects.point_height_margin_m": ("range", 0.0, 100.0, False, False),
    "objects.footprint_frames": ("range", 0, 1_000, False, False),
    "objects.backfill_frames": ("range", 0, 100, False, False),
    "objects.bridge_reach_cells": ("range", 0, 10, False, False),
    "objects.lead_frames": ("range", 0, 100, False, False),
    "objects.lead_reach_cells": ("range", 0, 10, False, False),
    "objects.small_support_frames": ("range", 0, 100, False, False),
    "objects.small_support_reach_cells": ("range", 0, 100, False, False),
    "objects.small_support_min_frames": ("range", 1, 200, False, False),
    "objects.facade_max_speed_m_per_s": ("range", 0.0, 1000.0, False, False),
    "objects.moving_min_height_m": ("range", 0.0, 100.0, False, False),
    "objects.arrival_share": ("range", *_UNIT_INTERVAL, False, False),
    "objects.arrival_min_cells": ("range", 0, 1_000_000, False, False),
    "objects.ego_clearance_m": ("range", 0.0, 100.0, False, False),
    "objects.fragment_gap_cells": ("range", 0, 100, False, False),
    "objects.fragment_extent_m": ("range", 0.0, 100.0, True, False),
    "objects.box_length_m": ("range", 0.0, 100.0, False, False),
    "objects.box_width_m": ("range", 0.0, 100.0, False, False),
    "objects.box_min_length_m": ("range", 0.0, 100.0, False, False),
    "objects.box_min_width_m": ("range", 0.0, 100.0, False, False),
    "objects.unmapped_max_width_m": ("range", 0.0, 100.0, True, False),
    "objects.unmapped_min_age_s": ("range", 0.0, 3600.0, False, False),
    "input.max_pose_gap_s": ("range", 0.0, 1e6, True, False),
    "input.pose_check": ("choice", "warn", "error", "off"),
    "input.origin_lat_deg": ("range", -90.0, 90.0, False, False),
    "input.origin_lon_deg": ("range", -180.0, 180.0, False, False),
    "input.origin_heading_deg": ("range", -360.0, 360.0, False, False),
    "output.chunk_frames": ("range", 1, 100_000, False, False),
    "output.chunk_max_mb": ("range", 1.0, 1e5, False, False),
    "output.checkpoint_frames": ("range", 1, 10_000_000, False, False),
    "sim.moving_cars": ("range", 0, 1000, False, False),
    "sim.pedestrians": ("range", 0, 1000, False, False),
    "sim.parked_car_spacing_m": ("range", 1.0, 1e6, False, False),
    "sim.furniture_spacing_m": ("range", 1.0, 1e6, False, False),
    "sim.ego_max_speed_m_per_s": ("range", 0.0, 40.0, False, False),
    "sim.range_noise_m": ("range", 0.0, 10.0, False, False),
    "sim.dropout": ("range", 0.0, 1.0, False, True),
    "sim.pose_noise_m": ("range", 0.0, 100.0, False, False),
    "sim.pose_noise_deg": ("range", 0.0, 180.0, False, False),
    "sim.gnss_noise_m": ("range", 0.0, 100.0, False, False),
    "sim.start_lat_deg": ("range", -90.0, 90.0, False, False),
    "sim.start_lon_deg": ("range", -180.0, 180.0, False, False),
}

#: keys whose value may be NaN, meaning "not set"
NULLABLE = {"input.origin_lat_deg", "input.origin_lon_deg", "sim.range_noise_m", "sim.dropout",
            "sim.start_lat_deg", "sim.start_lon_deg"}


def default_config() -> dict[str, Any]:
    """The defaults as a nested dict (a fresh copy)."""
    with DEFAULT_PATH.open("rb") as f:
        return tomllib.load(f)


def preset_for_layers(layers: int) -> str | None:
    """The shipped preset tuned for a lidar of ``layers`` layers (:data:`LAYER_PRESETS`)."""
    return next((p for lo, hi, p in LAYER_PRESETS if lo <= layers <= hi), None)


def with_preset(config: dict[str, Any], preset: str, user_path: str | Path | None = None
                ) -> dict[str, Any]:
    """``config`` — the defaults under the user's file at ``user_path`` (None: no file), as
    :func:`load_config` made it, perhaps adjusted since — with the keys of the shipped preset
    ``preset`` between the two: each key the preset sets takes the preset's value unless the
    user's file sets it. Equal to ``load_config(user_path, preset=preset)`` for a
    ``config`` that is ``load_config(user_path)``; keys changed after loading that neither
    file sets are kept (``evperc batch``'s ``fusion.threads``). A new dict."""
    out = copy.deepcopy(config)
    user = _flat(_read_toml(Path(user_path))) if user_path is not None else {}
    for dotted, value in _flat(_read_toml(preset_path(preset))).items():
        if dotted not in user:
            _set(out, dotted, value)
    problems = validate(out)
    if problems:
        raise ConfigError(f"{preset_path(preset)}: " + "; ".join(problems))
    return out


def _flat(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A TOML document's values by dotted key (``objects.centroid``; an open table's, such
    as ``map.road_width_m.footway``, one by one, as :func:`_merge` sets them)."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flat(value, f"{dotted}."))
        else:
            out[dotted] = value
    return out


def preset_path(name: str) -> Path:
    """The file of the shipped preset ``name``; ConfigError naming the presets if unknown."""
    if name not in PRESETS:
        raise ConfigError(f"--preset {name}: unknown preset (shipped: {', '.join(PRESETS)})")
    return PRESET_DIR / f"{name}.toml"


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError as err:
        raise ConfigError(f"{path}: config file not found") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML ({err})") from err
    except OSError as err:
        raise ConfigError(f"{path}: cannot read config ({err.strerror})") from err


def load_config(path: str | Path | None = None, overrides: Mapping[str, Any] | None = None,
                preset: str | None = None) -> dict[str, Any]:
    """Defaults, updated by the preset ``preset`` (:data:`PRESETS`), then by the TOML file at
    ``path`` and by dotted-key ``overrides``; validated.

    Raises :class:`ConfigError` naming the file and every bad key.
    """
    config = default_config()
    source = "the defaults"
    merge_problems = []
    if preset is not None:
        p = preset_path(preset)
        source = str(p)
        merge_problems += _merge(config, _read_toml(p), prefix="")
    if path is not None:
        path = Path(path)
        source = str(path) if preset is None else f"{p} + {path}"
        merge_problems += _merge(config, _read_toml(path), prefix="")
    for dotted, value in (overrides or {}).items():
        _set(config, dotted, value)
    problems = merge_problems + validate(config)
    if problems:
        raise ConfigError(f"{source}: " + "; ".join(problems))
    return config


def _set(config: dict[str, Any], dotted: str, value: Any) -> None:
    """Set the key ``dotted`` (``objects.centroid``) of ``config`` to ``value``."""
    *tables, key = dotted.split(".")
    node = config
    for t in tables:
        node = node[t]
    node[key] = value


def _merge(base: dict[str, Any], user: Mapping[str, Any], prefix: str) -> list[str]:
    """Update ``base`` in place from ``user``; return the unknown keys and type errors."""
    problems = []
    for key, value in user.items():
        dotted = f"{prefix}{key}"
        if prefix.rstrip(".") in OPEN_TABLES:
            if not isinstance(value, int | float) or isinstance(value, bool):
                problems.append(f"{dotted} must be a number, got {value!r}")
            else:
                base[key] = float(value)
            continue
        if key not in base:
            close = [k for k in base if k.split("_")[0] == key.split("_")[0]]
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            problems.append(f"unknown key {dotted}{hint}")
            continue
        default = base[key]
        if isinstance(default, dict):
            if not isinstance(value, dict):
                problems.append(f"{dotted} must be a table")
            else:
                problems.extend(_merge(default, value, prefix=f"{dotted}."))
            continue
        coerced = _coerce(default, value)
        if coerced is None:
            problems.append(
                f"{dotted} must be {type(default).__name__}, got {type(value).__name__} {value!r}")
        else:
            base[key] = coerced
    return problems


def _coerce(default: Any, value: Any) -> Any:
    if isinstance(default, bool):
        return value if isinstance(value, bool) else None
    if isinstance(default, float):
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        return None
    if isinstance(default, int):
        return value if isinstance(value, int) and not isinstance(value, bool) else None
    if isinstance(default, str):
        return value if isinstance(value, str) else None
    return value


def validate(config: Mapping[str, Any]) -> list[str]:
    """Every broken range or choice in ``config``, as messages naming the dotted key."""
    problems = []
    for dotted, rule in RULES.items():
        value = get(config, dotted)
        if rule[0] == "choice":
            if value not in rule[1:]:
                problems.append(f"{dotted} = {value!r} is not one of {', '.join(rule[1:])}")
            continue
        _, lo, hi, lo_open, hi_open = rule
        if isinstance(value, float) and math.isnan(value):
            if dotted not in NULLABLE:
                problems.append(f"{dotted} must be a number, got nan")
            continue
        if (value < lo or (lo_open and value == lo)) or (value > hi or (hi_open and value == hi)):
            lb = "(" if lo_open else "["
            rb = ")" if hi_open else "]"
            problems.append(f"{dotted} = {value!r} is outside {lb}{lo}, {hi}{rb}")
    sensor = config["sensor"]
    if sensor["min_range_m"] >= sensor["max_range_m"]:
        problems.append("sensor.min_range_m must be below sensor.max_range_m")
    if config["grid"]["window_size_m"] < 2 * config["grid"]["cell_size_m"]:
        problems.append("grid.window_size_m must hold at least two cells")
    for cls, width in config["map"]["road_width_m"].items():
        if not 0.0 <= width <= 200.0:
            problems.append(f"map.road_width_m.{cls} = {width!r} is outside [0.0, 200.0]")
    return problems


def get(config: Mapping[str, Any], dotted: str) -> Any:
    """``get(cfg, "fusion.zeta_increment")`` — a value by its dotted key."""
    node: Any = config
    for part in dotted.split("."):
        node = node[part]
    return node


def dumps(config: Mapping[str, Any]) -> str:
    """The config as TOML text (NaN written as ``nan``), to store beside a result."""
    return tomli_w.dumps(copy.deepcopy(dict(config)))
