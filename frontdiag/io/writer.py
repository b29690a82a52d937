"""Write small recordings in every container frontdiag reads.

Used by the simulator, the sample-log generator and the test fixtures. Messages are given as
plain nested dicts keyed by ROS field names; missing fields take their zero value, so the same
dict writes a ROS 1 message (with ``header.seq``) or a ROS 2 one. Field names match
case-insensitively, which covers CameraInfo's ``K``/``k`` split between ROS 1 and ROS 2.

Formats:

``bag``          ROS 1 bag file (rosbags)
``ros2-db3``     ROS 2 bag folder with sqlite3 storage (rosbags)
``ros2-mcap``    ROS 2 bag folder with MCAP storage (rosbags)
``mcap``         plain MCAP file, ROS 2 ``cdr`` encoding with ``ros2msg`` schemas (mcap)
``mcap-ros1``    plain MCAP file, ROS 1 encoding with ``ros1msg`` schemas (mcap)
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar, Literal

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

WriteFormat = Literal["bag", "ros2-db3", "ros2-mcap", "mcap", "mcap-ros1"]
WRITE_FORMATS: tuple[str, ...] = ("bag", "ros2-db3", "ros2-mcap", "mcap", "mcap-ros1")

_TS_ROS1: Typestore | None = None
_TS_ROS2: Typestore | None = None


def typestore(ros_version: int) -> Typestore:
    """Shared typestores (building one costs ~50 ms)."""
    global _TS_ROS1, _TS_ROS2
    from frontdiag.lidar import livox, velodyne

    if ros_version == 1:
        if _TS_ROS1 is None:
            _TS_ROS1 = get_typestore(Stores.ROS1_NOETIC)
            livox.register_types(_TS_ROS1, 1)
            velodyne.register_types(_TS_ROS1, 1)
        return _TS_ROS1
    if _TS_ROS2 is None:
        _TS_ROS2 = get_typestore(Stores.ROS2_HUMBLE)
        livox.register_types(_TS_ROS2, 2)
        velodyne.register_types(_TS_ROS2, 2)
    return _TS_ROS2


def normalise_msgtype(msgtype: str) -> str:
    """``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image``."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return msgtype


_ZERO_BASE: dict[str, Any] = {"string": "", "bool": False, "float32": 0.0, "float64": 0.0}


def _base_value(typ: str, value: Any) -> Any:
    if value is None:
        return _ZERO_BASE.get(typ, 0)
    if typ == "string":
        return str(value)
    if typ == "bool":
        return bool(value)
    if typ.startswith("float"):
        return float(value)
    return int(value)


_NUMPY_DTYPES = {
    "uint8": np.uint8, "int8": np.int8, "uint16": np.uint16, "int16": np.int16,
    "uint32": np.uint32, "int32": np.int32, "uint64": np.uint64, "int64": np.int64,
    "float32": np.float32, "float64": np.float64, "char": np.uint8, "byte": np.uint8,
    "bool": np.bool_,
}


def build_message(ts: Typestore, msgtype: str, values: Mapping[str, Any] | None) -> Any:
    """Build a typestore message object from a nested dict (missing fields are zero)."""
    msgtype = normalise_msgtype(msgtype)
    cls = ts.types[msgtype]
    _, fields = ts.fielddefs[msgtype]
    given = {k.lower(): v for k, v in (values or {}).items()}
    kwargs: dict[str, Any] = {}
    for name, (ntype, desc) in fields:
        value = given.get(name.lower())
        kwargs[name] = _build_field(ts, ntype, desc, value)
    return cls(**kwargs)


def _build_field(ts: Typestore, ntype: Nodetype, desc: Any, value: Any) -> Any:
    if ntype == Nodetype.BASE:
        return _base_value(desc[0], value)
    if ntype == Nodetype.NAME:
        if value is not None and not isinstance(value, Mapping):
            return value  # already a message object
        return build_message(ts, desc, value)
    # ARRAY or SEQUENCE
    (sub_ntype, sub_desc), length = desc
    if sub_ntype == Nodetype.BASE and sub_desc[0] in _NUMPY_DTYPES:
        dtype = _NUMPY_DTYPES[sub_desc[0]]
        if value is None:
            return np.zeros(length if ntype == Nodetype.ARRAY else 0, dtype=dtype)
        arr = np.frombuffer(value, dtype=np.uint8) if isinstance(value, bytes | bytearray) \
            else np.asarray(value)
        return np.ascontiguousarray(arr.reshape(-1).astype(dtype, copy=False))
    items = list(value or [])
    if ntype == Nodetype.ARRAY and not items:
        items = [None] * length
    return [_build_field(ts, sub_ntype, sub_desc, v) for v in items]


