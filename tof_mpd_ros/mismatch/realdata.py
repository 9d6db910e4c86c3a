"""Real ToF frames as ToF frames with an approximate reference: planes fitted away from their
creases. Two sources share one implementation (block reduction, RANSAC, plane reference,
amplitude units):

**Azure Kinect** (``data/realdata/azure_kinect_mug``). The depth image is z-depth in mm
on a distorted (Brown–Conrady, rational) grid. It is resampled onto a pinhole grid (each pinhole
pixel's ray is distorted to find its source pixel), converted to radial range, and block-reduced
by ``downsample`` (median range, mean amplitude) so the simulator's interreflection stays
affordable. Two planes are found by RANSAC; each is then refitted by least squares on its
inliers that lie more than ``crease_margin_mm`` from the other plane, where interreflection from
the crease is weak. The reference of a pixel is the nearest ray–plane intersection, kept where
the measurement lies within ``inlier_mm`` of it (the mug, flying pixels and other objects stay
missing). The IR image serves as amplitude, scaled into simulator units so that the median
inferred albedo of the planes is ``PLANE_ALBEDO``; the Kinect's multi-frequency unwrapping
never wraps in its range, so the frame is given the nominal 30 MHz (5 m ambiguity) of the
simulated cell.

**Analog Devices ToF module** (``data/realdata/adi_tof_office``: an office, 512 x 512,
modes 2 and 3). No intrinsics ship: a pinhole with the principal point at the centre and
``fov_deg`` (75°, the module's nominal field of view) is assumed. The depth is **radial range**,
not z-depth: a flat back panel facing the camera reads 2074 mm near the centre and 2189 mm
135 px to the side (+88 mm 125 px up), the bowl radial range draws on a plane; read as radial
range, the office's planes cover 27 % / 42 % of the 128 x 128 pixels (modes 2 / 3) at a median
|measurement − plane| of 3.6 / 4.8 mm, read as z-depth 17 % / 17 % at 7.6 / 8.4 mm. Pixels with
a confidence value above ``ADI_MAX_CONFIDENCE`` (4) are dropped: where the other mode is
reliable (confidence <= 3), the two modes' median |difference| is 5–6 mm up to confidence 4
with under 6 % gross (> 200 mm) errors, 10 mm and 9 % at 5–6, then rising to 28 mm at 11–12
and 778 mm at 24–27 (mode 2's far ceiling); the limit keeps 67 % / 77 % of the valid pixels.
Up to ``ADI_PLANES`` planes are found; a person is not a plane, so a RANSAC plane must lie
within ``ADI_MANHATTAN_DEG`` of a box room's axes (the person's torso and arm planes are
20–50° off) and a pixel's own normal within ``ADI_MAX_NORMAL_DEG`` of its plane's (the person
crossing the desk's extension). Known limit: no single pinhole flattens every plane — each
plane's best field of view lies between 60° and 80°, most between 67° and 75° (a wide-angle
lens with some distortion); at 75° the planes' robust spread about their fits is 1.2–9 mm at
128 x 128.
"""

from __future__ import annotations

import itertools
import json
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import MismatchError
from ..frame import DEFAULT_MOD_FREQ_HZ, ToFFrame
from ..sim.tof import DEFAULT_LIGHT_POWER, ToFConfig
from ..templates import render
from .profile import CELL_DISTANCE_MM, with_scene_distance

#: planes closer than this to parallel form no crease (neighbouring panels, or two fits of one
#: slightly curved surface): they do not limit each other's fit, and the measurement decides
#: which of them a pixel is on
PARALLEL_DEG = 15.0
#: NFOV unbinned: 640 x 576 crop of the 1024 x 1024 sensor at this offset (Azure Kinect SDK)
NFOV_UNBINNED_OFFSET = (192.0, 180.0)
#: IR saturates here; saturated pixels are invalid
IR_SATURATION = 65535
PLANE_ALBEDO = 0.6
#: light power of the simulated stand-in for the Kinect (amplitude·mm²): the cell's power
#: scaled by (2 m / 0.3 m)², so the wall at ~2 m is as bright (and as noisy, ~2–3 mm) as the
#: cell's table at 0.3 m
KINECT_LIGHT_POWER = DEFAULT_LIGHT_POWER * (2000.0 / CELL_DISTANCE_MM) ** 2

