"""Surfaces whose brightness depends on the view: glossy and metal parts the predictor cannot light.

The predictor's light transport is Lambertian: it infers each pixel's albedo from the real
amplitude (``a = P ρ cosθ / r²``) and sends light on from there in every direction alike. A
Lambertian surface point then has the same apparent albedo from every view of a sweep; a
specular one does not — its retro-reflection rises steeply as its normal turns to the camera
(a rough metal's GGX lobe of α ≈ 0.15 falls ~40× between 0° and 20°), and a dim specular pixel
shows mostly the mirror image of other surfaces, i.e. a longer range no Lambertian model
predicts. Measured on path-traced sweeps of the benchmark's scenes (session 23, development
seeds 3001-3006, 6 views), the share of pixels above ``SPECULAR_LOG_RATIO``: metal 47 %, glossy
plastic 5.4 %, diffuse and translucent 0.1 %; on the built-in renderer's sweeps of the same
scenes (every surface Lambertian) 0.0 % of diffuse, 0.2 % of translucent pixels. Such pixels
are left out of fits and scores, as depth-edge pixels can be, and counted in the report: the
data, not the material, says which surfaces the model cannot explain.

**Whole surfaces** (session 37). Specularity belongs to a material, and a material to a
surface: where at least ``SURFACE_SHARE`` of a smooth surface's judged pixels (the reference
split at its depth edges and creases, :func:`reference_surfaces`) are flagged, the whole
surface is, with the unjudged band at its edges. The pixel test alone misses a metal part's dim
faces, which show the mirror image of the table at about the same brightness from every view,
and its rim, which lies in the edge band the test does not judge — there the range is tens of
millimetres long. Measured on path-traced sweeps (seed 960, 7 sweeps of 6 views): metal pixels
left out 50 % by the pixel test, 94 % with whole surfaces; diffuse 0.0 % and 0.3 % (the rims
of metal parts on the table), glossy plastic 0.1 % both, translucent 0 %; the built-in
renderer's sweeps (seed 961, 4 sweeps) 0.0 % and ≤ 0.1 % of diffuse pixels.

**From one view** (session 37, :func:`incidence_falloff`): the light sits at the camera, so a
Lambertian surface's apparent albedo does not depend on the incidence angle, and a specular
one dims as its normal turns from the camera. This needs no poses: a static recording, which
sees every point from one view, is judged this way only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from ..frame import ToFFrame
from ..pose import invert_pose, pose_m_to_mm, transform_points
from ..sim.tof import surface_from_reference
from .features import EDGE_JUMP_MM, EDGE_JUMP_REL, depth_edges
from .predict import fill_holes, median_albedo

#: RMS log-ratio of a point's apparent albedo between views above which it is specular
#: (e^0.2 ≈ 1.22: a fifth brighter from another view, after the pair's common gain)
SPECULAR_LOG_RATIO = 0.2
#: a reprojected point is the same surface when the other view's reference range agrees
#: within this (mm); otherwise it is occluded there
SAME_SURFACE_MM = 5.0
#: pixels this close to a reference depth edge (px) are not judged
EDGE_MARGIN_PX = 1
#: a surface of the reference ends where its normal turns by more than this to a neighbour
CREASE_DEG = 30.0
#: a smooth surface is specular as a whole when at least this share of its judged pixels is
#: (specularity belongs to a material; see :func:`_whole_surfaces`), judged on at least
#: ``MIN_JUDGED`` pixels
SURFACE_SHARE = 0.3
MIN_JUDGED = 16
#: from one view, a surface whose apparent albedo falls faster than this with the incidence
#: angle is specular (log units per degree: 18 % per 10°; see :func:`incidence_falloff`) ...
FALLOFF_PER_DEG = 0.02
#: ... judged on the surfaces that span at least this range of incidence angles, and only
#: where the incidence explains at least this share of the variance of the log apparent
#: albedo over the surface (a lobe most of it, 0.5-0.96 on path-traced metal; a texture that
#: happens to be brighter on one side of a surface next to none)
MIN_SPAN_DEG = 8.0
MIN_EXPLAINED = 0.25


def _world_points(frame: ToFFrame) -> np.ndarray:
    """(H, W, 3) float64 reference points of ``frame`` in the arm's base frame, mm."""
    return transform_points(pose_m_to_mm(frame.pose),
                            frame.intrinsics.backproject(frame.reference_mm))


