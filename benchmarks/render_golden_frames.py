"""Render the path-traced golden frames that the simulator's multipath is validated against.

Each golden scene (a table and one to three objects, Lambertian, seen by the cell's ToF camera:
the 180x140 crop of the DS325-like 320x240 sensor, the nominal modulation frequency, a spot light
at the camera centre) is rendered with Mitsuba 3 + mitransient
(:mod:`tof_mpd_ros.sim.pathtrace`) three times — direct light only, direct + exactly one
indirect bounce, all bounces — and written with the ray caster's true range to
``test/sim/data/golden/<name>.npz`` (format: :mod:`tof_mpd_ros.sim.pathtrace.golden`).
``summary.json`` beside them collects render times, noise and the figures of each scene
(over-shoot on side faces by height, on the table by distance from the objects).

Needs the optional extra (``pip install -e '.[pathtrace]'``) and a system LLVM library (Debian:
``apt-get install libllvm19``). Usage::

    python benchmarks/render_golden_frames.py [--scenes cube_300 ...] [--spp 4096]
        [--max-depth 12] [--overwrite]
    python benchmarks/render_golden_frames.py --preview /tmp/golden_preview   # views only
    python benchmarks/render_golden_frames.py --study cube_300              # convergence
    python benchmarks/render_golden_frames.py --summary-only   # summary.json from the files

``--study`` renders one scene at increasing ``max_depth`` (same seed, so the renders differ
only by the longer paths) and twice at the production sample count with different seeds, and
prints how far each depth is from the deepest and the seed-to-seed range noise.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from tof_mpd_ros.machine import cpu_model, set_openmp_wait_policy

set_openmp_wait_policy()  # before numba and torch load OpenMP (it reads the policy once)

import numpy as np

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.pose import look_at
from tof_mpd_ros.sim.cell import CameraModel
from tof_mpd_ros.sim.objects import ObjectSpec
from tof_mpd_ros.sim.pathtrace import (
    DIRECT_ONLY,
    ONE_BOUNCE,
    GoldenFrame,
    SpotLight,
    interior_mask,
    load_golden,
    multipath_field,
    phasor_range_amplitude,
    range_noise_mm,
    render_phasor_passes,
)
from tof_mpd_ros.sim.pathtrace.golden import write_golden
from tof_mpd_ros.sim.pathtrace.render import versions
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.scene import PlacedObject, Scene, Table
from tof_mpd_ros.sim.tof import ToFConfig

REPO = Path(__file__).resolve().parents[1]
DEFAULT_OUT = REPO / "test" / "sim" / "data" / "golden"
CENTRE_XY = (450.0, 0.0)
#: all bounces: measured with --study (vs depth 20, depth 12 differs by <= 0.002 mm at albedo 0.5
#: and <= 0.37 mm at 0.9; paths escape the open scenes, so a deeper bound costs nothing)
DEFAULT_MAX_DEPTH = 32
DEFAULT_SPP = 16384
DEFAULT_SPP_DIRECT = 4096
SPP_PER_PASS = 128
# table bands for the figures: distance from the nearest object footprint, mm
TABLE_BANDS_MM = ((0.0, 25.0), (26.0, 59.0), (60.0, 150.0))
# side-surface bands: height above the table, mm
SIDE_BANDS_MM = ((25.0, 40.0), (100.0, 115.0))


@dataclass(frozen=True)
class GoldenScene:
    """A scene and the camera pose it is rendered from.

    Attributes:
        name: file stem.
        description: one sentence for the README and the file's metadata.
        scene: table and objects (base frame, mm).
        camera_to_base_mm: (4, 4) float64 camera optical frame -> base frame, mm.
    """

    name: str
    description: str
    scene: Scene
    camera_to_base_mm: np.ndarray


def _placed(index: int, kind: str, dims: tuple[float, float, float], albedo: float,
            xy: tuple[float, float], yaw_deg: float = 0.0, apex_mm: float = 0.0) -> PlacedObject:
    spec = ObjectSpec(0, kind, dims, albedo, apex_offset_mm=apex_mm)
    return PlacedObject(spec, index, xy[0], xy[1], 0.0, math.radians(yaw_deg))


def _view(centre_xy: tuple[float, float], top_mm: float, above_mm: float, *,
          azimuth_deg: float = 245.0, offset_mm: float = 200.0, aim_shift_mm: float = 60.0,
          aim_z_mm: float = 40.0) -> np.ndarray:
    """Camera ``above_mm`` over the highest top, ``offset_mm`` from the objects' centre towards
    ``azimuth_deg``, aimed at a point ``aim_shift_mm`` from the centre towards the camera and
    ``aim_z_mm`` above the table: looking down, tilted so the near side faces are seen."""
    az = math.radians(azimuth_deg)
    toward = np.array([math.cos(az), math.sin(az)])
    eye = np.array([*(np.asarray(centre_xy) + offset_mm * toward), top_mm + above_mm])
    aim = np.array([*(np.asarray(centre_xy) + aim_shift_mm * toward), aim_z_mm])
    return look_at(eye, aim)


def _cube(albedo: float, above_mm: float, name: str, what: str) -> GoldenScene:
    cube = _placed(1, "box", (150.0, 150.0, 150.0), albedo, CENTRE_XY, 20.0)
    scene = Scene(Table(centre_xy_mm=CENTRE_XY, albedo=albedo), (cube,))
    return GoldenScene(name, f"150 mm cube rotated 20 deg on the table, {what}, camera "
                       f"{above_mm:.0f} mm above the cube top looking down at two side faces",
                       scene, _view(CENTRE_XY, 150.0, above_mm))


def golden_scenes() -> list[GoldenScene]:
    """The golden scenes (at least the 8 of issue 12), in a fixed order."""
    scenes = [
        _cube(0.5, 300.0, "cube_300", "cube and table albedo 0.5"),
        _cube(0.5, 180.0, "cube_180", "cube and table albedo 0.5"),
        _cube(0.5, 350.0, "cube_350", "cube and table albedo 0.5"),
        _cube(0.15, 300.0, "cube_dark", "cube and table albedo 0.15 (dark)"),
        _cube(0.9, 300.0, "cube_bright", "cube and table albedo 0.9 (bright)"),
    ]
    cylinder = _placed(1, "cylinder", (120.0, 120.0, 150.0), 0.5, CENTRE_XY)
    scenes.append(GoldenScene(
        "cylinder", "upright cylinder 120 mm across, 150 mm tall, albedo 0.5 on a table of 0.5, "
        "camera 300 mm above its top", Scene(Table(centre_xy_mm=CENTRE_XY, albedo=0.5),
                                             (cylinder,)),
        _view(CENTRE_XY, 150.0, 300.0, offset_mm=170.0, aim_shift_mm=50.0)))
    sphere = _placed(1, "sphere", (150.0, 150.0, 150.0), 0.5, CENTRE_XY)
    scenes.append(GoldenScene(
        "sphere", "sphere 150 mm across resting on the table, albedo 0.5 on a table of 0.5, "
        "camera 300 mm above its top", Scene(Table(centre_xy_mm=CENTRE_XY, albedo=0.5),
                                             (sphere,)),
        _view(CENTRE_XY, 150.0, 300.0, offset_mm=170.0, aim_shift_mm=50.0)))
    clutter = (
        _placed(1, "box", (120.0, 100.0, 90.0), 0.6, (410.0, -55.0), 30.0),
        _placed(2, "cylinder", (90.0, 90.0, 140.0), 0.4, (530.0, -30.0)),
        _placed(3, "prism", (130.0, 110.0, 90.0), 0.7, (450.0, 85.0), -15.0, 20.0),
    )
    centre = (463.0, 0.0)
    scenes.append(GoldenScene(
        "clutter", "box (albedo 0.6), cylinder (0.4) and triangular prism (0.7) 25-40 mm apart "
        "on a table of 0.5, camera 300 mm above the tallest top",
        Scene(Table(centre_xy_mm=CENTRE_XY, albedo=0.5), clutter),
        _view(centre, 140.0, 300.0, azimuth_deg=225.0, offset_mm=180.0, aim_shift_mm=40.0,
              aim_z_mm=30.0)))
    wall = (
        _placed(1, "box", (30.0, 400.0, 250.0), 0.5, (575.0, 0.0)),
        _placed(2, "box", (120.0, 120.0, 100.0), 0.5, (495.0, -20.0)),
    )
    scenes.append(GoldenScene(
        "wall", "120 mm box (100 mm tall) 5 mm in front of a 250 mm tall wall (a 30 mm thick "
        "box), all albedo 0.5 on a table of 0.5, camera 300 mm above the box looking at the "
        "concave corners", Scene(Table(centre_xy_mm=CENTRE_XY, albedo=0.5), wall),
        look_at(np.array([300.0, -90.0, 400.0]), np.array([520.0, -10.0, 70.0]))))
    return scenes


def _footprint_distance(points_xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) distance (mm) from points to a convex polygon ((K, 2), ccw); 0 inside."""
    d = np.full(points_xy.shape[0], np.inf)
    inside = np.ones(points_xy.shape[0], dtype=bool)
    for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        ab = b - a
        t = np.clip(((points_xy - a) @ ab) / (ab @ ab), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(points_xy - (a + t[:, None] * ab), axis=1))
        inside &= (ab[0] * (points_xy[:, 1] - a[1]) - ab[1] * (points_xy[:, 0] - a[0])) >= 0.0
    return np.where(inside, 0.0, d)


