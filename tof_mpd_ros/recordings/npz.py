"""The NPZ interchange (docs/recordings.md): load/save ``.npz`` files, convert to/from recordings.

One ``.npz`` holds N frames of one camera:

* ``range_mm``: (N, H, W) float32 radial range in mm, NaN = invalid;
* ``amplitude``: (N, H, W) float32;
* ``reference_mm``: (N, H, W) float32 radial range in mm, NaN = missing (optional);
* ``fx fy cx cy``: scalars, pixels of these H x W images; ``mod_freq_hz``: scalar, Hz;
* ``stamp_ns``: (N,) int64 (optional); ``pose``: (N, 4, 4) float64 camera-to-base, m (optional);
* ``sigma_mm``: (N, H, W) float32, written by ``tof-mpd correct`` with an fcn model (the
  predicted σ of the corrected range, mm); loading ignores it.

A single frame may drop the N axis. Files are loaded with ``allow_pickle=False``.

Importing with the default ``64FC1`` range encoding and exporting again reproduces every array
bit-exactly (NaN included); export always writes the N axis and ``stamp_ns``. Values the
recording defines as invalid come back as NaN: range/reference <= 0 or +-inf, amplitude +-inf.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic_file import write_atomically
from ..camera import Intrinsics
from ..errors import InputError, RecordingError
from ..frame import ToFFrame
from ..npz_file import read_npz
from .reader import RecordingReader
from .topics import TopicNames
from .writer import DEFAULT_TOPICS, RecordingWriter

_log = logging.getLogger(__name__)

IMAGE_KEYS = ("range_mm", "amplitude", "reference_mm")
SCALAR_KEYS = ("fx", "fy", "cx", "cy", "mod_freq_hz")
REQUIRED_KEYS = ("range_mm", "amplitude", *SCALAR_KEYS)
KNOWN_KEYS = (*IMAGE_KEYS, *SCALAR_KEYS, "stamp_ns", "pose")
# Synthesised stamps when the file has none: 30 frames per second from 0.
SYNTH_PERIOD_NS = 1_000_000_000 // 30


def load_npz(path: str | Path, *, start_ns: int = 0,
             period_ns: int = SYNTH_PERIOD_NS) -> list[ToFFrame]:
    """Read an interchange ``.npz`` into frames.

    Args:
        path: the ``.npz`` file.
        start_ns, period_ns: stamps given to the frames when the file has no ``stamp_ns``
            (``start_ns + i * period_ns``).

    Returns:
        N frames sharing one set of intrinsics.

    Raises:
        RecordingError: not a zip/npz, missing keys, wrong shapes or dtypes, non-finite or
            non-positive scalars, duplicate stamps, pickled (object) arrays.
    """
    path = Path(path)
    arrays = _read_arrays(path)
    single = arrays["range_mm"].ndim == 2
    images = {k: _image_stack(path, k, arrays[k], single) for k in IMAGE_KEYS if k in arrays}
    n, height, width = images["range_mm"].shape
    for key, stack in images.items():
        if stack.shape != images["range_mm"].shape:
            raise RecordingError(f"{path}: {key} has shape {arrays[key].shape} but range_mm has "
                                 f"{arrays['range_mm'].shape}")
    scalars = {k: _scalar(path, k, arrays[k]) for k in SCALAR_KEYS}
    try:
        intrinsics = Intrinsics(scalars["fx"], scalars["fy"], scalars["cx"], scalars["cy"],
                                width, height)
    except InputError as err:
        raise RecordingError(f"{path}: {err}") from err
    if not scalars["mod_freq_hz"] > 0:
        raise RecordingError(f"{path}: mod_freq_hz must be > 0, got {scalars['mod_freq_hz']}")
    stamps = _stamps(path, arrays.get("stamp_ns"), n, single, start_ns, period_ns)
    poses = _poses(path, arrays.get("pose"), n, single)
    reference = images.get("reference_mm")
    return [ToFFrame(images["range_mm"][i], images["amplitude"][i], intrinsics,
                     mod_freq_hz=scalars["mod_freq_hz"],
                     reference_mm=None if reference is None else reference[i],
                     stamp_ns=int(stamps[i]), pose=None if poses is None else poses[i])
            for i in range(n)]


def save_npz(path: str | Path, frames: Iterable[ToFFrame], *, overwrite: bool = False,
             extra: Mapping[str, np.ndarray] | None = None) -> int:
    """Write frames as an interchange ``.npz`` (always with the N axis, stamps included).

    Frames without a reference or pose get NaN-filled ones when other frames have them.

    Args:
        path: the ``.npz`` to write.
        frames: the frames (one camera).
        overwrite: replace an existing file.
        extra: more per-frame images written beside them (name -> (N, H, W), e.g.
            ``sigma_mm``), with names the format does not read (:func:`load_npz` ignores
            them).

    Returns:
        The number of frames written.

    Raises:
        InputError: no frames, frames with different intrinsics / modulation frequency, or an
            ``extra`` array of another shape or with a name the format uses.
        RecordingError: the file exists (and not ``overwrite``) or cannot be written.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise RecordingError(f"{path}: already exists; refusing to overwrite")
    arrays = frames_to_arrays(list(frames))
    for name, value in (extra or {}).items():
        if name in KNOWN_KEYS or np.shape(value) != arrays["range_mm"].shape:
            raise InputError(f"extra array {name!r} {np.shape(value)}: expected a new name and "
                             f"the frames' shape {arrays['range_mm'].shape}")
        arrays[name] = np.asarray(value, np.float32)
    try:
        write_atomically(path, lambda stream: np.savez(stream, **arrays))
    except OSError as err:
        raise RecordingError(f"{path}: cannot write: {err}") from err
    return int(arrays["range_mm"].shape[0])


