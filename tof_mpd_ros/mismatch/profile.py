"""The camera's profile: what every ToF camera has its own values of, found before naming physics.

A real camera differs from the nominal cell in everything at once. Some of it is the camera
itself and says nothing about missing physics: its modulation frequency (the recording states
it), the units of its amplitude, its noise law, its per-pixel offset and gain, its wiggling and
its amplitude-dependent bias. :func:`adopt_recording` takes what the recording states and the
amplitude units; the analysis then fits :data:`PROFILE_EFFECTS` first (:mod:`.analysis`) and
only then ranks the scene, pose and timing effects (:data:`SCENE_EFFECTS`) on top.

Amplitude units. The simulator's direct return is ``a = P ρ cosθ / r²``; a camera reports ``k·a``
in its own units. From one camera's range and amplitude, ``k`` and the scene's albedo ρ are
degenerate (only ``k ρ`` is seen), and the noise law in the camera's units scales with ``k``
too. :func:`with_amplitude_units` applies ``k`` to every amplitude-unit quantity of a config
(light power, the noise law's read/shot/ambient terms, the amplitude-bias reference, the
validity threshold), which leaves every predicted *range* and its noise unchanged and changes
only the albedo inferred from the amplitude — hence the interreflection's strength relative to
the direct return. ``k`` is chosen so that the scene's median inferred albedo is
:data:`GREY_WORLD_ALBEDO` (a stated assumption: a grey world), and reported; a camera whose
units the given config already matches keeps them (calibrate-then-monitor).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ..frame import ToFFrame
from ..sim.tof import ToFConfig
from .predict import raw_albedo
from .wording import phrase

#: effects every camera has its own values of (fitted first, reported as the camera's profile)
PROFILE_EFFECTS: tuple[str, ...] = ("noise_model", "pixel_offset", "wiggling", "amplitude_bias")
#: scene, pose and timing physics, ranked on top of the camera's profile
SCENE_EFFECTS: tuple[str, ...] = ("multipath", "mixed_pixels", "lens_scatter", "subsurface",
                                  "phase_wrapping", "temperature_drift", "time_offset",
                                  "hand_eye")
#: the assumed median albedo of a scene when the amplitude units are unknown
GREY_WORLD_ALBEDO = 0.5
#: how far a scene's median albedo may sit from the grey world's (0.3-0.8)
ALBEDO_DOUBT = (0.6, 1.6)
#: the effect whose strength the scene's albedo sets: with the units assumed, the profile fits
#: its gain within what ``ALBEDO_DOUBT`` allows (the analysis), i.e. the scene's albedo
ALBEDO_EFFECT = "multipath"
#: the interreflection of the reference's world scales as albedo ** ALBEDO_EXPONENT under a
#: uniform albedo scale: one bounce (∝ albedo) dominates, two (∝ albedo²) add a little
#: (measured on tabletop scenes: 0.6× the albedo gives 0.57-0.59× the indirect phasor, an
#: exponent of 1.02-1.09; ``test_interreflection_scales_with_the_albedo``)
ALBEDO_EXPONENT = 1.1
#: the widest optical blur of a lens focused on the scene (σ, px; FWHM 1.4 px, i.e. the lens
#: still resolves about its pixel pitch); the simulator's nominal cell has 0.3
LENS_PSF_MAX_PX = 0.6
#: effects the simulator names as physics that every camera also has its own value of, within
#: a window (effect -> (parameter, low, high)): the interreflection's strength, set by the
#: scene's albedo when the amplitude units were assumed, and the lens's point spread. The
#: one-shot profile fits them inside the window; they are named as physics only beyond it.
CAMERA_WINDOWS: dict[str, tuple[str, float, float]] = {
    ALBEDO_EFFECT: ("gain", ALBEDO_DOUBT[0] ** ALBEDO_EXPONENT,
                    ALBEDO_DOUBT[1] ** ALBEDO_EXPONENT),
    "mixed_pixels": ("psf_sigma_px", 0.0, LENS_PSF_MAX_PX),
}
#: why a value inside the window is the camera's, as the facts the template words
#: (``templates/mismatch.txt``, ``camera_window_why``): the albedo's doubt and the exponent of
#: the interreflection's scaling, the widest blur of a focused lens
CAMERA_WINDOW_REASONS: dict[str, dict[str, Any]] = {
    ALBEDO_EFFECT: {"reason": "albedo", "doubt": ALBEDO_DOUBT, "exponent": ALBEDO_EXPONENT},
    "mixed_pixels": {"reason": "lens", "max_px": LENS_PSF_MAX_PX},
}
#: inferred albedo is implausible for a config's amplitude units when its median leaves this
#: range or more than ``BRIGHT_SHARE`` of the pixels come out brighter than a white diffuser
PLAUSIBLE_MEDIAN_ALBEDO = (0.15, 0.95)
BRIGHT_SHARE = 0.05
BRIGHT_ALBEDO = 1.05
#: distance of the cell's table (mm): the nominal light power and interreflection patches are
#: sized for it
CELL_DISTANCE_MM = 300.0
#: a recording whose median reference range exceeds this many cell distances gets its
#: interreflection patches scaled with it (:func:`with_scene_distance`)
PATCH_SCALING_FROM = 2.0


def with_amplitude_units(config: ToFConfig, scale: float) -> ToFConfig:
    """``config`` for a camera whose amplitude is ``scale`` × the simulator's.

    Every amplitude-unit quantity scales with it (light power, read and ambient noise, the shot
    term's gain, the amplitude-bias reference, the validity threshold), so predicted ranges and
    their noise are unchanged; only albedo inferred from a measured amplitude changes.
    """
    k = float(scale)
    noise = config.params("noise")
    bias = config.params("amplitude_bias")
    out = replace(config, light_power=config.light_power * k,
                  min_amplitude=config.min_amplitude * k)
    out = out.with_effect("noise", read_std=noise["read_std"] * k,
                          shot_gain=noise["shot_gain"] * k, ambient=noise["ambient"] * k)
    return out.with_effect("amplitude_bias", ref_amplitude=bias["ref_amplitude"] * k)


def with_scene_distance(config: ToFConfig, distance_mm: float) -> ToFConfig:
    """``config`` with the interreflection's patches (``multipath`` ``leaf_mm``,
    ``bounce_patch_mm``) the nominal cell's × ``distance_mm`` / :data:`CELL_DISTANCE_MM`: a
    leaf stays about one pixel's footprint, as in the cell (at 4 mm the support plane of a
    room, extended across the light's cone, holds millions of leaves). Ranges are unchanged;
    the indirect light is sampled as coarsely, relative to the scene, as in the cell.
    Idempotent: a config already scaled to the distance is returned as it is."""
    scale = float(distance_mm) / CELL_DISTANCE_MM
    nominal = ToFConfig.nominal().params("multipath")
    return config.with_effect("multipath", **{k: float(nominal[k]) * scale
                                             for k in ("leaf_mm", "bounce_patch_mm")})


def scene_albedo(frames: Sequence[ToFFrame], config: ToFConfig) -> np.ndarray:
    """(N,) float64 unclipped albedo of every pixel with amplitude and reference, inferred by
    inverting the direct return under ``config``'s light power (no smoothing)."""
    out = []
    for f in frames:
        rho = raw_albedo(f, config.light_power)
        ok = np.isfinite(rho) & (rho > 0) & np.isfinite(f.reference_mm)
        out.append(rho[ok])
    return np.concatenate(out) if out else np.zeros(0)


