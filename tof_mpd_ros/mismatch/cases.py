"""Concealed-effect test cases for the mismatch benchmark: "real" recordings the tool runs on.

Each case is a short sweep of the camera over a random scene of the simulated cell. The "real"
frames come from a path that differs from the tool's predictor on purpose, so the tool faces
model mismatch as with a real camera:

* geometry is ray-cast from the full scene, supersampled 3 x 3 per pixel (the predictor only
  has the reference range image, one sample per pixel);
* the reference is the structured-light fusion (noisy, with occlusion holes), not the truth;
* pose errors are physical: a hand-eye error renders from the truly displaced camera, a time
  offset renders from the pose the arm had ``offset_ms`` later along its (variable-speed)
  trajectory, while the recording holds the nominal poses and stamps;
* every other concealed effect is the simulator's effect module with drawn parameters, and
  albedo, material and light transport follow the scene, not the predictor's assumptions.

The labels (effect names and parameters) are returned separately; the tool never sees them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..arm.viewpoints import view_pose_mm
from ..camera import Intrinsics
from ..frame import ToFFrame
from ..pose import make_pose, pose_mm_to_m, rotvec_to_matrix
from ..sim.raycast import render_surface
from ..sim.scene import Scene, make_scene
from ..sim.structured_light import FusionConfig, reference_range
from ..sim.tof import ToFConfig, centre_samples, render_tof, wiggle_mm
from .profile import with_amplitude_units

#: effects the benchmark conceals; ``phase_wrapping`` is nominal and has no parameter, and at
#: 30 MHz nothing in the workspace wraps, so it cannot be concealed in the cell
CONCEALABLE = ("multipath", "mixed_pixels", "wiggling", "amplitude_bias", "lens_scatter",
               "subsurface", "pixel_offset", "temperature_drift", "time_offset", "hand_eye",
               "noise_model")
#: image grid of the benchmark (the DS325 field of view at a reduced resolution, for speed)
DEFAULT_INTRINSICS = Intrinsics.from_fov(96, 72, 74.0)
#: seconds between frames of a sweep
FRAME_PERIOD_S = 0.1
#: a cheaper fusion than the paper's 10 x 3 scans (the benchmark needs many frames)
BENCH_FUSION = FusionConfig(n_rotations=5, distance_offsets_mm=(-30.0, 30.0))


@dataclass(frozen=True)
class Sweep:
    """A camera path: view parameters interpolated along s in [0, 1], with varying speed.

    Attributes:
        start, end: (height_mm, tilt_deg, azimuth_deg, roll_deg) at s = 0 and s = 1.
        wobble: speed modulation in [0, 1): s(t) = t/T + wobble · sin(2π t/T) / (2π).
        duration_s: T, the time of the whole sweep.
    """

    start: tuple[float, float, float, float]
    end: tuple[float, float, float, float]
    wobble: float
    duration_s: float

    def s_at(self, t_s: float) -> float:
        x = t_s / self.duration_s
        return x + self.wobble * math.sin(2.0 * math.pi * x) / (2.0 * math.pi)

    def pose_mm(self, scene: Scene, t_s: float) -> np.ndarray:
        """(4, 4) camera-to-base pose at time ``t_s`` (mm)."""
        s = self.s_at(t_s)
        view = [a + (b - a) * s for a, b in zip(self.start, self.end, strict=True)]
        return view_pose_mm(scene.objects_centroid_mm(), scene.top_height_mm(), *view)


def draw_sweep(rng: np.random.Generator, n_frames: int) -> Sweep:
    """A random sweep 180–350 mm above the objects, tilt 12–30°, orbiting 40–70° in azimuth
    (the arm moves at roughly 0.1–0.3 m/s, so a stamp offset of tens of ms matters)."""
    h0 = rng.uniform(200.0, 330.0)
    t0 = rng.uniform(15.0, 28.0)
    a0 = rng.uniform(0.0, 360.0)
    r0 = rng.uniform(-180.0, 180.0)
    end = (float(np.clip(h0 + rng.uniform(-40.0, 40.0), 180.0, 350.0)),
           float(np.clip(t0 + rng.uniform(-6.0, 6.0), 12.0, 30.0)),
           a0 + rng.choice([-1.0, 1.0]) * rng.uniform(40.0, 70.0), r0 + rng.uniform(-15.0, 15.0))
    return Sweep((h0, t0, a0, r0), end, float(rng.uniform(0.5, 0.9)),
                 n_frames * FRAME_PERIOD_S)


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def _wiggle_draw(rng: np.random.Generator, n_frames: int) -> dict[str, Any]:
    nominal = ToFConfig.nominal().params("wiggling")
    r = np.linspace(150.0, 450.0, 61)
    base = wiggle_mm(r, 30e6, nominal["a1_mm"], nominal["p1_rad"], nominal["a2_mm"],
                     nominal["p2_rad"])
    while True:  # a wiggle that differs from the nominal one by >= 1.5 mm RMS
        p = {"a1_mm": rng.uniform(0.0, 10.0), "p1_rad": rng.uniform(-math.pi, math.pi),
             "a2_mm": rng.uniform(0.0, 5.0), "p2_rad": rng.uniform(-math.pi, math.pi)}
        diff = wiggle_mm(r, 30e6, p["a1_mm"], p["p1_rad"], p["a2_mm"], p["p2_rad"]) - base
        if np.sqrt(np.mean(diff ** 2)) >= 1.5:
            return p


def _sign(rng: np.random.Generator) -> float:
    return float(rng.choice([-1.0, 1.0]))


#: effect -> parameter draw(rng, n_frames): realistic values that still matter in the cell
DRAWS: dict[str, Callable[[np.random.Generator, int], dict[str, Any]]] = {
    "multipath": lambda rng, n: {"gain": (rng.uniform(1.7, 3.0) if rng.uniform() < 0.75
                                          else rng.uniform(0.0, 0.3))},
    "mixed_pixels": lambda rng, n: {"psf_sigma_px": rng.uniform(0.8, 1.5)},
    "wiggling": _wiggle_draw,
    "amplitude_bias": lambda rng, n: {"bias_mm": _sign(rng) * rng.uniform(5.0, 10.0),
                                      "exponent": rng.uniform(0.3, 1.2)},
    "lens_scatter": lambda rng, n: {"fraction": rng.uniform(0.03, 0.1),
                                    "sigma_px": rng.uniform(10.0, 50.0)},
    "subsurface": lambda rng, n: {"delay_mm": (rng.uniform(4.0, 15.0),),
                                  "sigma_px": (rng.uniform(0.8, 3.0),),
                                  "fraction": (rng.uniform(0.2, 0.6),)},
    "pixel_offset": lambda rng, n: {"offset_std_mm": rng.uniform(5.0, 10.0),
                                    "gain_std": rng.uniform(0.01, 0.03)},
    "temperature_drift": lambda rng, n: {"max_mm": _sign(rng) * rng.uniform(4.0, 12.0),
                                         "tau_frames": rng.uniform(5.0, max(6.0, 1.5 * n))},
    "time_offset": lambda rng, n: {"offset_ms": _sign(rng) * rng.uniform(15.0, 50.0)},
    "hand_eye": lambda rng, n: dict(zip(
        ("rx_mrad", "ry_mrad", "rz_mrad", "tx_mm", "ty_mm", "tz_mm"),
        (*(_unit(rng) * rng.uniform(4.0, 10.0)), *(_unit(rng) * rng.uniform(2.0, 5.0))),
        strict=True)),
    "noise_model": lambda rng, n: {"scale": rng.uniform(1.6, 3.0),
                                   "exponent": rng.uniform(0.8, 1.4),
                                   "jitter_mm": rng.uniform(0.0, 2.0)},
}


#: modulation frequencies of the cameras the benchmark draws (the cell's 30 MHz among them)
PROFILE_FREQUENCIES_HZ = (20e6, 30e6, 50e6, 80e6, 100e6)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_camera_profile(rng: np.random.Generator) -> dict[str, Any]:
    """A camera that is not the nominal cell: its own noise law (0.3-3× the nominal std), level
    and per-pixel pattern (a new one), wiggle, amplitude bias, amplitude units (0.01-100× the
    simulator's) and modulation frequency. Returns ``{"effects": {name: params},
    "amplitude_scale": k, "mod_freq_hz": f}``."""
    effects = {
        "noise_model": {"scale": _log_uniform(rng, 0.3, 3.0),
                        "exponent": float(rng.uniform(0.85, 1.2)),
                        "jitter_mm": float(rng.uniform(0.0, 1.0))},
        "pixel_offset": {"offset_mean_mm": float(rng.uniform(-8.0, 8.0)),
                         "offset_std_mm": float(rng.uniform(0.5, 3.0)),
                         "gain_std": float(rng.uniform(0.0, 0.008)),
                         "seed": int(rng.integers(0, 2**31 - 1))},
        "wiggling": {"a1_mm": float(rng.uniform(0.0, 8.0)),
                     "p1_rad": float(rng.uniform(-math.pi, math.pi)),
                     "a2_mm": float(rng.uniform(0.0, 3.0)),
                     "p2_rad": float(rng.uniform(-math.pi, math.pi))},
        "amplitude_bias": {"bias_mm": float(rng.uniform(-6.0, 6.0)),
                           "exponent": float(rng.uniform(0.3, 1.2))},
    }
    return {"effects": effects, "amplitude_scale": _log_uniform(rng, 0.01, 100.0),
            "mod_freq_hz": float(rng.choice(PROFILE_FREQUENCIES_HZ))}


def draw_effect(name: str, rng: np.random.Generator, n_frames: int) -> dict[str, Any]:
    """Random parameters of effect ``name`` (floats, or 1-tuples for per-material ones)."""
    params = DRAWS[name](rng, n_frames)
    return {k: (tuple(float(x) for x in v) if isinstance(v, tuple) else float(v))
            for k, v in params.items()}


@dataclass
class Case:
    """One benchmark case.

    Attributes:
        frames: the "real" frames (range, amplitude, SL reference, nominal poses and stamps).
        labels: hidden truth: ``{"effects": [{"name", "params"}], ...}``; never shown to the tool.
        materials: per frame, (H, W) int32 material id (``objects.MATERIAL_NAMES``; −1 = no
            surface) of the true view at each pixel's centre: for diagnosing what a base's
            materials leave unexplained; never shown to the tool either.
    """

    frames: list[ToFFrame]
    labels: dict[str, Any]
    materials: list[np.ndarray] = field(default_factory=list)


def _true_pose(sweep: Sweep, scene: Scene, t_s: float, effects: dict[str, dict]) -> np.ndarray:
    """Where the camera really was when the frame stamped ``t_s`` was exposed (mm)."""
    if "time_offset" in effects:
        t_s = t_s + 1e-3 * effects["time_offset"]["offset_ms"]
    pose = sweep.pose_mm(scene, t_s)
    if "hand_eye" in effects:
        p = effects["hand_eye"]
        rot = rotvec_to_matrix(1e-3 * np.array([p["rx_mrad"], p["ry_mrad"], p["rz_mrad"]]))
        pose = pose @ make_pose(rot, np.array([p["tx_mm"], p["ty_mm"], p["tz_mm"]]))
    return pose


def camera_config(profile: dict[str, Any] | None) -> ToFConfig:
    """The nominal cell, or the camera of a drawn profile (:func:`draw_camera_profile`) in the
    simulator's amplitude units (the units are applied to the recorded amplitude)."""
    cfg = ToFConfig.nominal()
    if profile is None:
        return cfg
    for name, params in profile["effects"].items():
        cfg = cfg.with_effect(name, enabled=True, **params)
    return replace(cfg, mod_freq_hz=float(profile["mod_freq_hz"]))