def frames_to_arrays(frames: Sequence[ToFFrame]) -> dict[str, np.ndarray]:
    """The interchange arrays of frames sharing one camera (see the module docstring)."""
    if not frames:
        raise InputError("no frames to save")
    first = frames[0]
    for i, f in enumerate(frames):
        if f.intrinsics != first.intrinsics or f.mod_freq_hz != first.mod_freq_hz:
            raise InputError(f"frame {i} has intrinsics {f.intrinsics} at {f.mod_freq_hz} Hz, "
                             f"frame 0 {first.intrinsics} at {first.mod_freq_hz} Hz; one .npz "
                             "holds one camera")
    intr = first.intrinsics
    arrays: dict[str, np.ndarray] = {
        "range_mm": np.stack([f.range_mm for f in frames]).astype(np.float32, copy=False),
        "amplitude": np.stack([f.amplitude for f in frames]).astype(np.float32, copy=False),
        "fx": np.float64(intr.fx), "fy": np.float64(intr.fy), "cx": np.float64(intr.cx),
        "cy": np.float64(intr.cy), "mod_freq_hz": np.float64(first.mod_freq_hz),
        "stamp_ns": np.array([f.stamp_ns for f in frames], dtype=np.int64),
    }
    if any(f.reference_mm is not None for f in frames):
        arrays["reference_mm"] = np.stack([_or_nan(f.reference_mm, intr.shape, np.float32)
                                           for f in frames])
    if any(f.pose is not None for f in frames):
        arrays["pose"] = np.stack([_or_nan(f.pose, (4, 4), np.float64) for f in frames])
    for key in ("reference_mm", "pose"):
        missing = sum(getattr(f, key) is None for f in frames)
        if key in arrays and missing:
            _log.warning("%d of %d frames have no %s; written as NaN", missing, len(frames), key)
    return arrays


def import_npz(npz: str | Path, recording: str | Path, *, range_encoding: str = "64FC1",
               compression: str = "zstd", topics: TopicNames = DEFAULT_TOPICS,
               overwrite: bool = False, start_ns: int = 0,
               period_ns: int = SYNTH_PERIOD_NS) -> int:
    """Write the frames of an interchange ``.npz`` into a new recording.

    ``64FC1`` (default) keeps float32 millimetres bit-exact through the recording.

    Returns:
        The number of frames written.
    """
    frames = load_npz(npz, start_ns=start_ns, period_ns=period_ns)
    with RecordingWriter(recording, compression=compression, topics=topics,
                         range_encoding=range_encoding, overwrite=overwrite,
                         custom_data={"tof_mpd_ros.imported_from": Path(npz).name}) as writer:
        for frame in frames:
            writer.write_frame(frame)
    return len(frames)