def _median(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return round(float(np.median(finite)), 3) if finite.size else None


def scene_figures(frame: GoldenFrame) -> dict[str, object]:
    """Multipath figures of a golden frame: medians of range − truth (mm) over pixels inside
    one face (3×3 neighbourhood on the same face, so no mixed edge pixel counts).

    Side surfaces (normal within 10° of horizontal) by height above the table; table pixels by
    distance from the nearest footprint, with the all-bounce / one-bounce over-shoot ratio.
    """
    surface = render_surface(frame.scene, frame.camera_to_base_mm, frame.intrinsics)
    pose = frame.camera_to_base_mm
    points = surface.points_mm() @ pose[:3, :3].T + pose[:3, 3]
    normal_z = (surface.normal @ pose[:3, :3].T)[..., 2]
    inner = interior_mask(surface.object_id, surface.normal, half_px=1)
    err_all = np.where(inner, frame.range_all_mm - frame.true_range_mm, np.nan)
    err_one = np.where(inner, frame.range_one_bounce_mm - frame.true_range_mm, np.nan)
    err_direct = np.where(inner, frame.range_direct_mm - frame.true_range_mm, np.nan)
    out: dict[str, object] = {
        "interior_pixels": int(inner.sum()),
        "direct_minus_truth_median_mm": _median(err_direct),
        "direct_minus_truth_p99_abs_mm": round(float(np.nanpercentile(np.abs(err_direct), 99)),
                                               3),
        "all_minus_truth_median_mm": _median(err_all),
        "all_minus_truth_p99_mm": round(float(np.nanpercentile(err_all, 99)), 3),
        "all_minus_truth_max_mm": round(float(np.nanmax(err_all)), 3),
        "one_bounce_minus_truth_median_mm": _median(err_one),
    }
    side = (surface.object_id > 0) & (np.abs(normal_z) < math.sin(math.radians(10.0)))
    height = points[..., 2] - frame.scene.table.height_mm
    out["side"] = [{"height_mm": list(band), "pixels": int((m := side & inner
                                                            & (height >= band[0])
                                                            & (height <= band[1])).sum()),
                    "all_mm": _median(err_all[m]), "one_bounce_mm": _median(err_one[m])}
                   for band in SIDE_BANDS_MM]
    table = surface.object_id == 0
    xy = points[..., :2].reshape(-1, 2)
    dist = np.full(xy.shape[0], np.inf)
    for obj in frame.scene.objects:
        dist = np.minimum(dist, _footprint_distance(np.nan_to_num(xy), obj.footprint_base()))
    dist = dist.reshape(table.shape)
    bands = []
    for lo, hi in TABLE_BANDS_MM:
        m = table & inner & (dist >= lo) & (dist <= hi)
        all_mm, one_mm = _median(err_all[m]), _median(err_one[m])
        bands.append({"distance_mm": [lo, hi], "pixels": int(m.sum()), "all_mm": all_mm,
                      "one_bounce_mm": one_mm,
                      "all_over_one": round(all_mm / one_mm, 2)
                      if all_mm is not None and one_mm else None})
    out["table"] = bands
    return out


def _render(spec: GoldenScene, *, intrinsics: Intrinsics, mod_freq_hz: float, light: SpotLight,
            spp: int, spp_direct: int, max_depth: int, seed: int, command: str,
            machine: str, lib_versions: dict[str, str]) -> GoldenFrame:
    """Render one golden scene (direct, one bounce, all bounces) and assemble the frame."""
    truth = render_surface(spec.scene, spec.camera_to_base_mm, intrinsics).range_mm
    ranges, noises, seconds = {}, {}, {}
    amplitude = None
    plan = (("direct", DIRECT_ONLY, spp_direct), ("one_bounce", ONE_BOUNCE, spp),
            ("all", max_depth, spp))
    for key, depth, n in plan:
        t0 = time.perf_counter()
        passes = render_phasor_passes(spec.scene, spec.camera_to_base_mm, intrinsics,
                                      mod_freq_hz=mod_freq_hz, spp=n, max_depth=depth, seed=seed,
                                      light=light, spp_per_pass=min(n, SPP_PER_PASS))
        seconds[key] = round(time.perf_counter() - t0, 2)
        ranges[key], amp = phasor_range_amplitude(passes.mean(axis=0), mod_freq_hz)
        noises[key] = range_noise_mm(passes, mod_freq_hz)
        if key == "all":
            amplitude = amp
        print(f"  {key:10s} max_depth {depth:2d}  {n:5d} spp  {seconds[key]:7.1f} s  "
              f"median noise {np.nanmedian(noises[key]):.3f} mm", flush=True)
    lit = np.isfinite(ranges["all"]) & np.isfinite(truth)
    noise = {}
    for key in ("all", "one_bounce"):
        values = noises[key][lit & np.isfinite(noises[key])]
        noise[f"{key}_median_mm"] = round(float(np.median(values)), 4)
        noise[f"{key}_p95_mm"] = round(float(np.percentile(values, 95)), 4)
        noise[f"{key}_p99_mm"] = round(float(np.percentile(values, 99)), 4)
    assert amplitude is not None
    return GoldenFrame(
        name=spec.name, description=spec.description, scene=spec.scene,
        camera_to_base_mm=spec.camera_to_base_mm, intrinsics=intrinsics,
        mod_freq_hz=mod_freq_hz, light=light,
        spp={"all": spp, "one_bounce": spp, "direct": spp_direct},
        max_depth={"all": max_depth, "one_bounce": ONE_BOUNCE, "direct": DIRECT_ONLY},
        seed=seed, versions=lib_versions, command=command, cpu_model=machine,
        render_seconds=seconds, noise=noise,
        range_all_mm=ranges["all"], range_one_bounce_mm=ranges["one_bounce"],
        range_direct_mm=ranges["direct"], amplitude_all=amplitude, true_range_mm=truth,
        range_all_noise_mm=noises["all"], range_one_bounce_noise_mm=noises["one_bounce"])


def _preview(scenes: list[GoldenScene], intrinsics: Intrinsics, out: Path) -> None:
    """Write each scene's ray-cast range image as a PNG (no path tracing)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out.mkdir(parents=True, exist_ok=True)
    for spec in scenes:
        s = render_surface(spec.scene, spec.camera_to_base_mm, intrinsics)
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.6))
        ax[0].imshow(s.range_mm, cmap="viridis")
        ax[0].set_title(f"{spec.name}: range (mm)")
        ax[1].imshow(s.object_id, cmap="tab10", vmin=-1, vmax=9)
        ax[1].set_title("object id")
        fig.savefig(out / f"{spec.name}.png", dpi=80)
        plt.close(fig)
        print(out / f"{spec.name}.png")


def _study(spec: GoldenScene, *, intrinsics: Intrinsics, mod_freq_hz: float, light: SpotLight,
           spp: int, depths: tuple[int, ...]) -> dict[str, object]:
    """Depth convergence (same seed) and seed-to-seed noise at ``spp`` of one scene."""
    truth = render_surface(spec.scene, spec.camera_to_base_mm, intrinsics).range_mm
    study_spp = 1024
    ranges = {}
    for depth in depths:
        t0 = time.perf_counter()
        passes = render_phasor_passes(spec.scene, spec.camera_to_base_mm, intrinsics,
                                      mod_freq_hz=mod_freq_hz, spp=study_spp, max_depth=depth,
                                      seed=7, light=light, spp_per_pass=SPP_PER_PASS)
        ranges[depth] = phasor_range_amplitude(passes.mean(axis=0), mod_freq_hz)[0]
        print(f"  depth {depth:2d}: {time.perf_counter() - t0:.1f} s", flush=True)
    deepest = ranges[depths[-1]]
    depth_rows = []
    for depth in depths[:-1]:
        diff = np.abs(ranges[depth] - deepest)
        depth_rows.append({"max_depth": depth, "median_mm": float(np.nanmedian(diff)),
                           "p99_mm": float(np.nanpercentile(diff, 99)),
                           "max_mm": float(np.nanmax(diff))})
    seeds = []
    for seed in (1, 2):
        passes = render_phasor_passes(spec.scene, spec.camera_to_base_mm, intrinsics,
                                      mod_freq_hz=mod_freq_hz, spp=spp,
                                      max_depth=depths[-1], seed=seed, light=light,
                                      spp_per_pass=SPP_PER_PASS)
        seeds.append(phasor_range_amplitude(passes.mean(axis=0), mod_freq_hz)[0])
    per_pixel = (seeds[0] - seeds[1]) / math.sqrt(2.0)
    field = (multipath_field(seeds[0], truth) - multipath_field(seeds[1], truth)) / math.sqrt(2.0)
    return {"scene": spec.name, "depth_vs_deepest": depth_rows, "deepest": depths[-1],
            "spp": spp, "pixel_noise_rms_mm": float(np.sqrt(np.nanmean(per_pixel ** 2))),
            "pixel_noise_p95_mm": float(np.nanpercentile(np.abs(per_pixel), 95)),
            "field_noise_rms_mm": float(np.sqrt(np.nanmean(field ** 2))),
            "field_noise_p95_mm": float(np.nanpercentile(np.abs(field), 95))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder")
    parser.add_argument("--scenes", nargs="*", default=None, help="scene names (default: all)")
    parser.add_argument("--spp", type=int, default=DEFAULT_SPP,
                        help="samples per pixel of the one-bounce and all-bounce images")
    parser.add_argument("--spp-direct", type=int, default=DEFAULT_SPP_DIRECT,
                        help="samples per pixel of the direct-only image")
    parser.add_argument("--max-depth", type=int, default=DEFAULT_MAX_DEPTH,
                        help="Mitsuba max_depth of the all-bounce image")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--overwrite", action="store_true", help="replace existing files")
    parser.add_argument("--preview", type=Path, default=None,
                        help="only write ray-cast previews (PNG) of the scenes to this folder")
    parser.add_argument("--study", default=None, metavar="SCENE",
                        help="only run the depth / noise convergence study on one scene")
    parser.add_argument("--summary-only", action="store_true",
                        help="only recompute summary.json from the files in --out")
    args = parser.parse_args(argv)

    intrinsics = CameraModel().intrinsics
    mod_freq_hz = ToFConfig.nominal().mod_freq_hz
    light = SpotLight()
    scenes = golden_scenes()
    known = {s.name for s in scenes}
    wanted = set(args.scenes) if args.scenes else known
    if wanted - known:
        parser.error(f"unknown scenes {sorted(wanted - known)}; known: {sorted(known)}")
    scenes = [s for s in scenes if s.name in wanted]
    if args.preview is not None:
        _preview(scenes, intrinsics, args.preview)
        return 0
    if args.summary_only:
        summary_path = args.out / "summary.json"
        summary = {s.name: _summary_entry(args.out / f"{s.name}.npz") for s in scenes
                   if (args.out / f"{s.name}.npz").exists()}
        summary_path.write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
        print(summary_path)
        return 0
    if args.study is not None:
        if args.study not in known:
            parser.error(f"unknown scene {args.study!r}; known: {sorted(known)}")
        spec = next(s for s in golden_scenes() if s.name == args.study)
        result = _study(spec, intrinsics=intrinsics, mod_freq_hz=mod_freq_hz, light=light,
                        spp=args.spp, depths=(3, 4, 5, 6, 8, 12, 20))
        print(json.dumps(result, indent=2))
        return 0

    given = sys.argv[1:] if argv is None else argv
    command = " ".join(["python benchmarks/render_golden_frames.py", shlex.join(given)]).strip()
    machine = cpu_model()
    lib_versions = versions()
    args.out.mkdir(parents=True, exist_ok=True)
    summary_path = args.out / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    for spec in scenes:
        path = args.out / f"{spec.name}.npz"
        if path.exists() and not args.overwrite:
            print(f"{path} exists (pass --overwrite to replace it); skipped")
            continue
        print(f"{spec.name}: {spec.description}", flush=True)
        frame = _render(spec, intrinsics=intrinsics, mod_freq_hz=mod_freq_hz, light=light,
                        spp=args.spp, spp_direct=args.spp_direct, max_depth=args.max_depth,
                        seed=args.seed, command=command, machine=machine,
                        lib_versions=lib_versions)
        write_golden(path, frame, overwrite=args.overwrite)
        summary[spec.name] = _summary_entry(path)
        summary_path.write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
        print(json.dumps(summary[spec.name]["figures"]), flush=True)
    return 0


def _summary_entry(path: Path) -> dict[str, object]:
    """summary.json entry of one written golden file."""
    frame = load_golden(path)
    return {"description": frame.description, "command": frame.command,
            "cpu_model": frame.cpu_model, "versions": frame.versions,
            "spp": frame.spp, "max_depth": frame.max_depth,
            "render_seconds": frame.render_seconds, "noise": frame.noise,
            "figures": scene_figures(frame), "file_kb": round(path.stat().st_size / 1024.0, 1)}


if __name__ == "__main__":
    raise SystemExit(main())