def units_plausible(albedo: np.ndarray) -> bool:
    """Whether albedo inferred under some amplitude units looks like a real scene's."""
    if albedo.size == 0:
        return True
    lo, hi = PLAUSIBLE_MEDIAN_ALBEDO
    return bool(lo <= np.median(albedo) <= hi
                and np.mean(albedo > BRIGHT_ALBEDO) <= BRIGHT_SHARE)


def adopt_recording(frames: Sequence[ToFFrame], config: ToFConfig, *,
                    keep_units: bool) -> tuple[ToFConfig, dict[str, Any]]:
    """The config the analysis starts from: the recording's modulation frequency and the
    camera's amplitude units.

    Args:
        frames: the real frames (one camera).
        config: the config given (or the nominal cell).
        keep_units: keep ``config``'s amplitude units while the albedo they imply is plausible
            (calibrate-then-monitor); otherwise (one-shot) choose them by the grey world.

    Returns:
        ``(config, facts)``; facts: ``mod_freq_hz``, ``mod_freq_from_recording`` (bool),
        ``amplitude_scale`` (k applied to ``config``), ``median_albedo_before`` / ``_after``,
        ``scene_distance_mm`` and, when the patches were scaled to it (one-shot, a scene
        beyond ``PATCH_SCALING_FROM`` cell distances), ``patch_scale``.
    """
    facts: dict[str, Any] = {}
    freq = float(frames[0].mod_freq_hz)
    facts["mod_freq_from_recording"] = freq != float(config.mod_freq_hz)
    if facts["mod_freq_from_recording"]:
        config = replace(config, mod_freq_hz=freq)
    facts["mod_freq_hz"] = freq
    refs = [f.reference_mm[np.isfinite(f.reference_mm)] for f in frames]
    distance = float(np.median(np.concatenate(refs))) if sum(r.size for r in refs) else 0.0
    facts["scene_distance_mm"] = distance
    if not keep_units and distance > PATCH_SCALING_FROM * CELL_DISTANCE_MM:
        config = with_scene_distance(config, distance)
        facts["patch_scale"] = distance / CELL_DISTANCE_MM
    albedo = scene_albedo(frames, config)
    median = float(np.median(albedo)) if albedo.size else float("nan")
    facts["median_albedo_before"] = median
    scale = 1.0
    if albedo.size and median > 0 and not (keep_units and units_plausible(albedo)):
        scale = median / GREY_WORLD_ALBEDO
    facts["amplitude_scale"] = scale
    facts["median_albedo_after"] = median / scale if albedo.size else float("nan")
    return (with_amplitude_units(config, scale) if scale != 1.0 else config), facts


