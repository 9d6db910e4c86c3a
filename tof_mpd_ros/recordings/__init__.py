"""Recordings: rosbag2 MCAP files (``ros2 bag``/Foxglove/rosbags-compatible) and the NPZ
interchange.

* :class:`RecordingWriter` writes ToF frames (radial range, amplitude, CameraInfo, SL reference,
  arm pose) as CDR messages; :class:`RecordingReader` streams them back as
  :class:`~tof_mpd_ros.frame.ToFFrame` objects, also from files a crashed writer left behind.
* :func:`load_npz`, :func:`save_npz`, :func:`import_npz`, :func:`export_npz`: SPEC §3 interchange.

Nothing here imports rclpy; the ROS message definitions are embedded in :mod:`.msgdefs`.
"""

from __future__ import annotations

from .convert import RANGE_ENCODINGS
from .npz import export_npz, import_npz, load_npz, save_npz
from .reader import RecordedMessage, RecordingInfo, RecordingReader
from .topics import FrameIds, TopicNames
from .writer import RecordingWriter

__all__ = [
    "RANGE_ENCODINGS", "FrameIds", "RecordedMessage", "RecordingInfo", "RecordingReader",
    "RecordingWriter", "TopicNames", "export_npz", "import_npz", "load_npz", "save_npz",
]
