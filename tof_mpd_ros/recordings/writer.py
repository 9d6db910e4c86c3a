"""Write ToF frames to a rosbag2 MCAP recording (CDR messages encoded by ``mcap_ros2``).

Layout: ``<dir>/metadata.yaml`` + ``<dir>/<dir name>_0.mcap`` (profile ``ros2``, message encoding
``cdr``, schema encoding ``ros2msg``). Every :meth:`RecordingWriter.write_frame` closes an MCAP
chunk and flushes it to the operating system, so a writer killed with SIGKILL leaves a file whose
complete frames are all recoverable (:class:`~tof_mpd_ros.recordings.reader.RecordingReader`
reads files without a summary section). A write that fails (disk full, file size limit) cuts the
file back to the end of its last complete frame and closes the writer, so the same holds then.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import yaml
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

# mcap_ros2's CDR encoder factory (the function its Writer uses); we drive the plain mcap Writer
# ourselves because rosbag2 readers need QoS metadata on each channel and a chunk flush per frame.
from mcap_ros2._dynamic import EncoderFunction, serialize_dynamic

from .. import __version__
from ..errors import InputError, RecordingError
from ..frame import ToFFrame
from ..validation import check_array
from . import convert, metadata, msgdefs
from .topics import (
    KEY_MOD_FREQ,
    KEY_RANGE_CONVENTION,
    KEY_RANGE_ENCODING,
    KEY_VERSION,
    MCAP_METADATA_NAME,
    RADIAL,
    FrameIds,
    TopicNames,
)

_log = logging.getLogger(__name__)

_LIBRARY = f"tof_mpd_ros/{__version__}; mcap-python; mcap-ros2-support"
_COMPRESSION = {"zstd": CompressionType.ZSTD, "none": CompressionType.NONE,
                "lz4": CompressionType.LZ4}
DEFAULT_TOPICS = TopicNames()
DEFAULT_FRAME_IDS = FrameIds()
# hand-eye and TCP pose must compose to the frame's pose within this (m, and rotation entries).
_POSE_TOLERANCE = 1e-6
# metadata.yaml is rewritten at most this often while recording (and at open/close/new topic).
_METADATA_REFRESH_S = 5.0


class _FileSink:
    """The MCAP file, unbuffered: each write reaches the operating system whole or raises, and
    the file can be cut back to an earlier length.

    A buffered file would keep the bytes of a failed write and try them again on close, past a
    cut; here nothing is left behind.
    """

    def __init__(self, path: Path) -> None:
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data).cast("B")
        done = 0
        while done < len(view):  # a short write (the limit reached) is followed by the error
            done += os.write(self._fd, view[done:])
        self._position += done
        return done

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        """Nothing is buffered here."""

    def cut(self, size: int) -> None:
        """Truncate to ``size`` bytes and write on from there (shrinking needs no space)."""
        os.ftruncate(self._fd, size)
        os.lseek(self._fd, size, os.SEEK_SET)
        self._position = size

    def close(self) -> None:
        os.close(self._fd)


def mcap_file_name(directory: Path) -> str:
    """rosbag2's name of the first storage file: ``<dir name>_0.mcap``."""
    return f"{directory.name}_0.mcap"


