"""One ROS 2 MCAP log rewritten as the other kinds of log evperc reads, with third-party
writers only (no evperc code):

- :func:`write_ros1_mcap` — ROS 1 encoded MCAP (``ros1msg`` schemas, ``ros1`` messages) with
  mcap-ros1-support's writer, as ``mcap convert drive.bag drive.mcap`` leaves a bag;
- :func:`write_rosbag1` — a ROS 1 ``.bag`` with rosbags' rosbag1 writer (``/tf_static``
  latched, as ROS 1's tf2 static publisher records it);
- :func:`write_rosbag2_sqlite` — a ROS 2 bag directory of ``.db3`` storage with rosbags'
  rosbag2 writer.

Each reads the ROS 2 messages with mcap-ros2-support, copies them field by field into rosbags'
message classes of the target distribution (ROS 1 Noetic: the Header gains ``seq``), and writes
them at the same log times in the same order.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

#: ROS 1 types rosbags' Noetic store lacks: tf2's and tf's TF message (both the same fields)
_ROS1_EXTRA = {"tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
               "tf/msg/tfMessage": "geometry_msgs/TransformStamped[] transforms\n"}
_NUMPY = {"bool": np.bool_, "int8": np.int8, "uint8": np.uint8, "byte": np.uint8,
          "char": np.uint8, "int16": np.int16, "uint16": np.uint16, "int32": np.int32,
          "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64, "float32": np.float32,
          "float64": np.float64}

Message = tuple[str, str, int, Any]  # topic, ROS 2 type name, log time ns, decoded message


def ros2_messages(mcap_path: str | Path) -> Iterator[Message]:
    """The decoded messages of a ROS 2 MCAP, in the order they are in the file."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with Path(mcap_path).open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(
                log_time_order=False):
            yield channel.topic, schema.name, message.log_time, decoded


def typestore(ros_version: int) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if ros_version == 2:
        return get_typestore(Stores.ROS2_HUMBLE)
    ts = get_typestore(Stores.ROS1_NOETIC)
    for name, text in _ROS1_EXTRA.items():
        ts.register(get_types_from_msg(text, name))
    return ts


def convert(msg: Any, typename: str, ts: Any) -> Any:
    """A rosbags message of ``typename`` in store ``ts`` with the fields of ``msg`` (an
    attribute-style message); fields ``msg`` lacks (ROS 1's ``seq``) are zero."""
    from rosbags.typesys.base import Nodetype

    def value(desc: tuple, v: Any) -> Any:
        kind, spec = desc
        if kind == Nodetype.BASE:
            if v is None:
                return "" if spec[0] == "string" else 0
            return v
        if kind == Nodetype.NAME:
            return convert(v, spec, ts)
        sub, _ = spec
        if sub[0] == Nodetype.BASE and sub[1][0] != "string":
            dtype = _NUMPY[sub[1][0]]
            if isinstance(v, bytes | bytearray | memoryview):
                return np.frombuffer(v, dtype=dtype).copy()
            return np.asarray(v if v is not None else [], dtype=dtype)
        return [value(sub, item) for item in (v or [])]

    _, fields = ts.fielddefs[typename]
    return ts.types[typename](**{name: value(desc, getattr(msg, name, None))
                                 for name, desc in fields})


def _ros1_name(typename: str) -> str:
    return typename.replace("/msg/", "/")


def _retyped(tf_type: str) -> Callable[[str], str]:
    return lambda t: tf_type if t == "tf2_msgs/msg/TFMessage" else t


def write_ros1_mcap(src: str | Path, out: str | Path, tf_type: str = "tf2_msgs/msg/TFMessage"
                    ) -> Path:
    """``src`` as a ROS 1 MCAP (mcap-ros1-support's writer; genpy message objects generated
    from the ROS 1 definitions)."""
    from mcap_ros1._vendor.genpy import dynamic
    from mcap_ros1.writer import Writer

    ts, retype, classes = typestore(1), _retyped(tf_type), {}
    out = Path(out)
    with out.open("wb") as f:
        writer = Writer(f)
        for topic, name, ns, msg in ros2_messages(src):
            typename = retype(name)
            if typename not in classes:
                text = ts.generate_msgdef(typename, ros_version=1)[0]
                ros1 = _ros1_name(typename)
                classes[typename] = dynamic.generate_dynamic(ros1, text)[ros1]
            genpy_msg = classes[typename]()
            genpy_msg.deserialize(bytes(ts.serialize_ros1(convert(msg, typename, ts), typename)))
            writer.write_message(topic, genpy_msg, log_time=ns, publish_time=ns)
        writer.finish()
    return out


def write_rosbag1(src: str | Path, out: str | Path, tf_type: str = "tf2_msgs/msg/TFMessage",
                  latched: tuple[str, ...] = ("/tf_static",),
                  static_stamp_ns: int | None = None) -> Path:
    """``src`` as a ROS 1 bag; ``latched`` topics get ``latching=1`` in their connection
    header; ``static_stamp_ns`` replaces the header stamps of /tf_static (a ROS 1 static
    publisher stamps its transforms when it starts, often long before the recording)."""
    from rosbags.rosbag1 import Writer

    ts, retype, connections = typestore(1), _retyped(tf_type), {}
    out = Path(out)
    with Writer(out) as writer:
        for topic, name, ns, msg in ros2_messages(src):
            typename = retype(name)
            if topic not in connections:
                connections[topic] = writer.add_connection(
                    topic, typename, typestore=ts, latching=1 if topic in latched else None)
            ros1 = convert(msg, typename, ts)
            if topic == "/tf_static" and static_stamp_ns is not None:
                for t in ros1.transforms:
                    t.header.stamp.sec, t.header.stamp.nanosec = divmod(static_stamp_ns,
                                                                        1_000_000_000)
            writer.write(connections[topic], ns, ts.serialize_ros1(ros1, typename))
    return out


def write_rosbag2_sqlite(src: str | Path, out_dir: str | Path) -> Path:
    """``src`` as a ROS 2 bag directory with sqlite3 (.db3) storage; returns the directory."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts, connections = typestore(2), {}
    out_dir = Path(out_dir)
    with Writer(out_dir, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        for topic, name, ns, msg in ros2_messages(src):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, name, typestore=ts)
            writer.write(connections[topic], ns, ts.serialize_cdr(convert(msg, name, ts), name))
    return out_dir
