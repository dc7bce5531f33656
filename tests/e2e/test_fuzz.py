"""Property tests: mangled MCAP bytes and random configs never give a traceback or a hang.

Every outcome must be exit code 0 (the reader used what was valid) or 2 (one-line error).
"""

from __future__ import annotations

import signal
import tomllib

import numpy as np
import pytest
import tomli_w
from click.testing import CliRunner
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from evperc.cli import cli
from evperc.config import default_config, load_config
from evperc.errors import ConfigError

from .scenes import write_street_drive

SMALL = {"grid": {"window_size_m": 20.0}}
SECONDS_PER_EXAMPLE = 20


@pytest.fixture(scope="module")
def good_log(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = write_street_drive(tmp_path_factory.mktemp("fuzz") / "d.mcap", n_scans=4, beams=90)
    return path.read_bytes()


class Hang(Exception):
    pass


def _alarm(signum, frame):  # noqa: ANN001
    raise Hang


def run_bounded(args: list[str]) -> tuple[int, str]:
    """Run the CLI; fail the test if it takes longer than SECONDS_PER_EXAMPLE."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(SECONDS_PER_EXAMPLE)
    try:
        result = CliRunner().invoke(cli, args)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    if isinstance(result.exception, Hang):
        pytest.fail(f"evperc {' '.join(args)} hung for more than {SECONDS_PER_EXAMPLE} s")
    return result.exit_code, result.output + repr(result.exception or "")


mutations = st.lists(
    st.tuples(st.sampled_from(["flip", "cut", "insert", "zero"]),
              st.floats(0, 1, allow_nan=False), st.binary(min_size=1, max_size=16)),
    min_size=1, max_size=4)


def mangle(data: bytes, ops: list[tuple[str, float, bytes]]) -> bytes:
    buf = bytearray(data)
    for kind, where, payload in ops:
        i = int(where * (len(buf) - 1)) if buf else 0
        if kind == "flip" and buf:
            buf[i] ^= payload[0] | 1
        elif kind == "cut":
            del buf[i:]
        elif kind == "insert":
            buf[i:i] = payload
        elif kind == "zero":
            buf[i:i + len(payload)] = bytes(len(buf[i:i + len(payload)]))
    return bytes(buf)


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ops=mutations)
# found by this test in CI: a pose decoded to ~1e300 m put the window beyond the integer
# lattice (OverflowError in the sensor grid, exit 1); such scans are now skipped
@example(ops=[("insert", 0.46875, b"\n")])
def test_mangled_logs_never_crash(good_log: bytes, ops, tmp_path_factory) -> None:
    tmp = tmp_path_factory.mktemp("m")
    log = tmp / "mangled.mcap"
    log.write_bytes(mangle(good_log, ops))
    config = tmp / "c.toml"
    config.write_text(tomli_w.dumps(SMALL))
    code, output = run_bounded(["run", str(log), "--no-map", "--config", str(config),
                                "--out", str(tmp / "out")])
    assert code in (0, 2), output
    assert "Traceback" not in output
    if code == 2:
        assert "evperc: error:" in output
    code, output = run_bounded(["info", str(log)])
    assert code in (0, 2), output


def _leaves(config: dict, prefix: str = "") -> list[tuple[str, object]]:
    out = []
    for key, value in config.items():
        if isinstance(value, dict):
            out += _leaves(value, f"{prefix}{key}.")
        else:
            out.append((f"{prefix}{key}", value))
    return out


LEAVES = _leaves(default_config())
values = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6),
                   st.booleans(), st.text(max_size=8), st.lists(st.integers(), max_size=2))


def _nest(pairs: dict[str, object]) -> dict:
    out: dict = {}
    for dotted, value in pairs.items():
        *tables, key = dotted.split(".")
        node = out
        for t in tables:
            node = node.setdefault(t, {})
        node[key] = value
    return out


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(picked=st.dictionaries(st.sampled_from([k for k, _ in LEAVES] + ["fusion.bogus"]),
                              values, max_size=4))
def test_random_configs_load_or_fail_cleanly(picked, tmp_path_factory) -> None:
    path = tmp_path_factory.mktemp("cfg") / "c.toml"
    try:
        path.write_text(tomli_w.dumps(_nest(picked)))
    except (TypeError, ValueError):
        return  # not representable in TOML (e.g. a key both table and value)
    try:
        config = load_config(path)
    except ConfigError as err:
        assert "\n" not in str(err)
        assert str(path) in str(err)
        return
    assert tomllib.loads(path.read_text()) is not None
    assert config["grid"]["cell_size_m"] > 0


@settings(max_examples=12, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(picked=st.dictionaries(st.sampled_from([k for k, _ in LEAVES
                                               if not k.startswith(("grid.", "sim."))]),
                              values, max_size=3))
def test_random_configs_through_the_cli(good_log: bytes, picked, tmp_path_factory) -> None:
    tmp = tmp_path_factory.mktemp("c")
    log = tmp / "d.mcap"
    log.write_bytes(good_log)
    config = _nest(picked)
    config.setdefault("grid", {})["window_size_m"] = 20.0
    path = tmp / "c.toml"
    try:
        path.write_text(tomli_w.dumps(config))
    except (TypeError, ValueError):
        return
    code, output = run_bounded(["run", str(log), "--no-map", "--config", str(path),
                                "--out", str(tmp / "out")])
    assert code in (0, 2), output
    assert "Traceback" not in output


def test_plausible_pose_refuses_non_finite_and_far_poses() -> None:
    from evperc.runner import MAX_POSE_M, plausible_pose

    T = np.eye(4)
    T[:3, 3] = (3.5e5, 6.7e6, 10.0)  # a UTM position
    assert plausible_pose(T)
    far, nan = T.copy(), T.copy()
    far[1, 3] = 2 * MAX_POSE_M
    nan[0, 0] = np.nan
    assert not plausible_pose(far) and not plausible_pose(nan)
