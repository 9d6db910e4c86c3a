"""Golden frames: path-traced reference images of cell scenes, and helpers to compare with them.

Pure numpy (no mitsuba): the simulator's tests load the committed files in
``test/sim/data/golden/`` (made by ``benchmarks/render_golden_frames.py``) without the
``[pathtrace]`` extra.

File format (``.npz``, ``np.savez_compressed``, readable with ``allow_pickle=False``):

* ``meta``: 0-d unicode array holding a JSON object — ``name``, ``description``, ``scene``
  (:meth:`Scene.as_dict`), ``camera_to_base_mm`` (4×4 nested list, mm), ``intrinsics``
  (:meth:`Intrinsics.as_dict`), ``mod_freq_hz``, ``light`` (:meth:`SpotLight.as_dict`),
  ``spp`` and ``max_depth`` (each a dict with keys ``all``, ``one_bounce``, ``direct``),
  ``seed``, ``versions`` (mitsuba, mitransient, drjit), ``command``, ``cpu_model``,
  ``render_seconds`` (per image), ``noise`` (summary statistics, mm).
* images, all (H, W): ``range_all_mm``, ``range_one_bounce_mm``, ``range_direct_mm`` (float32
  radial range in mm, NaN = no light), ``amplitude_all`` (float32, simulator amplitude units:
  π × radiance × light power), ``true_range_mm`` (float32, the ray caster's centre-ray range,
  NaN = no hit), ``range_all_noise_mm`` and ``range_one_bounce_noise_mm`` (float16 rounded to 4
  mantissa bits, standard error of each pixel's range from the spread of independent render
  passes, mm).
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...camera import Intrinsics
from ...errors import InputError, RecordingError
from ...validation import check_array
from ..scene import Scene
from .light import SpotLight

#: image arrays of a golden file and the dtype each is stored in
IMAGE_DTYPES: dict[str, type] = {
    "range_all_mm": np.float32,
    "range_one_bounce_mm": np.float32,
    "range_direct_mm": np.float32,
    "amplitude_all": np.float32,
    "true_range_mm": np.float32,
    "range_all_noise_mm": np.float16,
    "range_one_bounce_noise_mm": np.float16,
}
#: the noise maps, stored with :data:`NOISE_MANTISSA_BITS` mantissa bits
NOISE_KEYS = ("range_all_noise_mm", "range_one_bounce_noise_mm")
#: a standard error estimated from ~128 passes is itself uncertain by ~6 %: 4 bits (6 % steps)
NOISE_MANTISSA_BITS = 4
#: side of the square window of :func:`multipath_field`, pixels
FIELD_WINDOW_PX = 5


@dataclass(frozen=True)
class GoldenFrame:
    """One path-traced golden frame and everything needed to re-render it.

    Attributes:
        name: file stem, e.g. ``"cube_300"``.
        description: what the scene is, one sentence.
        scene: the scene (base frame, mm), rebuilt with :meth:`Scene.from_dict`.
        camera_to_base_mm: (4, 4) float64 camera optical frame -> base frame, mm.
        intrinsics: the image grid (the cell's 180x140 crop).
        mod_freq_hz: modulation frequency, Hz.
        light: the spot light at the camera centre.
        spp: samples per pixel per image: keys ``all``, ``one_bounce``, ``direct``.
        max_depth: Mitsuba path depth per image (2 = direct only, 3 = one bounce), same keys.
        seed: base seed of the renders.
        versions: mitsuba / mitransient / drjit versions that rendered it.
        command: the command line that wrote the file.
        cpu_model: the machine's CPU (``lscpu`` model name).
        render_seconds: wall time per image, s.
        noise: summary statistics of the range noise, mm.
        range_all_mm: (H, W) float32 range with all bounces, mm; NaN = no light.
        range_one_bounce_mm: (H, W) float32 range with direct + exactly one indirect bounce, mm.
        range_direct_mm: (H, W) float32 range of the direct light only (box pixel footprint), mm.
        amplitude_all: (H, W) float32 amplitude with all bounces, simulator amplitude units.
        true_range_mm: (H, W) float32 ray-cast centre-ray range, mm; NaN = no hit.
        range_all_noise_mm: (H, W) float32 standard error of ``range_all_mm``, mm.
        range_one_bounce_noise_mm: (H, W) float32 standard error of ``range_one_bounce_mm``, mm.
    """

    name: str
    description: str
    scene: Scene
    camera_to_base_mm: np.ndarray
    intrinsics: Intrinsics
    mod_freq_hz: float
    light: SpotLight
    spp: dict[str, int]
    max_depth: dict[str, int]
    seed: int
    versions: dict[str, str]
    command: str
    cpu_model: str
    render_seconds: dict[str, float]
    noise: dict[str, float]
    range_all_mm: np.ndarray
    range_one_bounce_mm: np.ndarray
    range_direct_mm: np.ndarray
    amplitude_all: np.ndarray
    true_range_mm: np.ndarray
    range_all_noise_mm: np.ndarray
    range_one_bounce_noise_mm: np.ndarray

    def meta(self) -> dict[str, Any]:
        """The JSON-ready metadata stored in the file's ``meta`` entry."""
        return {
            "name": self.name, "description": self.description, "scene": self.scene.as_dict(),
            "camera_to_base_mm": np.asarray(self.camera_to_base_mm, dtype=np.float64).tolist(),
            "intrinsics": self.intrinsics.as_dict(), "mod_freq_hz": float(self.mod_freq_hz),
            "light": self.light.as_dict(), "spp": dict(self.spp), "max_depth": dict(self.max_depth),
            "seed": int(self.seed), "versions": dict(self.versions), "command": self.command,
            "cpu_model": self.cpu_model, "render_seconds": dict(self.render_seconds),
            "noise": dict(self.noise),
        }


def write_golden(path: str | os.PathLike[str], frame: GoldenFrame, *,
                 overwrite: bool = False) -> Path:
    """Write a golden frame as a compressed ``.npz`` (format: module docstring).

    Args:
        path: destination file (``.npz``).
        frame: the frame; every image must be (H, W) of ``frame.intrinsics``.
        overwrite: replace an existing file (refused otherwise).

    Returns:
        The path written.

    Raises:
        RecordingError: the file exists and ``overwrite`` is False.
        InputError: an image has the wrong shape.
    """
    out = Path(path)
    if out.exists() and not overwrite:
        raise RecordingError(f"{out} exists; pass overwrite=True to replace it")
    shape = frame.intrinsics.shape
    arrays = {key: check_array(key, getattr(frame, key), ndim=2, shape=shape,
                               dtype_kind="f").astype(dtype)
              for key, dtype in IMAGE_DTYPES.items()}
    for key in NOISE_KEYS:
        arrays[key] = _coarse_float16(arrays[key])
    meta = np.array(json.dumps(frame.meta(), sort_keys=True))
    np.savez_compressed(out, meta=meta, **arrays)
    return out


def _coarse_float16(values: np.ndarray) -> np.ndarray:
    """(H, W) float16 rounded to :data:`NOISE_MANTISSA_BITS` mantissa bits (compresses well)."""
    bits = np.asarray(values, dtype=np.float16).view(np.uint16)
    drop = 10 - NOISE_MANTISSA_BITS
    rounded = ((bits.astype(np.uint32) + (1 << (drop - 1))) >> drop) << drop
    out = rounded.astype(np.uint16).view(np.float16)
    return np.where(np.isfinite(values), out, values.astype(np.float16))


def load_golden(path: str | os.PathLike[str]) -> GoldenFrame:
    """Read a golden frame written by :func:`write_golden`.

    Args:
        path: the ``.npz`` file.

    Returns:
        The frame; images as float32 (H, W) arrays (noise maps widened from float16).

    Raises:
        RecordingError: missing, unreadable or inconsistent file.
    """
    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"][()]))
            images = {key: np.asarray(data[key], dtype=np.float32) for key in IMAGE_DTYPES}
    except FileNotFoundError as err:
        raise RecordingError(f"golden frame {p} does not exist") from err
    except (KeyError, ValueError, OSError, zipfile.BadZipFile) as err:
        raise RecordingError(f"golden frame {p} is unreadable: {err}") from err
    try:
        intrinsics = Intrinsics(**meta["intrinsics"])
        frame = GoldenFrame(
            name=str(meta["name"]), description=str(meta["description"]),
            scene=Scene.from_dict(meta["scene"]),
            camera_to_base_mm=np.asarray(meta["camera_to_base_mm"], dtype=np.float64),
            intrinsics=intrinsics, mod_freq_hz=float(meta["mod_freq_hz"]),
            light=SpotLight(**meta["light"]),
            spp={k: int(v) for k, v in meta["spp"].items()},
            max_depth={k: int(v) for k, v in meta["max_depth"].items()},
            seed=int(meta["seed"]), versions=dict(meta["versions"]), command=str(meta["command"]),
            cpu_model=str(meta["cpu_model"]),
            render_seconds={k: float(v) for k, v in meta["render_seconds"].items()},
            noise={k: float(v) for k, v in meta["noise"].items()}, **images)
    except (KeyError, TypeError, ValueError, InputError) as err:
        raise RecordingError(f"golden frame {p} has malformed metadata: {err}") from err
    for key, image in images.items():
        if image.shape != intrinsics.shape:
            raise RecordingError(f"golden frame {p}: {key} has shape {image.shape}, the "
                                 f"intrinsics say {intrinsics.shape}")
    if frame.camera_to_base_mm.shape != (4, 4):
        raise RecordingError(f"golden frame {p}: camera_to_base_mm has shape "
                             f"{frame.camera_to_base_mm.shape}, expected (4, 4)")
    return frame


def multipath_field(range_mm: np.ndarray, true_range_mm: np.ndarray) -> np.ndarray:
    """Smoothed range error: the 5×5 median of (range − truth), ignoring NaN.

    Path-tracer noise and single-pixel edge effects drop out; the slowly varying over-shoot
    that multipath adds remains.

    Args:
        range_mm: (H, W) float measured or simulated radial range, mm; NaN = invalid.
        true_range_mm: (H, W) float true radial range, mm; NaN = no surface.

    Returns:
        (H, W) float64 median of the finite differences in the 5×5 window centred on each
        pixel (windows clipped at the border), mm; NaN where the pixel's own difference is NaN.
    """
    r = check_array("range_mm", range_mm, ndim=2, dtype_kind="fiu")
    t = check_array("true_range_mm", true_range_mm, ndim=2, shape=r.shape, dtype_kind="fiu")
    diff = r.astype(np.float64) - t.astype(np.float64)
    half = FIELD_WINDOW_PX // 2
    padded = np.pad(diff, half, constant_values=np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(padded, (FIELD_WINDOW_PX,) * 2)
    flat = windows.reshape(*diff.shape, -1)
    valid = np.isfinite(diff)
    out = np.full(diff.shape, np.nan)
    # every window of a valid pixel holds at least that pixel: no all-NaN slice
    out[valid] = np.nanmedian(flat[valid], axis=-1)
    return out


def interior_mask(object_id: np.ndarray, normal: np.ndarray, *, half_px: int = 1,
                  max_turn_deg: float = 10.0) -> np.ndarray:
    """Pixels well inside one face: the (2·half_px+1)² neighbourhood is all on the same object
    and its normals are within ``max_turn_deg`` of the centre pixel's (no depth edge, no crease;
    a curved surface stays interior while it turns slowly).

    Args:
        object_id: (H, W) int ids (``SurfaceImage.object_id``: 0 table, k object, -1 no hit).
        normal: (H, W, 3) float unit normals (any frame); NaN where there is no hit.
        half_px: half side of the neighbourhood, pixels.
        max_turn_deg: largest angle between a neighbour's normal and the centre's, degrees.

    Returns:
        (H, W) bool; False on the image border within ``half_px``.
    """
    ids = check_array("object_id", object_id, ndim=2, dtype_kind="iu")
    nrm = check_array("normal", normal, ndim=3, shape=(*ids.shape, 3), dtype_kind="f")
    h, w = ids.shape
    pad = half_px
    ids_p = np.pad(ids, pad, constant_values=-2)
    nrm_c = np.nan_to_num(nrm)
    nrm_p = np.pad(nrm_c, ((pad, pad), (pad, pad), (0, 0)))
    cos_min = math.cos(math.radians(max_turn_deg))
    out = ids >= 0
    for dy in range(-pad, pad + 1):
        for dx in range(-pad, pad + 1):
            rows, cols = slice(pad + dy, pad + dy + h), slice(pad + dx, pad + dx + w)
            out &= ids_p[rows, cols] == ids
            out &= np.einsum("hwk,hwk->hw", nrm_p[rows, cols], nrm_c) > cos_min
    return out


@dataclass(frozen=True)
class FieldComparison:
    """Agreement of two multipath fields over a mask.

    Attributes:
        rmse_mm: root mean square of (a − b), mm.
        correlation: Pearson correlation of a and b (NaN when either is constant).
        n_pixels: pixels compared (in the mask, both finite).
    """

    rmse_mm: float
    correlation: float
    n_pixels: int


def compare_fields(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None
                   ) -> FieldComparison:
    """RMSE and Pearson correlation of two (H, W) fields over the pixels where both are finite.

    Args:
        a, b: (H, W) float fields, e.g. :func:`multipath_field` of a simulation and of a golden
            frame, mm.
        mask: (H, W) bool pixels to compare (None = all).

    Returns:
        A :class:`FieldComparison`; NaN RMSE and correlation when no pixel is left.
    """
    fa = check_array("a", a, ndim=2, dtype_kind="fiu").astype(np.float64)
    fb = check_array("b", b, ndim=2, shape=fa.shape, dtype_kind="fiu").astype(np.float64)
    keep = np.isfinite(fa) & np.isfinite(fb)
    if mask is not None:
        keep &= check_array("mask", mask, ndim=2, shape=fa.shape, dtype_kind="b")
    n = int(keep.sum())
    if n == 0:
        return FieldComparison(math.nan, math.nan, 0)
    x, y = fa[keep], fb[keep]
    rmse = float(np.sqrt(np.mean((x - y) ** 2)))
    sx, sy = x.std(), y.std()
    corr = float(np.mean((x - x.mean()) * (y - y.mean())) / (sx * sy)) if sx > 0 and sy > 0 \
        else math.nan
    return FieldComparison(rmse, corr, n)