#: ADI modes with frames in a folder like data/realdata/adi_tof_office
ADI_FILES = ("depth_mode{}.npy", "amplitude_mode{}.npy", "confidence_mode{}.npy")
#: the ADI module's nominal field of view (no intrinsics ship; principal point at the centre)
ADI_FOV_DEG = 75.0
#: pixels with a larger confidence value (higher = less reliable) are dropped by default
ADI_MAX_CONFIDENCE = 4
#: most planes sought in the office (cubicle panels, side walls, ceiling, desk)
ADI_PLANES = 8
#: a plane of the ADI frame needs this share of the valid pixels
ADI_MIN_PLANE_SHARE = 0.02
#: the office's planes are a box room's (walls, panels, ceiling, desk) within this angle
ADI_MANHATTAN_DEG = 10.0
#: a pixel's own surface normal must be this close to its plane's (a person crossing the
#: desk's or the floor's extension is not on it)
ADI_MAX_NORMAL_DEG = 30.0
#: distance of the office's main surfaces (back panel at ~2.1 m; median valid range 1.8-2.1 m)
ADI_SCENE_DISTANCE_MM = 2000.0


def light_power_for(distance_mm: float) -> float:
    """Light power (amplitude·mm²) that makes a surface at ``distance_mm`` as bright as the
    cell's table at ``CELL_DISTANCE_MM`` under the nominal power."""
    return DEFAULT_LIGHT_POWER * (distance_mm / CELL_DISTANCE_MM) ** 2


def azure_kinect_config() -> ToFConfig:
    """The nominal cell with the Kinect stand-in's light power (see ``KINECT_LIGHT_POWER``)
    and the interreflection's patches scaled to the room's 2 m, as for the ADI module
    (:func:`adi_config`)."""
    return replace(with_scene_distance(ToFConfig.nominal(), 2000.0),
                   light_power=KINECT_LIGHT_POWER)


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
    rng = np.where(ok, full.z_to_radial(z), np.nan)
    amp = np.where(ok, amp, np.nan)
    return block_reduce(rng, amp, full, downsample)