def real_config(effects: dict[str, dict], profile: dict[str, Any] | None = None) -> ToFConfig:
    """The real camera's config: its profile (default nominal) plus the concealed effects
    (pose errors excepted)."""
    cfg = camera_config(profile)
    for name, params in effects.items():
        if name not in ("time_offset", "hand_eye"):
            cfg = cfg.with_effect(name, enabled=True, **params)
    return cfg


def truth_config(effects: Sequence[dict[str, Any]],
                 profile: dict[str, Any] | None = None) -> ToFConfig:
    """The simulator config an oracle would give the tool: the camera (its profile, in its
    amplitude units) plus every concealed effect at its true parameters, pose errors included
    as the predictor's ``hand_eye`` / ``time_offset`` effects.

    Args:
        effects: a label's ``"effects"`` list, ``[{"name": ..., "params": {...}}, ...]``.
        profile: a label's ``"camera"`` (None: the nominal cell).
    """
    cfg = camera_config(profile)
    if profile is not None:
        cfg = with_amplitude_units(cfg, float(profile["amplitude_scale"]))
    for effect in effects:
        cfg = cfg.with_effect(effect["name"], enabled=True, **effect["params"])
    return cfg


#: bases of a case: the nominal cell, a drawn camera profile, or a drawn profile whose light
#: transport is path-traced (the ``[pathtrace]`` extra: true multi-bounce interreflection,
#: glossy and metal parts, translucent media)
BASES = ("nominal", "profile", "pathtrace")
#: what cannot be concealed on a path-traced base: the transport is the path tracer's, so the
#: simulator's multipath, pixel footprint and subsurface stages are not applied
PATHTRACE_OWN = ("multipath", "mixed_pixels", "subsurface")
#: samples per pixel of a path-traced case. The renderer's Monte Carlo noise is not a
#: camera's: left above the camera's own noise it is a noise law the tool must fit instead of
#: the camera's. Measured on a 96 x 72 test scene, the same view rendered with two seeds:
#: 2.8 mm range RMS at 64 samples (1.2-2.3x the true camera's noise on the static controls of
#: session 21's blind sample), 1.3 mm at 256, 0.7 mm at 1024 (~3 s per frame on a Xeon core)
PATHTRACE_SPP = 1024


