"""The real Azure Kinect frame (``/work/shared/realdata/azure_kinect_mug``) as a ToF frame with an
approximate reference: planes fitted to the table and the wall away from their crease.

The Kinect's depth image is z-depth in mm on a distorted (Brown–Conrady, rational) grid. It is
resampled onto a pinhole grid (each pinhole pixel's ray is distorted to find its source pixel),
converted to radial range, and block-reduced by ``downsample`` (median range, mean amplitude) so
the simulator's interreflection stays affordable. Two planes are found by RANSAC; each is then
refitted by least squares on its inliers that lie more than ``crease_margin_mm`` from the other
plane, where interreflection from the crease is weak. The reference of a pixel is the nearest
ray–plane intersection, kept where the measurement lies within ``inlier_mm`` of it (the mug,
flying pixels and other objects stay missing).

The IR image serves as amplitude, scaled into simulator units so that the median inferred albedo
of the planes is ``PLANE_ALBEDO``; the Kinect's multi-frequency unwrapping never wraps in its
range, so the frame is given the nominal 30 MHz (5 m ambiguity) of the simulated cell.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import MismatchError
from ..frame import DEFAULT_MOD_FREQ_HZ, ToFFrame
from ..sim.tof import ToFConfig
from ..sim.tof.config import DEFAULT_LIGHT_POWER

#: NFOV unbinned: 640 x 576 crop of the 1024 x 1024 sensor at this offset (Azure Kinect SDK)
NFOV_UNBINNED_OFFSET = (192.0, 180.0)
#: IR saturates here; saturated pixels are invalid
IR_SATURATION = 65535
PLANE_ALBEDO = 0.6
#: light power of the simulated stand-in for the Kinect (amplitude·mm²): the cell's power
#: scaled by (2 m / 0.3 m)², so the wall at ~2 m is as bright (and as noisy, ~2–3 mm) as the
#: cell's table at 0.3 m
KINECT_LIGHT_POWER = DEFAULT_LIGHT_POWER * (2000.0 / 300.0) ** 2


def azure_kinect_config() -> ToFConfig:
    """The nominal cell with the Kinect stand-in's light power (see ``KINECT_LIGHT_POWER``)."""
    return replace(ToFConfig.nominal(), light_power=KINECT_LIGHT_POWER)


def is_azure_kinect_dir(path: str | Path) -> bool:
    """True for a folder laid out like the shared Azure Kinect frame (depth, IR, calibration)."""
    p = Path(path)
    return p.is_dir() and all((p / f).exists() for f in
                              ("depth_000.npy", "ir_000.npy", "calibration.json"))


