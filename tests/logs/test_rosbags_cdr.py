"""ROS 2 CDR messages of MCAP logs decoded with rosbags' deserialiser
(:func:`evperc.logs.mcap_source._rosbags_cdr`) against mcap-ros2's decoder, the independent
oracle: the same values in every field of every message of the sample drive (pose,
transforms, GNSS, point clouds); and mcap-ros2 taking over where rosbags cannot."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from evperc.logs.mcap_source import _rosbags_cdr

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data" / "drive.mcap"


def assert_same(ours: object, oracle: object, where: str) -> None:
    """Field by field (the oracle's fields; rosbags adds its constants and ``__msgtype__``);
    a ``uint8[]`` comes as a numpy array from rosbags and as ``bytes`` from mcap-ros2,
    fixed-size arrays as numpy arrays against lists: compared as values."""
    if isinstance(oracle, SimpleNamespace) or hasattr(oracle, "__slots__"):
        names = getattr(oracle, "__slots__", None) or vars(oracle).keys()
        for name in names:
            assert_same(getattr(ours, name), getattr(oracle, name), f"{where}.{name}")
    elif isinstance(oracle, bytes | bytearray):
        assert np.asarray(ours, np.uint8).tobytes() == bytes(oracle), where
    elif isinstance(oracle, list | tuple) or isinstance(ours, np.ndarray):
        assert len(ours) == len(oracle), where
        if len(oracle) and not isinstance(oracle[0], int | float | bool):
            for k, (a, b) in enumerate(zip(ours, oracle, strict=True)):
                assert_same(a, b, f"{where}[{k}]")
        else:
            np.testing.assert_array_equal(np.asarray(ours), np.asarray(oracle), err_msg=where)
    else:
        assert ours == oracle, where
        assert type(ours) is type(oracle) or isinstance(oracle, float | int), where


def test_every_message_of_the_sample_drive_decodes_as_mcap_ros2_does() -> None:
    kinds: dict[str, int] = {}
    with SAMPLE.open("rb") as f:
        decoders = {}
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.id not in decoders:
                oracle = DecoderFactory().decoder_for(channel.message_encoding, schema)
                ours = _rosbags_cdr(schema, oracle)
                assert ours is not oracle, schema.name  # rosbags reads every schema here
                decoders[channel.id] = (ours, oracle)
            ours, oracle = decoders[channel.id]
            assert_same(ours(message.data), oracle(message.data), schema.name)
            kinds[schema.name] = kinds.get(schema.name, 0) + 1
    assert {"sensor_msgs/msg/PointCloud2", "nav_msgs/msg/Odometry",
            "tf2_msgs/msg/TFMessage"} <= kinds.keys(), kinds


def test_a_schema_rosbags_cannot_parse_keeps_mcap_ros2() -> None:
    oracle = object()
    bad = SimpleNamespace(encoding="ros2msg", name="pkg/msg/Broken", data=b"floot64 x\n")
    assert _rosbags_cdr(bad, oracle) is oracle  # type: ignore[arg-type]
    other = SimpleNamespace(encoding="ros2idl", name="pkg/msg/X", data=b"")
    assert _rosbags_cdr(other, oracle) is oracle  # type: ignore[arg-type]


def test_a_message_rosbags_refuses_goes_to_mcap_ros2() -> None:
    """A truncated payload: rosbags raises, the fallback's answer (here its error) is what
    the caller gets, so the one-line error of the log reader stays mcap-ros2's."""
    with SAMPLE.open("rb") as f:
        schema, channel, message = next(iter(make_reader(f).iter_messages()))
    calls = []

    def fallback(data: bytes) -> object:
        calls.append(len(data))
        raise ValueError("mcap-ros2 refuses it too")

    ours = _rosbags_cdr(schema, fallback)
    with pytest.raises(ValueError, match="mcap-ros2 refuses"):
        ours(message.data[:7])
    assert calls == [7]