def export_npz(recording: str | Path, npz: str | Path, *, overwrite: bool = False,
               on_error: str = "raise") -> int:
    """Write every frame of a recording to an interchange ``.npz``.

    Returns:
        The number of frames written.
    """
    with RecordingReader(recording, on_error=on_error) as reader:
        frames = list(reader.frames())
    if not frames:
        raise RecordingError(f"{recording}: holds no complete frames to export")
    return save_npz(npz, frames, overwrite=overwrite)


# ---------------------------------------------------------------------------------- helpers


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    with open(path, "rb") as stream:
        magic = stream.read(6)
    if magic == b"\x93NUMPY":
        raise RecordingError(f"{path}: is a single .npy array, not an .npz archive")
    if magic[:2] != b"PK":
        # said plainly here: the zip reader's own message would be cryptic
        raise RecordingError(f"{path}: is not an .npz (zip) file (starts with {magic!r})")
    arrays = read_npz(path, RecordingError)
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise RecordingError(f"{path}: missing key(s) {', '.join(missing)} (has "
                             f"{', '.join(sorted(arrays)) or 'none'})")
    extra = sorted(set(arrays) - set(KNOWN_KEYS))
    if extra:
        _log.info("%s: ignoring unknown keys %s", path, ", ".join(extra))
    return arrays


def _image_stack(path: Path, key: str, value: np.ndarray, single: bool) -> np.ndarray:
    """(N, H, W) float32 of an image key; float32 input passes through untouched."""
    if value.dtype.kind not in "fiu":
        raise RecordingError(f"{path}: {key} has dtype {value.dtype}; expected float32")
    expected_ndim = 2 if single else 3
    if value.ndim != expected_ndim or 0 in value.shape:
        raise RecordingError(f"{path}: {key} has shape {value.shape}; expected "
                             f"{'(H, W)' if single else '(N, H, W)'} like range_mm")
    if value.dtype != np.float32:
        _log.info("%s: converting %s from %s to float32", path, key, value.dtype)
    stack = value.astype(np.float32, copy=False)
    return stack[None] if single else stack


def _scalar(path: Path, key: str, value: np.ndarray) -> float:
    if value.dtype.kind not in "fiu" or value.size != 1 or value.ndim > 1:
        raise RecordingError(f"{path}: {key} must be a real scalar, got dtype {value.dtype} "
                             f"shape {value.shape}")
    out = float(value.reshape(()))
    if not np.isfinite(out):
        raise RecordingError(f"{path}: {key} is {out}; expected a finite number")
    return out


def _stamps(path: Path, value: np.ndarray | None, n: int, single: bool, start_ns: int,
            period_ns: int) -> np.ndarray:
    if value is None:
        return start_ns + period_ns * np.arange(n, dtype=np.int64)
    if value.dtype.kind not in "iu":
        raise RecordingError(f"{path}: stamp_ns has dtype {value.dtype}; expected int64 ns")
    stamps = value.reshape(-1) if (single and value.ndim == 0) else value
    if stamps.shape != (n,):
        raise RecordingError(f"{path}: stamp_ns has shape {value.shape}; expected ({n},)")
    stamps = stamps.astype(np.int64)
    if len(np.unique(stamps)) != n:
        raise RecordingError(f"{path}: stamp_ns holds duplicate stamps; frames are paired by "
                             "stamp, so each frame needs its own")
    if stamps.min() < 0:
        raise RecordingError(f"{path}: stamp_ns holds negative stamps")
    return stamps


def _poses(path: Path, value: np.ndarray | None, n: int, single: bool) -> np.ndarray | None:
    if value is None:
        return None
    if value.dtype.kind not in "fiu":
        raise RecordingError(f"{path}: pose has dtype {value.dtype}; expected float64")
    poses = value[None] if (single and value.shape == (4, 4)) else value
    if poses.shape != (n, 4, 4):
        raise RecordingError(f"{path}: pose has shape {value.shape}; expected ({n}, 4, 4)")
    return poses.astype(np.float64, copy=False)


def _or_nan(value: np.ndarray | None, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
    return np.full(shape, np.nan, dtype=dtype) if value is None else value.astype(dtype)