def generate_case(rng: np.random.Generator, effects: Sequence[str], *, n_frames: int = 8,
                  intrinsics: Intrinsics = DEFAULT_INTRINSICS, supersample: int = 3,
                  fusion: FusionConfig = BENCH_FUSION, base: str = "nominal",
                  static: bool = False) -> Case:
    """A "real" sweep carrying the concealed ``effects`` (empty = a control).

    Args:
        rng: source of all randomness (scene, sweep, parameters, noise).
        effects: names from ``CONCEALABLE`` (on a ``"pathtrace"`` base, none of
            ``PATHTRACE_OWN``).
        n_frames: frames of the sweep, ``FRAME_PERIOD_S`` apart.
        intrinsics: the ToF image grid.
        supersample: samples per pixel and axis of the "real" render.
        fusion: structured-light fusion of the reference.
        base: one of ``BASES``: the camera the concealed effects sit on.
        static: the camera stays at the sweep's first view (no motion: no pose or timing
            effect can show).
    """
    if base not in BASES:
        raise ValueError(f"base must be one of {BASES}, got {base!r}")
    if base == "pathtrace" and set(effects) & set(PATHTRACE_OWN):
        raise ValueError(f"a path-traced base cannot conceal {PATHTRACE_OWN}")
    drawn = {name: draw_effect(name, rng, n_frames) for name in effects}
    profile = draw_camera_profile(rng) if base != "nominal" else None
    scene = make_scene("test", rng, materials="pathtrace" if base == "pathtrace" else "builtin")
    sweep = draw_sweep(rng, n_frames)
    if static:
        sweep = Sweep(sweep.start, sweep.start, 0.0, sweep.duration_s)
    cfg = real_config(drawn, profile)
    k = 1.0 if profile is None else float(profile["amplitude_scale"])
    frames, materials = [], []
    for i in range(n_frames):
        t_s = i * FRAME_PERIOD_S
        nominal_pose = sweep.pose_mm(scene, t_s)
        true_pose = _true_pose(sweep, scene, t_s, drawn)
        surface = render_surface(scene, true_pose, intrinsics.scaled(supersample))
        materials.append(centre_samples(surface, supersample).material_id.astype(np.int32))
        transport = (_traced(scene, true_pose, intrinsics, cfg, int(rng.integers(0, 1 << 16)))
                     if base == "pathtrace" else None)
        meas = render_tof(surface, cfg, rng, supersample=supersample, frame_index=i,
                          transport=transport)
        ref = reference_range(scene, nominal_pose, intrinsics, rng, fusion=fusion)
        frames.append(ToFFrame(meas.range_mm, meas.amplitude * k, intrinsics,
                               mod_freq_hz=cfg.mod_freq_hz, reference_mm=ref,
                               stamp_ns=round(t_s * 1e9),
                               pose=pose_mm_to_m(nominal_pose)))
    labels = {"effects": [{"name": n, "params": drawn[n]} for n in effects], "base": base,
              "static": bool(static),
              "camera": profile, "n_frames": n_frames, "scene_objects": len(scene.objects),
              "sweep": {"start": sweep.start, "end": sweep.end, "wobble": sweep.wobble}}
    return Case(frames, labels, materials)


def _traced(scene: Scene, pose_mm: np.ndarray, intrinsics: Intrinsics, cfg: ToFConfig,
            seed: int) -> np.ndarray:
    """(H, W) complex128 path-traced phasor of the pixels (every bounce), simulator units."""
    from ..sim.pathtrace.light import SpotLight
    from ..sim.pathtrace.render import DATASET_RR_DEPTH, render_phasor

    return render_phasor(scene, pose_mm, intrinsics, mod_freq_hz=cfg.mod_freq_hz,
                         spp=PATHTRACE_SPP, max_depth=-1, seed=seed,
                         light=SpotLight.of_config(cfg),
                         spp_per_pass=min(PATHTRACE_SPP, 64), rr_depth=DATASET_RR_DEPTH)