class RecordingWriter:
    """Context manager writing one rosbag2 MCAP recording; refuses to overwrite.

    Args:
        path: the recording directory to create.
        compression: ``"zstd"`` (default), ``"lz4"`` or ``"none"`` MCAP chunk compression.
        topics: topic names.
        frame_ids: TF frame ids of the headers.
        range_encoding: ``"32FC1"`` (m), ``"16UC1"`` (mm, 0 = invalid) or ``"64FC1"`` (m,
            lossless for float32 mm) for the range and reference images.
        overwrite: replace an existing recording directory (only one holding metadata.yaml
            or ``.mcap`` files).
        custom_data: extra ``custom_data`` string pairs for metadata.yaml.
        chunk_size: MCAP chunk size in bytes (a chunk is also closed after every frame).

    Example::

        with RecordingWriter("run1", range_encoding="64FC1") as w:
            for frame in frames:
                w.write_frame(frame)
    """

    def __init__(self, path: str | Path, *, compression: str = "zstd",
                 topics: TopicNames = DEFAULT_TOPICS, frame_ids: FrameIds = DEFAULT_FRAME_IDS,
                 range_encoding: str = "32FC1", overwrite: bool = False,
                 custom_data: Mapping[str, str] | None = None,
                 chunk_size: int = 4 * 1024 * 1024) -> None:
        if compression not in _COMPRESSION:
            raise InputError(f"compression {compression!r} is not one of {sorted(_COMPRESSION)}")
        if range_encoding not in convert.RANGE_ENCODINGS:
            raise InputError(f"range_encoding {range_encoding!r} is not one of "
                             f"{convert.RANGE_ENCODINGS}")
        self.path = Path(path)
        self.topics = topics
        self.frame_ids = frame_ids
        self.range_encoding = range_encoding
        self._compression = compression
        self._chunk_size = chunk_size
        self._overwrite = overwrite
        self._custom: dict[str, str] = {
            KEY_VERSION: __version__, KEY_RANGE_CONVENTION: RADIAL,
            KEY_RANGE_ENCODING: range_encoding, **topics.as_custom_data(),
            **{str(k): str(v) for k, v in (custom_data or {}).items()}}
        self._file: _FileSink | None = None
        self._mcap: McapWriter | None = None
        self._schemas: dict[str, tuple[int, EncoderFunction]] = {}
        self._channels: dict[str, int] = {}
        self._types: dict[str, str] = {}  # topic -> msgtype, in first-write order
        self._counts: dict[str, int] = {}
        self._start_ns: int | None = None
        self._end_ns = 0
        self._mod_freq: float | None = None
        self._stamps: set[int] = set()
        self._metadata_written = 0.0
        # File length and bookkeeping at the end of the last complete frame: what a failed
        # write goes back to.
        self._good_size = 0
        self._good_state: tuple = ()

    # ------------------------------------------------------------------------ lifecycle

    @property
    def mcap_path(self) -> Path:
        return self.path / mcap_file_name(self.path)

    def open(self) -> RecordingWriter:
        """Create the directory, the MCAP file and a first metadata.yaml."""
        if self._mcap is not None:
            return self
        self._prepare_directory()
        try:
            self._file = _FileSink(self.mcap_path)  # closed in close()
            self._mcap = McapWriter(self._file, chunk_size=self._chunk_size,
                                    compression=_COMPRESSION[self._compression])
            self._mcap.start(profile="ros2", library=_LIBRARY)
            self._mcap.add_metadata(MCAP_METADATA_NAME, dict(self._custom))
            self._flush()
        except OSError as err:
            raise RecordingError(f"{self.mcap_path}: cannot create: {err}") from err
        self._write_metadata()
        return self

    def _prepare_directory(self) -> None:
        if self.path.exists():
            if not self._overwrite:
                raise RecordingError(f"{self.path}: already exists; refusing to overwrite "
                                     "(pass overwrite=True)")
            looks_like_recording = self.path.is_dir() and (
                (self.path / metadata.METADATA_FILE).exists() or any(self.path.glob("*.mcap"))
                or not any(self.path.iterdir()))
            if not looks_like_recording:
                raise RecordingError(f"{self.path}: exists and is not a recording; "
                                     "refusing to delete it")
            shutil.rmtree(self.path)
        try:
            self.path.mkdir(parents=True)
        except OSError as err:
            raise RecordingError(f"{self.path}: cannot create directory: {err}") from err

    def close(self) -> None:
        """Finish the MCAP (summary, indexes) and write the final metadata.yaml."""
        if self._mcap is None:
            return
        mcap_writer, self._mcap = self._mcap, None
        try:
            mcap_writer.add_metadata(MCAP_METADATA_NAME, dict(self._custom))
            # rosbag2's MCAP plugin stores its metadata in the file too (read by ros2 bag info
            # when given the .mcap alone).
            doc = self._metadata_document()["rosbag2_bagfile_information"]
            mcap_writer.add_metadata("rosbag2", {
                "serialized_metadata": yaml.safe_dump(doc, sort_keys=False),
                "ROS_DISTRO": metadata.ROS_DISTRO})
            mcap_writer.finish()
        except OSError as err:
            raise self._abandon(err, "finishing (summary)") from err
        assert self._file is not None
        self._file.close()
        self._file = None
        self._write_metadata()

    def __enter__(self) -> RecordingWriter:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        # Close even on error: everything written so far stays a valid recording.
        self.close()

    # ------------------------------------------------------------------------ writing

    def write(self, topic: str, msgtype: str, message: Any, stamp_ns: int, *,
              schema_text: str | None = None) -> None:
        """Write one message; its MCAP log and publish time are ``stamp_ns``.

        Args:
            topic: topic name.
            msgtype: ``pkg/msg/Type``.
            message: a dict tree (or object with attributes) of the message's fields.
            stamp_ns: integer nanoseconds.
            schema_text: ``ros2msg`` definition for a type not embedded in ``msgdefs``.

        Raises:
            InputError: unknown type without ``schema_text``, a topic reused with another
                type, or a message that does not fit the type.
            RecordingError: the writer is closed or the file cannot be written.
        """
        if self._mcap is None:
            raise RecordingError(f"{self.path}: recording is not open")
        stamp_ns = int(stamp_ns)
        if not 0 <= stamp_ns < 2**63:
            raise InputError(f"{topic}: stamp {stamp_ns} ns is negative or too large")
        if self._types.get(topic, msgtype) != msgtype:
            raise InputError(f"topic {topic} already holds {self._types[topic]}, "
                             f"not {msgtype}")
        schema_id, encode = self._schema(msgtype, schema_text)
        try:
            data = encode(message)
        except Exception as err:  # the CDR encoder raises anything on bad input
            raise InputError(f"{topic}: message does not fit {msgtype}: {err}") from err
        channel = self._channel(topic, schema_id, msgtype)
        try:
            self._mcap.add_message(channel, log_time=stamp_ns, data=data,
                                   publish_time=stamp_ns, sequence=self._counts.get(topic, 0))
        except OSError as err:  # a full chunk is written out here
            raise self._abandon(err, "write") from err
        new_topic = topic not in self._types
        self._types[topic] = msgtype
        self._counts[topic] = self._counts.get(topic, 0) + 1
        self._start_ns = stamp_ns if self._start_ns is None else min(self._start_ns, stamp_ns)
        self._end_ns = max(self._end_ns, stamp_ns)
        if new_topic:
            # A crash must still leave metadata.yaml listing every topic in use.
            self._write_metadata()

    def write_frame(self, frame: ToFFrame, *, tcp_pose: np.ndarray | None = None,
                    hand_eye: np.ndarray | None = None,
                    sl_points: np.ndarray | None = None) -> None:
        """Write one frame; every message carries the header stamp ``frame.stamp_ns``.

        Args:
            frame: the ToF frame; ``range_mm``/``reference_mm`` are radial range in mm,
                ``pose`` (camera-to-base, m) is written exactly to ``topics.camera_to_base``.
            tcp_pose: (4, 4) float64 TCP (flange) pose in the base frame, m.
            hand_eye: (4, 4) float64 camera pose in the flange frame, m.
            sl_points: (M, 3) float structured-light points in the camera frame, m.

        Raises:
            InputError: a repeated stamp, another modulation frequency than earlier frames,
                or ``tcp_pose @ hand_eye`` differing from ``frame.pose``.
        """
        if not isinstance(frame, ToFFrame):
            raise InputError(f"write_frame expects a ToFFrame, got {type(frame).__name__}")
        stamp = frame.stamp_ns
        self._check_frame(frame, tcp_pose, hand_eye)
        cam, names = self.frame_ids.camera, self.topics
        self._write_known(names.range, msgdefs.IMAGE, convert.range_image_dict(
            frame.range_mm, self.range_encoding, stamp, cam), stamp)
        self._write_known(names.amplitude, msgdefs.IMAGE, convert.image_dict(
            frame.amplitude, "32FC1", stamp, cam), stamp)
        self._write_known(names.camera_info, msgdefs.CAMERA_INFO, convert.camera_info_dict(
            frame.intrinsics, stamp, cam), stamp)
        if frame.reference_mm is not None:
            self._write_known(names.reference, msgdefs.IMAGE, convert.range_image_dict(
                frame.reference_mm, self.range_encoding, stamp, cam), stamp)
        if sl_points is not None:
            self._write_known(names.points, msgdefs.POINT_CLOUD2,
                              convert.point_cloud_dict(sl_points, stamp, cam), stamp)
        if tcp_pose is not None:
            self._write_known(names.tcp_pose, msgdefs.POSE_STAMPED, convert.pose_stamped_dict(
                tcp_pose, stamp, self.frame_ids.base), stamp)
        if hand_eye is not None:
            self._write_known(names.hand_eye, msgdefs.TRANSFORM_STAMPED,
                              convert.transform_stamped_dict(hand_eye, stamp,
                                                             self.frame_ids.flange, cam), stamp)
        if frame.pose is not None:
            self._write_known(names.camera_to_base, msgdefs.FLOAT64_MULTI_ARRAY,
                              convert.matrix_array_dict(frame.pose), stamp)
        self._flush()
        self._stamps.add(stamp)
        if time.monotonic() - self._metadata_written > _METADATA_REFRESH_S:
            self._write_metadata()  # keeps counts near-current for `ros2 bag info` after a crash

    def flush(self) -> None:
        """Close the current MCAP chunk and hand it to the operating system."""
        self._flush()

    # ------------------------------------------------------------------------ helpers

    def _write_known(self, topic: str, msgtype: str, message: Any, stamp_ns: int) -> None:
        self.write(topic, msgtype, message, stamp_ns)

    def _check_frame(self, frame: ToFFrame, tcp_pose: np.ndarray | None,
                     hand_eye: np.ndarray | None) -> None:
        """Reject a frame before any of its messages is written."""
        convert.stamp_dict(frame.stamp_ns)  # range check
        if frame.stamp_ns in self._stamps:
            raise InputError(f"{self.path}: a frame with stamp {frame.stamp_ns} ns was already "
                             "written; frames are paired by stamp, so stamps must be unique")
        if self._mod_freq is not None and float(frame.mod_freq_hz) != self._mod_freq:
            raise InputError(f"{self.path}: frame modulation frequency {frame.mod_freq_hz} Hz "
                             f"differs from the recording's {self._mod_freq} Hz")
        if frame.pose is not None and tcp_pose is not None and hand_eye is not None:
            composed = check_array("tcp_pose", tcp_pose, shape=(4, 4), ndim=2) @ check_array(
                "hand_eye", hand_eye, shape=(4, 4), ndim=2)
            if not np.allclose(composed, frame.pose, rtol=0.0, atol=_POSE_TOLERANCE):
                raise InputError("tcp_pose @ hand_eye differs from frame.pose by "
                                 f"{np.abs(composed - frame.pose).max():.3g} (> "
                                 f"{_POSE_TOLERANCE}); they must describe the same camera pose")
        if self._mod_freq is None:
            # The recording's modulation frequency is that of its first frame.
            self._mod_freq = float(frame.mod_freq_hz)
            self._custom[KEY_MOD_FREQ] = repr(self._mod_freq)
            if self._mcap is not None:
                self._mcap.add_metadata(MCAP_METADATA_NAME, dict(self._custom))

    def _schema(self, msgtype: str, schema_text: str | None) -> tuple[int, EncoderFunction]:
        """Schema id and CDR encoder of ``msgtype``, registering the schema on first use."""
        known = self._schemas.get(msgtype)
        if known is not None:
            return known
        if schema_text is None:
            if msgtype not in msgdefs.MSG_TEXT:
                raise InputError(f"message type {msgtype} has no embedded definition; "
                                 "pass schema_text")
            schema_text = msgdefs.schema_text(msgtype)
        try:
            encode = serialize_dynamic(msgtype, schema_text)[msgtype]
        except Exception as err:  # the msg parser raises anything on a bad definition
            raise InputError(f"cannot parse the definition of {msgtype}: {err}") from err
        assert self._mcap is not None
        schema_id = self._mcap.register_schema(msgtype, "ros2msg", schema_text.encode())
        self._schemas[msgtype] = (schema_id, encode)
        return schema_id, encode

    def _channel(self, topic: str, schema_id: int, msgtype: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            assert self._mcap is not None
            # What rosbag2's MCAP plugin stores per channel (rosbags matches topics by QoS).
            info = {"offered_qos_profiles": yaml.safe_dump(metadata.RECORDING_QOS,
                                                           sort_keys=False),
                    "topic_type_hash": msgdefs.TYPE_HASHES.get(msgtype, "")}
            channel = self._mcap.register_channel(topic, "cdr", schema_id, metadata=info)
            self._channels[topic] = channel
        return channel

    def _flush(self) -> None:
        if self._mcap is None or self._file is None:
            return
        try:
            self._mcap.flush()  # closes the chunk in progress and writes it out
        except OSError as err:
            raise self._abandon(err, "write") from err
        self._good_size = self._file.tell()
        self._good_state = (dict(self._types), dict(self._counts), self._start_ns,
                            self._end_ns)

    def _abandon(self, err: OSError, action: str) -> RecordingError:
        """After a failed write: cut the file back to the end of its last complete frame,
        close it and the writer, and say what is kept. Returns the error to raise."""
        self._mcap = None
        file, self._file = self._file, None
        try:
            if file is not None:
                file.cut(self._good_size)
                file.close()
        except OSError as cut_err:  # the reader still recovers the complete frames
            _log.warning("%s: cannot cut the failed write off: %s", self.mcap_path, cut_err)
        if self._good_state:
            types, counts, self._start_ns, self._end_ns = self._good_state
            self._types, self._counts = dict(types), dict(counts)
        try:
            self._write_metadata()
        except RecordingError as meta_err:  # the MCAP alone is readable
            _log.warning("%s", meta_err)
        reason = err.strerror or str(err)
        return RecordingError(f"{self.mcap_path}: {action} failed: {reason}; the "
                              f"{self.frame_count} complete frames written before are kept")

    def _metadata_document(self) -> dict[str, Any]:
        topics = [metadata.TopicStats(t, self._types[t], self._counts.get(t, 0))
                  for t in self._types]
        start = self._start_ns or 0
        return metadata.build(self.mcap_path.name, topics, start, self._end_ns, self._custom)

    def _write_metadata(self) -> None:
        metadata.write(self.path, self._metadata_document())
        self._metadata_written = time.monotonic()

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        return dict(self._counts)

    @property
    def frame_count(self) -> int:
        return len(self._stamps)