@dataclass(frozen=True)
class BrownConrady:
    """Azure Kinect depth camera model in pixels of the 640 x 576 image.

    k1..k6 rational radial terms, p1, p2 tangential, (codx, cody) centre of distortion.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    k: tuple[float, float, float, float, float, float]
    p1: float
    p2: float
    codx: float = 0.0
    cody: float = 0.0

    def distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted pixel coordinates (u, v) of undistorted normalised coordinates (x, y)."""
        x0, y0 = x - self.codx, y - self.cody
        r2 = x0 * x0 + y0 * y0
        k1, k2, k3, k4, k5, k6 = self.k
        radial = ((1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
                  / (1 + r2 * (k4 + r2 * (k5 + r2 * k6))))
        xd = x0 * radial + 2 * self.p1 * x0 * y0 + self.p2 * (r2 + 2 * x0 * x0) + self.codx
        yd = y0 * radial + self.p1 * (r2 + 2 * y0 * y0) + 2 * self.p2 * x0 * y0 + self.cody
        return self.fx * xd + self.cx, self.fy * yd + self.cy


def load_calibration(path: Path) -> BrownConrady:
    """The depth camera model of ``calibration.json`` for the NFOV unbinned 640 x 576 mode."""
    try:
        doc = json.loads(path.read_text())
        cams = doc["CalibrationInformation"]["Cameras"]
        cam = next(c for c in cams if c["Purpose"] == "CALIBRATION_CameraPurposeDepth")
        p = [float(v) for v in cam["Intrinsics"]["ModelParameters"]]
        width, height = float(cam["SensorWidth"]), float(cam["SensorHeight"])
    except (OSError, ValueError, KeyError, StopIteration) as err:
        raise MismatchError(f"{path}: cannot read the depth camera calibration: {err}") from err
    cx, cy, fx, fy = p[0] * width, p[1] * height, p[2] * width, p[3] * height
    ox, oy = NFOV_UNBINNED_OFFSET
    return BrownConrady(fx, fy, cx - ox, cy - oy, (p[4], p[5], p[6], p[7], p[8], p[9]),
                        p1=p[13], p2=p[12], codx=p[10], cody=p[11])


def to_pinhole(depth_mm: np.ndarray, ir: np.ndarray, model: BrownConrady,
               downsample: int) -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """Radial range and amplitude on a pinhole grid, block-reduced by ``downsample``.

    Args:
        depth_mm: (576, 640) uint16 z-depth in mm, 0 = invalid.
        ir: (576, 640) uint16 active IR.

    Returns:
        range_mm (h, w) float32 radial mm (NaN invalid), amplitude (h, w) float32 raw IR units,
        and the pinhole intrinsics of the (h, w) grid.
    """
    h, w = depth_mm.shape
    full = Intrinsics(model.fx, model.fy, model.cx, model.cy, w, h)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = (u - full.cx) / full.fx, (v - full.cy) / full.fy
    ud, vd = model.distort(x, y)
    iu, iv = np.rint(ud).astype(int), np.rint(vd).astype(int)
    inside = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
    iu, iv = np.clip(iu, 0, w - 1), np.clip(iv, 0, h - 1)
    z = np.where(inside, depth_mm[iv, iu].astype(np.float64), 0.0)
    amp = np.where(inside, ir[iv, iu].astype(np.float64), np.nan)
    ok = (z > 0) & (amp < IR_SATURATION)
    rng = np.where(ok, z * np.sqrt(1.0 + x * x + y * y), np.nan)
    amp = np.where(ok, amp, np.nan)
    s = int(downsample)
    hh, ww = h // s, w // s
    blocks_r = rng[:hh * s, :ww * s].reshape(hh, s, ww, s).transpose(0, 2, 1, 3).reshape(
        hh, ww, s * s)
    blocks_a = amp[:hh * s, :ww * s].reshape(hh, s, ww, s).transpose(0, 2, 1, 3).reshape(
        hh, ww, s * s)
    enough = np.isfinite(blocks_r).sum(axis=-1) >= (s * s + 1) // 2
    with np.errstate(all="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            r_small = np.where(enough, np.nanmedian(blocks_r, axis=-1), np.nan)
            a_small = np.where(enough, np.nanmean(blocks_a, axis=-1), np.nan)
    k = Intrinsics(full.fx / s, full.fy / s, (full.cx + 0.5) / s - 0.5,
                   (full.cy + 0.5) / s - 0.5, ww, hh)
    return r_small.astype(np.float32), a_small.astype(np.float32), k


def ransac_plane(points: np.ndarray, rng: np.random.Generator, *, tol_mm: float = 8.0,
                 iterations: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """The plane with most inliers among ``points`` (N, 3) mm.

    Returns:
        (4,) float64 plane (unit normal n, offset d with n·p + d = 0) refitted to its inliers
        by least squares, and (N,) bool inliers.
    """
    n = points.shape[0]
    if n < 3:
        raise MismatchError("too few valid points to fit a plane")
    best, best_count = None, -1
    for _ in range(iterations):
        a, b, c = points[rng.choice(n, 3, replace=False)]
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal)
        if norm < 1e-9:
            continue
        normal /= norm
        count = int(np.sum(np.abs(points @ normal - normal @ a) < tol_mm))
        if count > best_count:
            best, best_count = np.append(normal, -normal @ a), count
    inliers = np.abs(points @ best[:3] + best[3]) < tol_mm
    return fit_plane(points[inliers]), inliers


def fit_plane(points: np.ndarray) -> np.ndarray:
    """Least-squares plane (4,) ``(n, d)`` of (N, 3) points, normal facing the origin side."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[-1]
    d = -normal @ centre
    if d < 0:  # camera (origin) on the positive side
        normal, d = -normal, -d
    return np.append(normal, d)


@dataclass
class PlaneReference:
    """The plane-fit reference and what it was made of.

    Attributes:
        reference_mm: (H, W) float32 radial range of the nearest plane, NaN = not a plane pixel.
        planes: (2, 4) float64 plane equations (n, d), mm.
        crease_distance_mm: (H, W) float64 distance of each pixel's plane point to the crease.
        inlier_counts: points used in each plane's final fit.
    """

    reference_mm: np.ndarray
    planes: np.ndarray
    crease_distance_mm: np.ndarray
    inlier_counts: tuple[int, int]


def plane_reference(range_mm: np.ndarray, intrinsics: Intrinsics, *, seed: int = 0,
                    crease_margin_mm: float = 150.0, inlier_mm: float = 40.0,
                    ransac_tol_mm: float = 10.0) -> PlaneReference:
    """Two planes (table, wall) fitted away from their crease, as a reference range image.

    Args:
        range_mm: (H, W) float radial range in mm, NaN = invalid.
        intrinsics: pinhole intrinsics of the image.
        seed: RANSAC seed.
        crease_margin_mm: the final fit of a plane uses its inliers at least this far from the
            other plane.
        inlier_mm: a pixel gets the plane's range when its measurement is within this of it.
    """
    rays = intrinsics.ray_directions()
    pts = rays * np.asarray(range_mm, dtype=np.float64)[..., None]
    valid = np.isfinite(range_mm)
    flat = pts[valid]
    rng = np.random.default_rng(seed)
    plane1, in1 = ransac_plane(flat, rng, tol_mm=ransac_tol_mm)
    rest = flat[~in1]
    plane2, in2 = ransac_plane(rest, rng, tol_mm=ransac_tol_mm)
    planes, counts = [], []
    for other, pts_own in ((plane2, flat[in1]), (plane1, rest[in2])):
        far = np.abs(pts_own @ other[:3] + other[3]) > crease_margin_mm
        use = pts_own[far] if far.sum() >= 50 else pts_own
        planes.append(fit_plane(use))
        counts.append(int(use.shape[0]))
    p = np.asarray(planes)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -p[:, 3][None, None, :] / np.einsum("hwk,pk->hwp", rays, p[:, :3])
    t = np.where(t > 0, t, np.inf)
    nearest = np.min(t, axis=-1)
    which = np.argmin(t, axis=-1)
    close = np.abs(nearest - range_mm) < inlier_mm
    ref = np.where(close & np.isfinite(nearest), nearest, np.nan)
    hit = rays * nearest[..., None]
    other = p[1 - which]
    crease = np.abs(np.einsum("hwk,hwk->hw", hit, other[..., :3]) + other[..., 3])
    return PlaneReference(ref.astype(np.float32), p, np.where(np.isfinite(ref), crease, np.nan),
                          (counts[0], counts[1]))


def azure_kinect_frame(directory: str | Path, *, downsample: int = 4,
                       seed: int = 0) -> tuple[ToFFrame, PlaneReference]:
    """The Azure Kinect frame as a pinhole ToF frame with the plane-fit reference.

    Args:
        directory: folder with ``depth_000.npy``, ``ir_000.npy`` and ``calibration.json``.
        downsample: block size of the reduction (4: 160 x 144 pixels).
        seed: RANSAC seed.

    Returns:
        The frame (amplitude in simulator units, see the module docstring) and the reference
        details.

    Raises:
        MismatchError: files missing or unreadable.
    """
    d = Path(directory)
    try:
        depth = np.load(d / "depth_000.npy", allow_pickle=False)
        ir = np.load(d / "ir_000.npy", allow_pickle=False)
    except (OSError, ValueError) as err:
        raise MismatchError(f"{d}: cannot read the Azure Kinect frame: {err}") from err
    if depth.shape != ir.shape or depth.ndim != 2:
        raise MismatchError(f"{d}: depth {depth.shape} and IR {ir.shape} must be one 2-D size")
    model = load_calibration(d / "calibration.json")
    rng_mm, amp, k = to_pinhole(depth, ir, model, downsample)
    ref = plane_reference(rng_mm, k, seed=seed)
    amp = _to_sim_units(amp, ref.reference_mm, k)
    frame = ToFFrame(rng_mm, amp, k, mod_freq_hz=DEFAULT_MOD_FREQ_HZ,
                     reference_mm=ref.reference_mm)
    return frame, ref


def _to_sim_units(amplitude: np.ndarray, reference_mm: np.ndarray,
                  intrinsics: Intrinsics) -> np.ndarray:
    """Scale raw IR so that the planes' median albedo under ``KINECT_LIGHT_POWER`` is
    ``PLANE_ALBEDO`` (the sensor's gain is unknown; only ratios are physical)."""
    from ..sim.tof.reference import surface_from_reference
    surf = surface_from_reference(reference_mm, intrinsics, 1.0)
    cos = np.clip(-np.einsum("hwk,hwk->hw", surf.normal, intrinsics.ray_directions()), 0.05, 1)
    unit = KINECT_LIGHT_POWER * cos / surf.range_mm ** 2
    ratio = amplitude / unit
    scale = PLANE_ALBEDO / float(np.nanmedian(ratio[np.isfinite(ratio)]))
    return (amplitude * scale).astype(np.float32)