def albedo_from_interreflection(facts: dict[str, Any], gain: float) -> dict[str, float]:
    """What a multipath ``gain`` fitted within the albedo's doubt says: the scene's albedo is
    ``gain ** (1 / ALBEDO_EXPONENT)`` × the grey world's, so the amplitude units are the grey
    world's divided by that (facts ``albedo_scale``, ``amplitude_scale_from_interreflection``)."""
    scale = float(gain) ** (1.0 / ALBEDO_EXPONENT)
    return {"albedo_scale": scale,
            "amplitude_scale_from_interreflection": float(facts.get("amplitude_scale", 1.0))
            / scale}


def describe_profile(nominal: ToFConfig, fitted: ToFConfig, facts: dict[str, Any],
                     effects: Sequence[str]) -> list[str]:
    """The camera's profile in words, relative to the nominal cell ("noise 3.6× lower than
    nominal", "offset -4.1 mm (nominal +4.0), ..."): one phrase per item of
    :func:`profile_items` (``templates/mismatch.txt``, ``profile_item``); an effect the
    template has no words for gives none."""
    phrases = (phrase("profile_item", item)
               for item in profile_items(nominal, fitted, facts, effects))
    return [p for p in phrases if p]


def profile_items(nominal: ToFConfig, fitted: ToFConfig, facts: dict[str, Any],
                  effects: Sequence[str]) -> list[dict[str, Any]]:
    """What the camera's profile says, as data (``facts`` from :func:`adopt_recording` and
    :func:`albedo_from_interreflection`), one dict per item, ``kind`` first:

    * ``"frequency"``: ``mod_freq_hz``, ``from_recording``;
    * ``"units"`` (only when the amplitude units are not the simulator's): ``scale``,
      ``grey_world`` (the assumed median albedo);
    * ``"pattern"`` (only when one was found, fact ``pattern_rms_mm``): ``rms_mm``, the
      camera's fixed pattern of per-pixel offsets (:func:`.fit.fixed_pattern`);
    * ``"specular"`` (only when some were found, fact ``specular_share``): ``share`` of the
      measured pixels left out as view-dependent surfaces (:mod:`.specular`);
    * ``"albedo"`` (for :data:`ALBEDO_EFFECT` when its gain was read as the scene's albedo):
      ``gain``, ``albedo_scale``, ``units_scale``, ``grey_world``;
    * every other effect of ``effects`` by name: its ``fitted`` and ``nominal`` parameters
      (the numeric ones, as floats).
    """
    items: list[dict[str, Any]] = [{"kind": "frequency", "mod_freq_hz": facts["mod_freq_hz"],
                                    "from_recording": bool(facts.get("mod_freq_from_recording"))}]
    k = facts.get("amplitude_scale", 1.0)
    if k != 1.0:
        items.append({"kind": "units", "scale": k, "grey_world": GREY_WORLD_ALBEDO})
    if facts.get("pattern_rms_mm", 0.0) > 0.0:
        items.append({"kind": "pattern", "rms_mm": facts["pattern_rms_mm"]})
    if facts.get("specular_share", 0.0) > 0.0:
        items.append({"kind": "specular", "share": facts["specular_share"]})
    for name in effects:
        p = _numbers(fitted.params(name))
        if name == ALBEDO_EFFECT and "albedo_scale" in facts:
            items.append({"kind": "albedo", "gain": p["gain"],
                          "albedo_scale": facts["albedo_scale"],
                          "units_scale": facts["amplitude_scale_from_interreflection"],
                          "grey_world": GREY_WORLD_ALBEDO})
        else:
            items.append({"kind": name, "fitted": p, "nominal": _numbers(nominal.params(name))})
    return items


def _numbers(params: dict[str, Any]) -> dict[str, float]:
    """The numeric parameters of an effect as floats (tuples, strings and flags left out)."""
    return {k: float(v) for k, v in params.items()
            if isinstance(v, (int, float, np.number)) and not isinstance(v, bool)}


__all__ = ["ALBEDO_DOUBT", "ALBEDO_EFFECT", "ALBEDO_EXPONENT", "CAMERA_WINDOWS",
           "CAMERA_WINDOW_REASONS", "GREY_WORLD_ALBEDO", "LENS_PSF_MAX_PX", "PROFILE_EFFECTS",
           "SCENE_EFFECTS", "adopt_recording", "albedo_from_interreflection",
           "describe_profile", "profile_items", "scene_albedo", "units_plausible",
           "with_amplitude_units", "with_scene_distance"]