def stamp(t_ns: int) -> dict[str, int]:
    """A ``builtin_interfaces/Time`` dict from integer nanoseconds."""
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


class RecordingWriter:
    """Context manager writing messages to one recording.

    >>> with RecordingWriter(tmp / "run.mcap", "mcap") as w:   # doctest: +SKIP
    ...     w.write("/cam/image_raw", "sensor_msgs/msg/Image", {...}, t_ns)
    """

    COMPRESSIONS: ClassVar[dict[str, tuple[str, ...]]] = {
        "bag": ("bz2", "lz4"), "ros2-db3": ("file", "message"), "ros2-mcap": ("file", "message")}
    """``compression`` each format takes: a ROS 1 bag's chunks (bz2 or lz4); a ROS 2 bag with
    zstd, the whole file or each message (``ros2 bag record --compression-mode``). MCAP files
    compress their chunks with zstd always."""

    def __init__(self, path: Path | str, fmt: WriteFormat | str = "mcap",
                 chunk_bytes: int = 1024 * 1024, compression: str | None = None) -> None:
        if fmt not in WRITE_FORMATS:
            raise ValueError(f"unknown format {fmt!r}; choose one of {', '.join(WRITE_FORMATS)}")
        if compression is not None and compression not in self.COMPRESSIONS.get(fmt, ()):
            raise ValueError(f"format {fmt!r} takes compression "
                             f"{' or '.join(self.COMPRESSIONS.get(fmt, ())) or 'none'}")
        self.compression = compression
        self.path = Path(path)
        self.fmt = fmt
        self.ros_version = 1 if fmt in ("bag", "mcap-ros1") else 2
        self.ts = typestore(self.ros_version)
        self._writer: Any = None
        self._conns: dict[tuple[str, str], Any] = {}
        self._schemas: dict[str, int] = {}
        self.chunk_bytes = chunk_bytes  # 0: an unchunked MCAP (bags always have chunks)

    # -- context management -------------------------------------------------------------
    def __enter__(self) -> RecordingWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def open(self) -> None:
        if self.fmt == "bag":
            from rosbags.rosbag1 import Writer as Ros1Writer

            self._writer = Ros1Writer(self.path)
            self._writer.chunk_threshold = max(self.chunk_bytes, 1)
            if self.compression:
                self._writer.set_compression(
                    Ros1Writer.CompressionFormat[self.compression.upper()])
            self._writer.open()
        elif self.fmt in ("ros2-db3", "ros2-mcap"):
            from rosbags.rosbag2 import StoragePlugin
            from rosbags.rosbag2 import Writer as Ros2Writer

            plugin = StoragePlugin.SQLITE3 if self.fmt == "ros2-db3" else StoragePlugin.MCAP
            self._writer = Ros2Writer(self.path, version=9, storage_plugin=plugin)
            if self.compression:
                from rosbags.rosbag2 import CompressionFormat, CompressionMode

                self._writer.set_compression(CompressionMode[self.compression.upper()],
                                             CompressionFormat.ZSTD)
            self._writer.open()
        else:
            from mcap.writer import Writer as McapWriter

            self._fh = open(self.path, "wb")  # noqa: SIM115 - closed in close()
            # 1 MiB chunks: a recording cut short loses at most one chunk
            self._writer = McapWriter(self._fh, chunk_size=max(self.chunk_bytes, 1),
                                      use_chunking=self.chunk_bytes > 0)
            profile = "ros1" if self.fmt == "mcap-ros1" else "ros2"
            self._writer.start(profile=profile, library="frontdiag")

    def close(self) -> None:
        if self._writer is None:
            return
        if self.fmt in ("mcap", "mcap-ros1"):
            self._writer.finish()
            self._fh.close()
        else:
            self._writer.close()
        self._writer = None

    # -- writing --------------------------------------------------------------------------
    def _connection(self, topic: str, msgtype: str) -> Any:
        key = (topic, msgtype)
        if key in self._conns:
            return self._conns[key]
        if self.fmt in ("bag", "ros2-db3", "ros2-mcap"):
            conn = self._writer.add_connection(topic, msgtype, typestore=self.ts)
        else:
            if msgtype not in self._schemas:
                text, _ = self.ts.generate_msgdef(msgtype, ros_version=self.ros_version)
                name = msgtype.replace("/msg/", "/") if self.ros_version == 1 else msgtype
                enc = "ros1msg" if self.ros_version == 1 else "ros2msg"
                self._schemas[msgtype] = self._writer.register_schema(
                    name=name, encoding=enc, data=text.encode())
            conn = self._writer.register_channel(
                topic=topic, message_encoding="ros1" if self.ros_version == 1 else "cdr",
                schema_id=self._schemas[msgtype])
        self._conns[key] = conn
        return conn

    def serialize(self, msgtype: str, values: Mapping[str, Any] | Any) -> bytes:
        msgtype = normalise_msgtype(msgtype)
        msg = build_message(self.ts, msgtype, values) if isinstance(values, Mapping) else values
        if self.ros_version == 1:
            return bytes(self.ts.serialize_ros1(msg, msgtype))
        return bytes(self.ts.serialize_cdr(msg, msgtype))

    def write(self, topic: str, msgtype: str, values: Mapping[str, Any] | Any, t_ns: int) -> None:
        """Write one message logged at ``t_ns`` (integer nanoseconds)."""
        msgtype = normalise_msgtype(msgtype)
        self.write_raw(topic, msgtype, self.serialize(msgtype, values), t_ns)

    def write_raw(self, topic: str, msgtype: str, data: bytes, t_ns: int,
                  sequence: int = 0) -> None:
        """Write already-serialised bytes (also used to craft corrupt messages in tests);
        ``sequence``: the MCAP message's sequence number (other containers have none)."""
        msgtype = normalise_msgtype(msgtype)
        conn = self._connection(topic, msgtype)
        if self.fmt in ("mcap", "mcap-ros1"):
            self._writer.add_message(channel_id=conn, log_time=int(t_ns), data=data,
                                     publish_time=int(t_ns), sequence=int(sequence))
        else:
            self._writer.write(conn, int(t_ns), data)


