"""Recordings: rosbag2 MCAP files (``ros2 bag``/Foxglove/rosbags-compatible) and the NPZ
interchange.

* :class:`RecordingWriter` writes ToF frames (radial range, amplitude, CameraInfo, SL reference,
  arm pose) as CDR messages; :class:`RecordingReader` streams them back as
  :class:`~tof_mpd_ros.frame.ToFFrame` objects, also from files a crashed writer left behind.
* :func:`load_npz`, :func:`save_npz`, :func:`import_npz`, :func:`export_npz`: the NPZ interchange
  (docs/recordings.md).
* :func:`iter_frames`, :func:`count_frames`, :func:`write_frames`: "a recording or an NPZ" file,
  told apart by :func:`is_npz`.

Nothing here imports rclpy; the ROS message definitions are embedded in :mod:`.msgdefs`.
"""

from __future__ import annotations

from .convert import RANGE_ENCODINGS
from .frame_files import count_frames, is_npz, iter_frames, write_frames
from .npz import export_npz, import_npz, load_npz, save_npz
from .reader import RecordedMessage, RecordingInfo, RecordingReader
from .topics import FrameIds, TopicNames
from .writer import RecordingWriter

__all__ = [
    "RANGE_ENCODINGS", "FrameIds", "RecordedMessage", "RecordingInfo", "RecordingReader",
    "RecordingWriter", "TopicNames", "count_frames", "export_npz", "import_npz", "is_npz",
    "iter_frames", "load_npz", "save_npz", "write_frames",
]