def _seen_from(points: np.ndarray, frame: ToFFrame) -> tuple[np.ndarray, np.ndarray]:
    """Where ``frame`` sees the base-frame ``points`` (H, W, 3, mm): its nearest pixel's flat
    index and whether that pixel sees the same surface (in view, not occluded)."""
    k = frame.intrinsics
    local = transform_points(invert_pose(pose_m_to_mm(frame.pose)), points)
    with np.errstate(invalid="ignore", divide="ignore"):
        uv = np.rint(k.project(local))
    ok = np.isfinite(uv).all(axis=-1) & (local[..., 2] > 0)
    u = np.where(ok, uv[..., 0], -1).astype(np.int64)
    v = np.where(ok, uv[..., 1], -1).astype(np.int64)
    ok &= (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
    flat = np.where(ok, v * k.width + u, 0)
    their = frame.reference_mm.ravel()[flat]
    with np.errstate(invalid="ignore"):
        ok &= np.abs(their - np.linalg.norm(local, axis=-1)) < SAME_SURFACE_MM
    return flat, ok


def _log_albedo(frame: ToFFrame) -> np.ndarray:
    """(H, W) float64 log apparent albedo (at unit light power); NaN within
    ``EDGE_MARGIN_PX`` of a reference depth edge, where the median window mixes two surfaces
    and the reference's normals are unreliable."""
    albedo = median_albedo(frame, 1.0)
    near_edge = ndimage.binary_dilation(depth_edges(frame.reference_mm),
                                        iterations=EDGE_MARGIN_PX)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((albedo > 0) & ~near_edge, np.log(albedo), np.nan)


def view_dependence(frames: Sequence[ToFFrame]) -> list[np.ndarray]:
    """Per frame, (H, W) float64 RMS over the other frames of log(apparent albedo there /
    apparent albedo here) at the same surface point, each pair's median log-ratio taken out;
    NaN where no other frame sees it (or without poses). The light's power cancels."""
    if len(frames) < 2 or any(f.pose is None for f in frames):
        return [np.full(f.range_mm.shape, np.nan) for f in frames]
    log_albedo = [_log_albedo(f) for f in frames]
    out = []
    for i, frame in enumerate(frames):
        points = _world_points(frame)
        total = np.zeros(frame.range_mm.shape)
        count = np.zeros(frame.range_mm.shape)
        for j, other in enumerate(frames):
            if j == i:
                continue
            flat, seen = _seen_from(points, other)
            d = log_albedo[j].ravel()[flat] - log_albedo[i]
            use = seen & np.isfinite(d)
            if not use.any():
                continue
            # a frame brighter as a whole (exposure, warm-up) is no surface's doing: the
            # pair's common gain, the median over the points both see, is taken out
            d = d - np.median(d[use])
            total += np.where(use, d * d, 0.0)
            count += use
        with np.errstate(invalid="ignore", divide="ignore"):
            out.append(np.where(count > 0, np.sqrt(total / count), np.nan))
    return out


def incidence_deg(frame: ToFFrame) -> np.ndarray:
    """(H, W) float64 angle (degrees) between each pixel's ray and the reference's normal there
    (the normals :func:`.predict.raw_albedo` infers the albedo with)."""
    k = frame.intrinsics
    normal = surface_from_reference(fill_holes(frame.reference_mm), k, 1.0).normal
    cos = -np.sum(normal * k.ray_directions(), axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def incidence_falloff(frame: ToFFrame) -> np.ndarray:
    """(H, W) float64 least-squares slope (log units per degree) of the apparent albedo
    against the incidence angle over each smooth surface (:func:`reference_surfaces`); NaN on
    surfaces with fewer than ``MIN_JUDGED`` judged pixels, spanning less than
    ``MIN_SPAN_DEG`` or whose variance the incidence explains less than ``MIN_EXPLAINED`` of,
    and off every surface.

    Why one view can tell: the light sits at the camera, so a Lambertian surface's apparent
    albedo does not depend on the incidence angle (a rough diffuse one rises a little towards
    grazing: backscatter), while a specular one retro-reflects along its normal and falls
    steeply as the normal turns away (a rough metal's lobe: ~40× between 0° and 20°). A
    texture varies too, but not in step with the incidence. Measured on path-traced views
    (session 37): metal surfaces −0.03 to −0.16 per degree, diffuse and glossy plastic
    ones within ±0.006 (+0.03 at grazing incidence)."""
    labels = reference_surfaces(frame)
    theta = incidence_deg(frame)
    y = _log_albedo(frame)
    use = (labels > 0) & np.isfinite(y) & np.isfinite(theta)
    lab = np.where(use, labels, 0)
    index = np.arange(1, int(labels.max()) + 1)
    if index.size == 0:
        return np.full(labels.shape, np.nan)
    n = ndimage.sum(use, lab, index)
    t, yy = np.where(use, theta, 0.0), np.where(use, y, 0.0)
    st, sy = ndimage.sum(t, lab, index), ndimage.sum(yy, lab, index)
    stt, sty = ndimage.sum(t * t, lab, index), ndimage.sum(t * yy, lab, index)
    span = ndimage.maximum(t, lab, index) - ndimage.minimum(t, lab, index)
    syy = ndimage.sum(yy * yy, lab, index)
    with np.errstate(invalid="ignore", divide="ignore"):
        cov, var_t, var_y = n * sty - st * sy, n * stt - st * st, n * syy - sy * sy
        slope = cov / var_t
        explained = cov * cov / (var_t * var_y)
    judged = (n >= MIN_JUDGED) & (span >= MIN_SPAN_DEG) & (explained >= MIN_EXPLAINED)
    slope = np.where(judged, slope, np.nan)
    return np.where(labels > 0, np.concatenate([[np.nan], slope])[labels], np.nan)


def reference_surfaces(frame: ToFFrame) -> np.ndarray:
    """(H, W) int32 label of the smooth surface of the reference each pixel lies on (1, 2, ...;
    0 = on a depth edge, a crease or a hole): the connected pixels off every depth edge
    (:func:`.features.depth_edges`) and every crease, where the reference's normal turns by
    more than ``CREASE_DEG`` to a neighbour (a box's top and side, an object and the table it
    stands on)."""
    points = frame.intrinsics.backproject(frame.reference_mm)
    normal = np.cross(np.gradient(points, axis=1), np.gradient(points, axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    cos_limit = math.cos(math.radians(CREASE_DEG))
    crease = np.zeros(frame.reference_mm.shape, dtype=bool)
    for axis in (0, 1):
        a = np.delete(normal, -1, axis=axis)
        b = np.delete(normal, 0, axis=axis)
        turn = ~(np.sum(a * b, axis=-1) >= cos_limit)   # NaN (a hole) counts as a turn
        lo, hi = [(0, 0), (0, 0)], [(0, 0), (0, 0)]
        lo[axis], hi[axis] = (1, 0), (0, 1)
        crease |= np.pad(turn, lo) | np.pad(turn, hi)
    smooth = np.isfinite(frame.reference_mm) & ~crease & ~depth_edges(frame.reference_mm)
    labels, _ = ndimage.label(smooth)
    return labels.astype(np.int32)


def _whole_surfaces(flagged: np.ndarray, judged: np.ndarray, surfaces: np.ndarray,
                    reference_mm: np.ndarray) -> np.ndarray:
    """``flagged`` (H, W bool) grown to every surface of ``surfaces`` (labels) of which at
    least ``SURFACE_SHARE`` of the judged pixels (``judged``, at least ``MIN_JUDGED``) are
    flagged, then into the pixels beside them on the same surface that were not judged (edge
    and crease bands; not across a depth jump to the table below)."""
    n = int(surfaces.max())
    if n == 0 or not flagged.any():
        return flagged
    index = np.arange(1, n + 1)
    judged_n = ndimage.sum(judged, surfaces, index)
    flagged_n = ndimage.sum(flagged & judged, surfaces, index)
    specular = (judged_n >= MIN_JUDGED) & (flagged_n >= SURFACE_SHARE * judged_n)
    grown = flagged | np.isin(surfaces, index[specular])
    # the unjudged band on the surface's side of its edge: its edge pixel, a sloped pixel
    # beside it, and the margin of the test
    for _ in range(EDGE_MARGIN_PX + 2):
        grown |= _continued(grown, reference_mm) & ~judged
    return grown


def _continued(mask: np.ndarray, reference_mm: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels with a 4-neighbour in ``mask`` on the same surface (no depth jump
    between them, as :func:`.features.depth_edges` defines one)."""
    out = np.zeros(mask.shape, dtype=bool)
    r = np.asarray(reference_mm, dtype=np.float64)
    for axis in (0, 1):
        a, b = np.delete(r, -1, axis=axis), np.delete(r, 0, axis=axis)
        with np.errstate(invalid="ignore"):
            joined = np.abs(a - b) <= np.maximum(EDGE_JUMP_MM, EDGE_JUMP_REL * np.fmin(a, b))
        lo, hi = [(0, 0), (0, 0)], [(0, 0), (0, 0)]
        lo[axis], hi[axis] = (1, 0), (0, 1)
        out |= np.pad(joined & np.delete(mask, -1, axis=axis), lo)   # from the pixel before
        out |= np.pad(joined & np.delete(mask, 0, axis=axis), hi)    # from the pixel after
    return out


def specular_masks(frames: Sequence[ToFFrame],
                   threshold: float = SPECULAR_LOG_RATIO) -> list[np.ndarray]:
    """Per frame, (H, W) bool: pixels whose apparent albedo changes between views by more
    than ``threshold`` (RMS log-ratio) — a specular surface, not a Lambertian one — or whose
    surface's apparent albedo falls with the incidence angle in that view
    (:func:`incidence_falloff`), and the rest of every smooth surface that is mostly such
    pixels (:func:`_whole_surfaces`)."""
    out = []
    for frame, d in zip(frames, view_dependence(frames), strict=True):
        flagged = np.nan_to_num(d, nan=0.0) > threshold
        flagged |= np.nan_to_num(incidence_falloff(frame), nan=0.0) < -FALLOFF_PER_DEG
        out.append(_whole_surfaces(flagged, np.isfinite(d), reference_surfaces(frame),
                                   frame.reference_mm))
    return out
