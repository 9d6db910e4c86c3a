"""Frames of an Analog Devices ToF module (ADTF3175 / ADSD3100 family) saved as ``.npy`` per
mode, as ToF frames for the NPZ interchange and the corrector.

The layout is the one of ``data/realdata/adi_tof_office``: per camera mode N,
``depth_modeN.npy`` (uint16 mm, 0 = invalid), ``amplitude_modeN.npy`` (uint16 active
brightness) and ``confidence_modeN.npy`` (uint8, higher = less reliable). What the frames mean is
established in :mod:`tof_mpd_ros.mismatch.realdata` (reading, masking and the measurements behind
them live there once; this module only turns them into full-resolution interchange frames):

* the depth is **radial range** (its planes are planar only so), which is what
  ``range_mm`` holds, so it is stored unchanged (uint16 mm -> float32 mm);
* a pixel whose confidence value exceeds ``max_confidence`` (default
  :data:`~tof_mpd_ros.mismatch.realdata.ADI_MAX_CONFIDENCE`, 4) is invalid (NaN), like a pixel
  of depth 0: above 4 the two modes' disagreement on static surfaces grows from 5-6 mm to tens
  and hundreds of mm. The interchange has no confidence field, so the confidence itself is not
  stored: it is applied;
* no intrinsics ship: a pinhole with the principal point at the image centre and a horizontal
  field of view of :data:`~tof_mpd_ros.mismatch.realdata.ADI_FOV_DEG` (75°) is an assumption,
  not a calibration (:func:`adi_intrinsics`);
* the modulation frequency is not recorded; ``mod_freq_hz`` is a placeholder
  (:data:`~tof_mpd_ros.frame.DEFAULT_MOD_FREQ_HZ`, the simulated cell's) that the corrector does
  not use.

Real time is not recorded either: every frame gets ``stamp_ns`` 0 unless told otherwise.
"""

from __future__ import annotations

from pathlib import Path

from ..camera import Intrinsics
from ..errors import RecordingError, TofMpdError
from ..frame import DEFAULT_MOD_FREQ_HZ, ToFFrame


def _realdata():
    # Imported when used: the mismatch package is heavy and imports the recordings package.
    from ..mismatch import realdata

    return realdata


def adi_intrinsics(width: int = 512, height: int = 512,
                   fov_deg: float | None = None) -> Intrinsics:
    """The assumed pinhole of the ADI frames: principal point at the image centre, square
    pixels, horizontal field of view ``fov_deg`` (None: ``ADI_FOV_DEG``, 75°).

    For 512 x 512 at 75°: fx = fy = 333.63 px, cx = cy = 255.5 px.
    """
    fov = _realdata().ADI_FOV_DEG if fov_deg is None else fov_deg
    return Intrinsics.from_fov(width, height, fov)


def adi_modes(directory: str | Path) -> tuple[int, ...]:
    """Camera modes with depth, amplitude and confidence files in ``directory`` (sorted)."""
    return _realdata().adi_modes(directory)


def read_adi(directory: str | Path, mode: int, *, max_confidence: int | None = None,
             fov_deg: float | None = None, mod_freq_hz: float = DEFAULT_MOD_FREQ_HZ,
             stamp_ns: int = 0) -> ToFFrame:
    """One mode of an ADI folder as a full-resolution ToF frame.

    Args:
        directory: folder with ``depth_modeN.npy``, ``amplitude_modeN.npy``,
            ``confidence_modeN.npy``.
        mode: camera mode N.
        max_confidence: pixels whose confidence value exceeds this are invalid; None =
            ``ADI_MAX_CONFIDENCE`` (4); 255 keeps every pixel of depth > 0.
        fov_deg: horizontal field of view of the assumed pinhole; None = ``ADI_FOV_DEG``.
        mod_freq_hz: modulation frequency written to the frame (not recorded by the camera).
        stamp_ns: the frame's stamp.

    Returns:
        A frame of the images' size: ``range_mm`` (H, W) float32 radial range in mm (the depth
        values unchanged), NaN where the depth is 0 or the confidence above the limit;
        ``amplitude`` (H, W) float32 active brightness in the camera's units, NaN at the same
        pixels; the assumed intrinsics.

    Raises:
        RecordingError: the mode's files are missing, unreadable or of different sizes.
    """
    realdata = _realdata()
    try:
        # A 1 x 1 "block reduction" is the identity: the full-resolution frame with the
        # mismatch tool's own reading, confidence limit and radial convention.
        range_mm, amplitude, intrinsics = realdata.adi_reduced(
            directory, mode, downsample=1,
            fov_deg=realdata.ADI_FOV_DEG if fov_deg is None else fov_deg,
            max_confidence=max_confidence)
        return ToFFrame(range_mm, amplitude, intrinsics, mod_freq_hz=mod_freq_hz,
                        stamp_ns=stamp_ns)
    except TofMpdError as err:
        raise RecordingError(str(err)) from err