# -- convenience builders for the message types frontdiag reads ----------------------------

def image_msg(gray_or_rgb: np.ndarray, encoding: str, t_ns: int, frame_id: str = "camera") -> dict:
    """``sensor_msgs/Image`` dict. ``encoding`` must describe the array's layout."""
    arr = np.ascontiguousarray(gray_or_rgb)
    h, w = arr.shape[:2]
    step = arr.strides[0]
    return {"header": {"stamp": stamp(t_ns), "frame_id": frame_id}, "height": h, "width": w,
            "encoding": encoding, "is_bigendian": 0, "step": step,
            "data": np.frombuffer(arr.tobytes(), dtype=np.uint8)}


def compressed_image_msg(data: bytes, fmt: str, t_ns: int, frame_id: str = "camera") -> dict:
    """``sensor_msgs/CompressedImage`` dict (``fmt`` is e.g. ``jpeg`` or ``png``)."""
    return {"header": {"stamp": stamp(t_ns), "frame_id": frame_id}, "format": fmt,
            "data": np.frombuffer(data, dtype=np.uint8)}


def camera_info_msg(K: np.ndarray, width: int, height: int, t_ns: int,
                    D: np.ndarray | None = None, model: str = "plumb_bob",
                    frame_id: str = "camera") -> dict:
    """``sensor_msgs/CameraInfo`` dict."""
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    P = np.zeros((3, 4))
    P[:, :3] = K
    D = np.zeros(5) if D is None else np.asarray(D, dtype=np.float64)
    return {"header": {"stamp": stamp(t_ns), "frame_id": frame_id}, "height": height,
            "width": width, "distortion_model": model, "d": D, "k": K.reshape(-1),
            "r": np.eye(3).reshape(-1), "p": P.reshape(-1)}