def block_reduce(range_mm: np.ndarray, amplitude: np.ndarray, intrinsics: Intrinsics,
                 downsample: int) -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """``downsample`` x ``downsample`` blocks reduced to one pixel: median range, mean amplitude.

    A block with fewer than half its pixels valid is invalid (NaN), so a few surviving pixels
    at an edge or in a noisy patch do not make a pixel.

    Args:
        range_mm: (H, W) float radial range in mm, NaN = invalid.
        amplitude: (H, W) float amplitude (any unit), NaN where the range is invalid.
        intrinsics: pinhole intrinsics of the (H, W) grid.
        downsample: block size s.

    Returns:
        range_mm (H // s, W // s) float32 mm (NaN invalid), amplitude (H // s, W // s) float32
        in the input's unit, and the intrinsics of the reduced grid.
    """
    s = int(downsample)
    h, w = range_mm.shape
    hh, ww = h // s, w // s

    def blocks(img: np.ndarray) -> np.ndarray:
        return img[:hh * s, :ww * s].reshape(hh, s, ww, s).transpose(0, 2, 1, 3).reshape(
            hh, ww, s * s)

    blocks_r, blocks_a = blocks(range_mm), blocks(amplitude)
    enough = np.isfinite(blocks_r).sum(axis=-1) >= (s * s + 1) // 2
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN blocks: masked below anyway
        r_small = np.where(enough, np.nanmedian(blocks_r, axis=-1), np.nan)
        a_small = np.where(enough, np.nanmean(blocks_a, axis=-1), np.nan)
    k = intrinsics
    small = Intrinsics(k.fx / s, k.fy / s, (k.cx + 0.5) / s - 0.5, (k.cy + 0.5) / s - 0.5,
                       ww, hh)
    return r_small.astype(np.float32), a_small.astype(np.float32), small


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
        reference_mm: (H, W) float32 radial range of the pixel's plane, NaN = not a plane pixel.
        planes: (P, 4) float64 plane equations (n, d), mm, in the order RANSAC found them.
        crease_distance_mm: (H, W) float64 distance of each pixel's plane point to the nearest
            other plane (NaN off the planes).
        inlier_counts: points used in each plane's final fit.
        plane_index: (H, W) int16 index into ``planes`` of each pixel's plane, -1 = none.
    """

    reference_mm: np.ndarray
    planes: np.ndarray
    crease_distance_mm: np.ndarray
    inlier_counts: tuple[int, ...]
    plane_index: np.ndarray


def plane_reference(range_mm: np.ndarray, intrinsics: Intrinsics, *, seed: int = 0,
                    crease_margin_mm: float = 150.0, inlier_mm: float = 40.0,
                    ransac_tol_mm: float = 10.0, n_planes: int = 2, min_inliers: int = 50,
                    manhattan_deg: float | None = None,
                    max_normal_deg: float | None = None) -> PlaneReference:
    """Planes (e.g. table and wall) fitted away from their creases, as a reference range image.

    RANSAC finds up to ``n_planes`` planes one after the other (:func:`find_planes`). Each is
    then refitted by least squares on its inliers more than ``crease_margin_mm`` from every
    other plane it can form a crease with (more than ``PARALLEL_DEG`` from parallel), where
    interreflection from the creases is weak. A pixel gets a plane whose ray intersection lies
    within ``inlier_mm`` of its measurement (:func:`_assign_planes`): the nearest, because
    where a plane is seen its extension behind another one is hidden; among those within
    ``inlier_mm``, because a plane's extension in front of a farther one (a near cubicle panel
    and the wall behind it) is not there. With ``max_normal_deg``, the pixel's own surface
    normal (:func:`~tof_mpd_ros.sim.tof.reference.normals_from_range`) must also lie within
    that angle of the plane's: an object crossing a plane's extension (a person standing on
    the floor's or the desk's) meets it within ``inlier_mm`` along a thin band of pixels, but
    at a steep angle.

    Args:
        range_mm: (H, W) float radial range in mm, NaN = invalid.
        intrinsics: pinhole intrinsics of the image.
        seed: RANSAC seed.
        crease_margin_mm: the final fit of a plane uses its inliers at least this far from the
            other planes.
        inlier_mm: a pixel gets a plane's range when its measurement is within this of it.
        ransac_tol_mm, n_planes, min_inliers, manhattan_deg: see :func:`find_planes`.
        max_normal_deg: largest angle between a pixel's normal and its plane's (None: any).

    Raises:
        MismatchError: fewer than 3 valid points, or not even one plane found.
    """
    range64 = np.asarray(range_mm, dtype=np.float64)
    rays = intrinsics.ray_directions()
    found, own = find_planes((rays * range64[..., None])[np.isfinite(range64)],
                             np.random.default_rng(seed), n_planes=n_planes,
                             min_inliers=min_inliers, tol_mm=ransac_tol_mm,
                             manhattan_deg=manhattan_deg)
    planes, counts = _refit_away_from_creases(found, own, crease_margin_mm)
    allowed = (None if max_normal_deg is None
               else _normal_agrees(range64, intrinsics, planes, max_normal_deg))
    which, nearest = _assign_planes(rays, range64, planes, inlier_mm, allowed)
    hit = rays * nearest[..., None]
    crease = np.full(which.shape, np.nan)
    for i in range(planes.shape[0]):
        mine = which == i
        crease[mine] = _distance_to_planes(hit[mine], _creasing(i, planes))
    return PlaneReference(nearest.astype(np.float32), planes, crease, counts,
                          which.astype(np.int16))


def _refit_away_from_creases(found: np.ndarray, own: list[np.ndarray],
                             margin_mm: float) -> tuple[np.ndarray, tuple[int, ...]]:
    """Each (P, 4) RANSAC plane refitted on its inliers (``own[i]``, (N_i, 3) mm) more than
    ``margin_mm`` from the planes it creases with (all of them when fewer than 50 are).

    Returns:
        (P, 4) float64 planes and the number of points of each fit.
    """
    planes, counts = [], []
    for i, pts_own in enumerate(own):
        far = _distance_to_planes(pts_own, _creasing(i, found)) > margin_mm
        use = pts_own[far] if far.sum() >= 50 else pts_own
        planes.append(fit_plane(use))
        counts.append(int(use.shape[0]))
    return np.asarray(planes), tuple(counts)


def _normal_agrees(range_mm: np.ndarray, intrinsics: Intrinsics, planes: np.ndarray,
                   max_deg: float) -> np.ndarray:
    """(H, W, P) bool: the pixel's local surface normal lies within ``max_deg`` of plane p's
    (False where the range image gives no normal)."""
    from ..sim.tof import normals_from_range
    normals = normals_from_range(range_mm, intrinsics)
    with np.errstate(invalid="ignore"):
        return np.abs(normals @ planes[:, :3].T) >= np.cos(np.radians(max_deg))


def find_planes(points: np.ndarray, rng: np.random.Generator, *, n_planes: int,
                min_inliers: int = 50, tol_mm: float = 10.0,
                manhattan_deg: float | None = None) -> tuple[np.ndarray, list[np.ndarray]]:
    """Up to ``n_planes`` planes among ``points``, found by RANSAC one after the other.

    Each search runs on the points the earlier planes left. The search stops when the next
    plane would have fewer than ``min_inliers`` points (nothing plane-like is left). With
    ``manhattan_deg``, a plane must also lie within that angle of the axes of a box room (the
    first plane's normal, the first one perpendicular to it, and their cross product): walls,
    panels, ceiling and desk of an office do, a person's torso or arm cut by a plane mostly
    does not. A rejected plane's points leave the pool too, and at most ``3 * n_planes``
    searches run.

    Args:
        points: (N, 3) float64 points in mm.

    Returns:
        (P, 4) float64 planes (n, d), P <= n_planes, and per plane its (N_i, 3) RANSAC inliers.

    Raises:
        MismatchError: fewer than 3 points, or no plane found.
    """
    found: list[np.ndarray] = []
    own: list[np.ndarray] = []
    axes: list[np.ndarray] = []
    rest = points
    for _ in range(n_planes if manhattan_deg is None else 3 * n_planes):
        if len(found) == n_planes or rest.shape[0] < max(min_inliers, 3):
            break
        plane, inliers = ransac_plane(rest, rng, tol_mm=tol_mm)
        if inliers.sum() < min_inliers:
            break
        if manhattan_deg is None or _manhattan(plane[:3], axes, manhattan_deg):
            found.append(plane)
            own.append(rest[inliers])
        rest = rest[~inliers]
    if not found:
        raise MismatchError("no plane with enough points in the range image")
    return np.asarray(found), own


def _manhattan(normal: np.ndarray, axes: list[np.ndarray], tol_deg: float) -> bool:
    """Whether ``normal`` (3,) lies within ``tol_deg`` of the room's ``axes`` (updated in
    place: the first normal, then the first perpendicular one, then their cross product)."""
    cos_tol, sin_tol = np.cos(np.radians(tol_deg)), np.sin(np.radians(tol_deg))
    if not axes:
        axes.append(normal / np.linalg.norm(normal))
        return True
    if len(axes) == 1:
        c = abs(float(normal @ axes[0]))
        if c >= cos_tol:
            return True
        if c > sin_tol:
            return False
        second = normal - (normal @ axes[0]) * axes[0]
        axes.append(second / np.linalg.norm(second))
        axes.append(np.cross(axes[0], axes[1]))
        return True
    return max(abs(float(normal @ a)) for a in axes) >= cos_tol


def _creasing(i: int, planes: np.ndarray) -> np.ndarray:
    """The (Q, 4) other rows of ``planes`` (P, 4) that can form a crease with plane ``i``:
    more than ``PARALLEL_DEG`` from parallel to it."""
    others = np.delete(planes, i, axis=0)
    return others[np.abs(others[:, :3] @ planes[i, :3]) < np.cos(np.radians(PARALLEL_DEG))]


def _distance_to_planes(points: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """(N,) float64 distance in mm of (N, 3) points to the nearest of (P, 4) planes (inf if
    P = 0: a lone plane has no crease)."""
    if planes.shape[0] == 0:
        return np.full(points.shape[0], np.inf)
    return np.min(np.abs(points @ planes[:, :3].T + planes[:, 3]), axis=1)


def _assign_planes(rays: np.ndarray, range_mm: np.ndarray, planes: np.ndarray,
                   inlier_mm: float,
                   allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's plane among those whose ray intersection is within ``inlier_mm`` of the
    measured range: the nearest along the ray, or, among planes within ``PARALLEL_DEG`` of
    parallel to that one, the one nearest the measurement.

    Nearly parallel planes form no crease whose hidden side the nearest rule resolves; they
    are neighbouring panels or two fits of one slightly curved surface, and the measurement
    tells which it is on.

    Args:
        rays: (H, W, 3) unit rays; range_mm: (H, W) float64 mm, NaN invalid;
        planes: (P, 4) plane equations; allowed: (H, W, P) bool, planes a pixel may take
        (None: all).

    Returns:
        (H, W) int plane index (-1 none) and (H, W) float64 radial range of that plane, NaN
        where none.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -planes[:, 3][None, None, :] / np.einsum("hwk,pk->hwp", rays, planes[:, :3])
    t = np.where(t > 0, t, np.inf)
    close = np.abs(t - range_mm[..., None]) < inlier_mm
    if allowed is not None:
        close &= allowed
    t = np.where(close, t, np.inf)
    first = np.argmin(t, axis=-1)
    parallel = np.abs(planes[:, :3] @ planes[:, :3].T) >= np.cos(np.radians(PARALLEL_DEG))
    misfit = np.where(close & parallel[first], np.abs(t - range_mm[..., None]), np.inf)
    which = np.argmin(misfit, axis=-1)
    nearest = np.take_along_axis(t, which[..., None], axis=-1)[..., 0]
    found = np.isfinite(nearest)
    return np.where(found, which, -1), np.where(found, nearest, np.nan)


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


def _to_sim_units(amplitude: np.ndarray, reference_mm: np.ndarray, intrinsics: Intrinsics,
                  light_power: float = KINECT_LIGHT_POWER) -> np.ndarray:
    """Scale raw amplitude so that the planes' median albedo under ``light_power`` is
    ``PLANE_ALBEDO`` (the sensor's gain is unknown; only ratios are physical)."""
    from ..sim.tof import surface_from_reference
    surf = surface_from_reference(reference_mm, intrinsics, 1.0)
    cos = np.clip(-np.einsum("hwk,hwk->hw", surf.normal, intrinsics.ray_directions()), 0.05, 1)
    unit = light_power * cos / surf.range_mm ** 2
    ratio = amplitude / unit
    scale = PLANE_ALBEDO / float(np.nanmedian(ratio[np.isfinite(ratio)]))
    return (amplitude * scale).astype(np.float32)


def adi_modes(path: str | Path) -> tuple[int, ...]:
    """Modes with depth, amplitude and confidence in an ADI folder (``depth_mode3.npy``, ...)."""
    p = Path(path)
    if not p.is_dir():
        return ()
    modes = set()
    for f in p.glob("depth_mode*.npy"):
        tail = f.stem.removeprefix("depth_mode")
        if tail.isdigit() and all((p / n.format(tail)).exists() for n in ADI_FILES):
            modes.add(int(tail))
    return tuple(sorted(modes))


def is_adi_dir(path: str | Path) -> bool:
    """True for a folder laid out like the shared ADI frames (per mode N: ``depth_modeN.npy``,
    ``amplitude_modeN.npy``, ``confidence_modeN.npy``)."""
    return bool(adi_modes(path))


def adi_config(scene_distance_mm: float = ADI_SCENE_DISTANCE_MM) -> ToFConfig:
    """The nominal cell as a stand-in for the ADI module, scaled to the office.

    * Light power ``light_power_for(scene_distance_mm)``: the office's main surfaces at ~2 m
      are as bright, and the noise law as quiet, as the cell's table at 0.3 m (the Kinect's
      scaling).
    * The interreflection's patches (``multipath`` ``leaf_mm``, ``bounce_patch_mm``) scaled by
      the same distance ratio (4 -> 27 mm, 8 -> 53 mm at 2 m): a leaf stays about one pixel's
      footprint, as in the cell. At the cell's 4 mm the world of a room (its support plane
      extended across the light's cone) holds millions of leaves and one prediction takes
      longer than 20 minutes.
    * The modulation frequency stays the cell's 30 MHz — an assumption, as for the Kinect: the
      frames do not state the module's frequencies, so the interreflected light's phase is the
      cell's, not the camera's.
    * Phase wrapping off: the camera unwraps by itself (mode 3 reports surfaces up to 7.5 m,
      beyond the 5 m ambiguity range of 30 MHz), so a 30 MHz cell that wraps would contradict
      the recording.
    """
    cfg = with_scene_distance(ToFConfig.nominal().with_effect("phase_wrapping", enabled=False),
                              scene_distance_mm)
    return replace(cfg, light_power=light_power_for(scene_distance_mm))


def adi_frame(directory: str | Path, mode: int, *, downsample: int = 4,
              fov_deg: float = ADI_FOV_DEG, max_confidence: int | None = None,
              depth_is_z: bool = False, n_planes: int = ADI_PLANES, seed: int = 0) -> ToFFrame:
    """One mode of the ADI office frames as a pinhole ToF frame with a plane-fit reference.

    See :func:`load_adi` (which also returns the reference's planes).
    """
    return load_adi(directory, mode, downsample=downsample, fov_deg=fov_deg,
                    max_confidence=max_confidence, depth_is_z=depth_is_z, n_planes=n_planes,
                    seed=seed)[0]


def load_adi(directory: str | Path, mode: int, *, downsample: int = 4,
             fov_deg: float = ADI_FOV_DEG, max_confidence: int | None = None,
             depth_is_z: bool = False, n_planes: int = ADI_PLANES,
             seed: int = 0) -> tuple[ToFFrame, PlaneReference]:
    """One mode of the ADI office frames as a pinhole ToF frame and its plane-fit reference.

    Preparation (:func:`adi_reduced`): pixels with depth 0 or confidence above the limit are
    invalid, the depth is taken as radial range (the frames' planes are planar only so; see
    the module docstring) and 4 x 4 blocks are reduced (median range, mean amplitude).
    Reference (:func:`adi_reference`): up to ``n_planes`` box-room planes, each needing
    ``ADI_MIN_PLANE_SHARE`` of the valid pixels, a pixel taking one only where its own normal is
    within ``ADI_MAX_NORMAL_DEG`` of it; the person and the clutter stay missing. Amplitude is
    scaled into simulator units as for the Kinect, under the light power of :func:`adi_config`.

    Args:
        directory: folder with ``depth_modeN.npy`` (uint16 mm, 0 invalid),
            ``amplitude_modeN.npy`` (uint16) and ``confidence_modeN.npy`` (uint8, higher = less
            reliable).
        mode: camera mode N (2 short-range, 3 long-range in the shared folder).
        downsample: block size (4: 512 x 512 -> 128 x 128).
        fov_deg: horizontal field of view of the assumed pinhole (principal point at the
            image centre; no intrinsics ship with the frames).
        max_confidence: drop pixels whose confidence value exceeds this; None =
            ``ADI_MAX_CONFIDENCE``.
        depth_is_z: treat the depth as z-depth and convert it to radial range.
        n_planes: most planes in the reference.
        seed: RANSAC seed.

    Returns:
        The frame (range (h, w) float32 mm, amplitude float32 simulator units, 30 MHz) and the
        reference details.

    Raises:
        MismatchError: the mode's files are missing or unreadable, or no plane is found.
    """
    rng_mm, amp, k = adi_reduced(directory, mode, downsample=downsample, fov_deg=fov_deg,
                                 max_confidence=max_confidence, depth_is_z=depth_is_z)
    ref = adi_reference(rng_mm, k, n_planes=n_planes, seed=seed)
    amp = _to_sim_units(amp, ref.reference_mm, k, light_power_for(ADI_SCENE_DISTANCE_MM))
    frame = ToFFrame(rng_mm, amp, k, mod_freq_hz=DEFAULT_MOD_FREQ_HZ,
                     reference_mm=ref.reference_mm)
    return frame, ref


def adi_reduced(directory: str | Path, mode: int, *, downsample: int = 4,
                fov_deg: float = ADI_FOV_DEG, max_confidence: int | None = None,
                depth_is_z: bool = False) -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """One ADI mode's radial range and raw amplitude on the pinhole grid, block-reduced.

    Returns:
        range_mm (h, w) float32 radial mm (NaN invalid), amplitude (h, w) float32 in the
        camera's units (NaN invalid), and the (h, w) grid's intrinsics.
    """
    depth, amplitude, confidence = _read_adi(Path(directory), mode)
    h, w = depth.shape
    k = Intrinsics.from_fov(w, h, fov_deg)
    limit = ADI_MAX_CONFIDENCE if max_confidence is None else max_confidence
    ok = (depth > 0) & (confidence <= limit)
    depth_mm = np.where(ok, depth.astype(np.float64), np.nan)
    rng_mm = k.z_to_radial(depth_mm) if depth_is_z else depth_mm
    amp = np.where(ok, amplitude.astype(np.float64), np.nan)
    return block_reduce(rng_mm, amp, k, downsample)


def adi_reference(range_mm: np.ndarray, intrinsics: Intrinsics, *, n_planes: int = ADI_PLANES,
                  seed: int = 0) -> PlaneReference:
    """The office's plane reference of a reduced ADI range image ((h, w) float mm, NaN
    invalid): :func:`plane_reference` with the office's settings (module constants)."""
    min_px = max(int(ADI_MIN_PLANE_SHARE * np.isfinite(range_mm).sum()), 3)
    return plane_reference(range_mm, intrinsics, seed=seed, n_planes=n_planes,
                           min_inliers=min_px, manhattan_deg=ADI_MANHATTAN_DEG,
                           max_normal_deg=ADI_MAX_NORMAL_DEG)


def _read_adi(d: Path, mode: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(H, W) uint16 depth mm, uint16 amplitude, uint8 confidence of ``mode``."""
    if mode not in adi_modes(d):
        raise MismatchError(f"{d}: no ADI frame of mode {mode} (modes here: "
                            f"{', '.join(map(str, adi_modes(d))) or 'none'})")
    try:
        arrays = [np.load(d / n.format(mode), allow_pickle=False) for n in ADI_FILES]
    except (OSError, ValueError) as err:
        raise MismatchError(f"{d}: cannot read the ADI frame of mode {mode}: {err}") from err
    if len({a.shape for a in arrays}) != 1 or arrays[0].ndim != 2:
        raise MismatchError(f"{d}: mode {mode}: depth, amplitude and confidence must be one "
                            f"2-D size, got {[a.shape for a in arrays]}")
    return arrays[0], arrays[1], arrays[2]


# -- the two modes' disagreement -------------------------------------------------------------


def mode_disagreement(directory: str | Path, modes: tuple[int, int] = (2, 3), *,
                      downsample: int = 4, fov_deg: float = ADI_FOV_DEG,
                      max_confidence: int | None = None, edge_px: int = 2,
                      same_surface_mm: float = 40.0, bins: int = 4,
                      seed: int = 0) -> dict:
    """How far two modes of the ADI folder disagree on the static surfaces of the scene.

    Each mode is prepared as in :func:`load_adi` (same grid) and gets its own plane reference.
    Compared are the pixels on a fitted plane in both modes, on the same surface (the two
    references within ``same_surface_mm``) and ``edge_px`` pixels inside that common area
    (away from depth edges, the person, invalid and unreliable pixels). A consistency check:
    neither mode is ground truth.

    Returns:
        :func:`range_disagreement`'s dictionary (differences = first mode − second mode, mm),
        plus ``modes``.
    """
    prepared = []
    for mode in modes:
        rng_mm, amp, k = adi_reduced(directory, mode, downsample=downsample, fov_deg=fov_deg,
                                     max_confidence=max_confidence)
        prepared.append((rng_mm, amp, adi_reference(rng_mm, k, seed=seed)))
    (r_a, amp_a, ref_a), (r_b, amp_b, ref_b) = prepared
    out = range_disagreement(r_a, r_b, ref_a.reference_mm, ref_b.reference_mm, amp_a, amp_b,
                             edge_px=edge_px, same_surface_mm=same_surface_mm, bins=bins,
                             labels=ref_b.plane_index)
    return {"modes": list(modes), **out}


# over 60 lines: one flat statistics table, half of it the docstring naming its JSON keys
def range_disagreement(range_a: np.ndarray, range_b: np.ndarray, reference_a: np.ndarray,
                       reference_b: np.ndarray, amplitude_a: np.ndarray,
                       amplitude_b: np.ndarray, *, edge_px: int = 2,
                       same_surface_mm: float = 40.0, bins: int = 4,
                       labels: np.ndarray | None = None) -> dict:
    """Statistics of ``range_a − range_b`` on the surfaces both references cover.

    Args:
        range_a, range_b: (H, W) float radial range in mm, NaN invalid.
        reference_a, reference_b: (H, W) float plane-reference range in mm, NaN off the planes.
        amplitude_a, amplitude_b: (H, W) float amplitude in each camera's units.
        edge_px: the compared area is the common area eroded by this many pixels.
        same_surface_mm: pixels whose two references differ by more are left out (a plane of
            one mode that the other did not find, or the person moved).
        bins: quantile bins per descriptor.
        labels: (H, W) int surface of each pixel (e.g. the second frame's plane index), -1 none.

    Returns:
        JSON-ready dict, mm rounded to 0.1: ``n``, ``share_of_pixels``, ``median_mm``,
        ``mad_mm`` (median |d − median|), ``robust_sigma_mm`` (1.4826 MAD), ``mean_mm``,
        ``rms_mm``, ``percentiles_mm`` {5, 25, 50, 75, 95}, ``slope_mm_per_m`` (least squares
        of d on range within 5 robust sigma: a scale difference between the modes),
        ``spearman`` of d with range and both amplitudes, and ``by_range_mm`` /
        ``by_amplitude_a`` / ``by_amplitude_b`` bins (``lo``, ``hi``, ``n``, ``median_mm``,
        ``mad_mm``); with ``labels`` also ``by_surface`` (``surface``, ``range_mm`` median,
        ``n``, ``median_mm``, ``mad_mm``).

    Raises:
        MismatchError: no pixel to compare.
    """
    from scipy.ndimage import binary_erosion
    from scipy.stats import spearmanr

    both = (np.isfinite(reference_a) & np.isfinite(reference_b) & np.isfinite(range_a)
            & np.isfinite(range_b))
    with np.errstate(invalid="ignore"):
        both &= np.abs(np.nan_to_num(reference_a) - np.nan_to_num(reference_b)) <= same_surface_mm
    use = binary_erosion(both, iterations=edge_px, border_value=0) if edge_px > 0 else both
    if use.sum() < 2:
        raise MismatchError("the two frames share no static surface to compare")
    d = (np.asarray(range_a, np.float64) - np.asarray(range_b, np.float64))[use]
    rng_mm = np.asarray(reference_b, np.float64)[use]
    amps = {"a": np.asarray(amplitude_a, np.float64)[use],
            "b": np.asarray(amplitude_b, np.float64)[use]}
    med = float(np.median(d))
    mad = float(np.median(np.abs(d - med)))
    core = np.abs(d - med) <= 5 * max(1.4826 * mad, 1e-9)
    slope = np.polyfit(rng_mm[core] / 1000.0, d[core], 1)[0] if core.sum() > 2 else np.nan
    pct = np.percentile(d, [5, 25, 50, 75, 95])
    return {
        "n": int(d.size), "share_of_pixels": _r(use.mean(), 3),
        "median_mm": _r(med), "mad_mm": _r(mad), "robust_sigma_mm": _r(1.4826 * mad),
        "mean_mm": _r(d.mean()), "rms_mm": _r(np.sqrt(np.mean(d * d))),
        "percentiles_mm": {str(q): _r(v) for q, v in zip((5, 25, 50, 75, 95), pct, strict=True)},
        "slope_mm_per_m": _r(slope),
        "spearman": {"range": _r(spearmanr(rng_mm, d)[0], 2),
                     "amplitude_a": _r(spearmanr(amps["a"], d)[0], 2),
                     "amplitude_b": _r(spearmanr(amps["b"], d)[0], 2)},
        "by_range_mm": _binned(rng_mm, d, bins),
        "by_amplitude_a": _binned(amps["a"], d, bins),
        "by_amplitude_b": _binned(amps["b"], d, bins),
        **({} if labels is None else {"by_surface": _by_label(labels[use], rng_mm, d)}),
    }


def _by_label(labels: np.ndarray, range_mm: np.ndarray, d: np.ndarray) -> list[dict]:
    """Median range, median and MAD of d (N,) per label (N,) int, nearest surface first."""
    out = []
    for lab in np.unique(labels[labels >= 0]):
        sel = labels == lab
        med = float(np.median(d[sel]))
        out.append({"surface": int(lab), "range_mm": _r(np.median(range_mm[sel]), 0),
                    "n": int(sel.sum()), "median_mm": _r(med),
                    "mad_mm": _r(np.median(np.abs(d[sel] - med)))})
    return sorted(out, key=lambda c: c["range_mm"])


def _binned(x: np.ndarray, d: np.ndarray, bins: int) -> list[dict]:
    """Median and MAD of d (N,) in quantile bins of x (N,)."""
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    out = []
    for i, (lo, hi) in enumerate(itertools.pairwise(edges)):
        sel = (x >= lo) & ((x <= hi) if i == len(edges) - 2 else (x < hi))
        if not sel.any():
            continue
        med = float(np.median(d[sel]))
        out.append({"lo": _r(lo), "hi": _r(hi), "n": int(sel.sum()), "median_mm": _r(med),
                    "mad_mm": _r(np.median(np.abs(d[sel] - med)))})
    return out


def _r(value: float, digits: int = 1) -> float:
    """``value`` rounded for printing (NaN stays NaN; no "-0.0")."""
    return round(float(value), digits) + 0.0


def format_disagreement(result: dict) -> str:
    """:func:`mode_disagreement`'s result as a few lines of text (the package template
    ``templates/mode_disagreement.txt``)."""
    return render("mode_disagreement.txt", r=result)
