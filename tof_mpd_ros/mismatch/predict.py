"""Predict the expected ToF measurement of a real frame from its reference, fast enough to fit.

The prediction is the simulator's :func:`~tof_mpd_ros.sim.tof.render_from_reference` with the
noise switched off (the expected value): :class:`FramePredictor` walks the simulator's own step
list (:func:`~tof_mpd_ros.sim.tof.pipeline_steps`, less the ``stochastic`` effects) and runs each
step through the simulator's own code (:func:`~tof_mpd_ros.sim.tof.run_step`), so that an effect
registered with the simulator is predicted too. It re-renders a frame thousands of times: the
state before every step is cached for the base configuration, and a candidate configuration
resumes from the first effect in which it differs. Three steps are its own:

* camera moves (:class:`~tof_mpd_ros.sim.tof.CameraMoveEffect`: hand-eye, time offset) move the
  direct surface sub-pixel exactly at the direct-return step (:func:`moved_direct_phasor`, a
  bilinear, phasor-domain version of the simulator's warp: the simulator's nearest-pixel warp is
  piecewise constant in sub-pixel rotations, which a fitter cannot descend), and keep the
  indirect light, which varies slowly with sub-pixel pose changes;
* ``multipath``: the one-bounce indirect phasor (the expensive part) is computed once per frame at
  unit gain and added through the effect's own ``add_indirect``;
* ``lens_scatter``: the effect's own equation with an FFT blur for wide PSFs.

The albedo the reference lacks is inferred from the real amplitude by inverting the direct
return (``a = P ρ cosθ / r²``), so amplitude-dependent physics (noise, amplitude bias,
interreflection strength) is evaluated at the real brightness.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage, signal

from ..errors import MismatchError
from ..frame import ToFFrame
from ..pose import matrix_to_rotvec, rotvec_to_matrix
from ..sim.surface import SurfaceImage
from ..sim.tof import (
    DIRECT,
    EFFECTS,
    Action,
    CameraMotion,
    CameraMoveEffect,
    RenderContext,
    Step,
    ToFConfig,
    direct_phasor,
    frame_context,
    phase_per_mm,
    phasor_noise_std,
    pipeline_steps,
    run_step,
    surface_from_reference,
)

#: albedo bounds of the inferred albedo (a black or mirror-like surface is not Lambertian)
ALBEDO_RANGE = (0.02, 1.0)
#: narrowest scatter PSF (px) blurred by FFT; narrower ones use the simulator's own blur
FFT_MIN_SIGMA_PX = 6.0


@dataclass
class Prediction:
    """Expected measurement of one frame.

    Attributes:
        range_mm: (H, W) float64 expected radial range in mm, NaN = predicted invalid.
        amplitude: (H, W) float64 expected amplitude (simulator units), NaN = invalid.
        noise_mm: (H, W) float64 predicted range noise std in mm (noise model at the expected
            amplitude), NaN = invalid.
    """

    range_mm: np.ndarray
    amplitude: np.ndarray
    noise_mm: np.ndarray


@dataclass
class _State:
    """What the steps have made so far: the surface, the camera moves still to apply at the
    direct return, the phasor, the pixels the moved surface covers, range and amplitude."""

    surface: SurfaceImage
    moves: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    z: np.ndarray | None = None
    hit: np.ndarray | None = None
    range_mm: np.ndarray | None = None
    amplitude: np.ndarray | None = None


def fill_holes(range_mm: np.ndarray, max_iterations: int = 64,
               background_mm: float = 20.0) -> np.ndarray:
    """Fill missing reference pixels from their background neighbours (for light transport).

    Structured-light holes are mostly occlusion shadows beside objects, where the background
    surface continues; a hole pixel takes the mean of its valid 8-neighbours that lie within
    ``background_mm`` of the farthest of them, growing inwards until filled. The predictor
    needs these pixels as senders of interreflected light (a hole sends none); they are never
    scored.

    Args:
        range_mm: (H, W) float radial range in mm, NaN = missing.

    Returns:
        (H, W) float64 range with holes filled (NaN only if the image has no valid pixel).
    """
    out = np.asarray(range_mm, dtype=np.float64).copy()
    h, w = out.shape
    for _ in range(max_iterations):
        hole = ~np.isfinite(out)
        if not hole.any() or hole.all():
            break
        padded = np.pad(out, 1, constant_values=np.nan)
        shifted = np.stack([padded[1 + dv:1 + dv + h, 1 + du:1 + du + w]
                            for dv in (-1, 0, 1) for du in (-1, 0, 1)])
        finite = np.isfinite(shifted)
        far = np.max(np.where(finite, shifted, -np.inf), axis=0)
        use = finite & (shifted >= far - background_mm)
        count = use.sum(axis=0)
        grow = hole & (count > 0)
        total = np.where(use, shifted, 0.0).sum(axis=0)
        out[grow] = total[grow] / count[grow]
    return out


def infer_albedo(frame: ToFFrame, config: ToFConfig, smooth_px: int = 3) -> np.ndarray:
    """Albedo that makes the direct return of the reference geometry match the real amplitude.

    Args:
        frame: real frame with ``reference_mm``.
        config: supplies ``light_power``.
        smooth_px: median filter size (pixels) against noise and mixed edge pixels.

    Returns:
        (H, W) float64 albedo in ``ALBEDO_RANGE``; 0.5 where amplitude or reference is missing.
    """
    rho = median_albedo(frame, config.light_power, smooth_px)
    return np.clip(np.where(np.isfinite(rho), rho, 0.5), *ALBEDO_RANGE)


def median_albedo(frame: ToFFrame, light_power: float, smooth_px: int = 3) -> np.ndarray:
    """(H, W) float64 :func:`raw_albedo` under a ``smooth_px`` x ``smooth_px`` median of its
    finite values (against noise and mixed edge pixels), unclipped; NaN where none."""
    return _nan_median(raw_albedo(frame, light_power), smooth_px)


def raw_albedo(frame: ToFFrame, light_power: float) -> np.ndarray:
    """(H, W) float64 albedo that makes each pixel's direct return off the reference geometry
    equal its real amplitude under ``light_power`` (amplitude·mm²), unclipped and unsmoothed;
    NaN where the reference gives no return."""
    k = frame.intrinsics
    unit = surface_from_reference(fill_holes(frame.reference_mm), k, 1.0)
    a1 = np.abs(direct_phasor(unit.range_mm, unit.normal, unit.albedo, k.ray_directions(),
                              frame.mod_freq_hz, light_power))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(a1 > 0, frame.amplitude / a1, np.nan)


def _nan_median(img: np.ndarray, size: int) -> np.ndarray:
    """Median over the finite values of each ``size`` x ``size`` window (NaN if none)."""
    if size <= 1:
        return img
    big = np.where(np.isfinite(img), img, np.inf)
    small = np.where(np.isfinite(img), img, -np.inf)
    # median of a window with NaNs ~ mean of the medians with NaNs pushed high and low
    hi = ndimage.median_filter(big, size=size, mode="nearest")
    lo = ndimage.median_filter(small, size=size, mode="nearest")
    both = np.isfinite(hi) & np.isfinite(lo)
    out = np.where(both, 0.5 * (np.where(both, hi, 0.0) + np.where(both, lo, 0.0)),
                   np.where(np.isfinite(hi), hi, lo))
    return np.where(np.isfinite(out), out, np.nan)


def _sample(img: np.ndarray, coords: np.ndarray, order: int) -> np.ndarray:
    """``img`` (H, W) at continuous (2, H, W) row/col ``coords`` (NaN outside / on holes)."""
    return ndimage.map_coordinates(img, coords, order=order, mode="constant", cval=np.nan,
                                   prefilter=False)


def moved_direct_phasor(surface: SurfaceImage, rotvec: np.ndarray, translation_mm: np.ndarray,
                        mod_freq_hz: float, light_power: float,
                        iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Direct phasor of ``surface`` seen from a camera moved by a small (R, t), sub-pixel exact.

    Same convention as :func:`tof_mpd_ros.sim.tof.warp.move_camera` (new camera at ``t`` with
    rotation ``R`` in the old frame, ``p' = Rᵀ (p − t)``). Each surface sample's direct return
    is computed from the new camera (range, incidence, falloff), then the *phasor* image is
    resampled onto the new pixel grid by a bilinear backward map. Interpolating phasors rather
    than ranges makes a pixel that a depth edge crosses after the move a mix of fore- and
    background returns in proportion to its coverage, which is what a real pixel integrates.

    Args:
        surface: pixel-resolution surface image.
        rotvec: (3,) rotation vector in rad; translation_mm: (3,) in mm.

    Returns:
        (H, W) complex128 direct phasor and (H, W) bool "mostly covered by a surface".
    """
    rot = rotvec_to_matrix(np.asarray(rotvec, dtype=np.float64))
    t = np.asarray(translation_mm, dtype=np.float64)
    k = surface.intrinsics
    h, w = k.shape
    moved = (surface.points_mm() - t) @ rot
    rng = np.linalg.norm(moved, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rays = moved / rng[..., None]
    z_src = direct_phasor(rng, surface.normal @ rot, surface.albedo, rays, mod_freq_hz,
                          light_power)
    z_src = np.where(np.isfinite(z_src), z_src, 0.0)
    uv = k.project(moved)
    u_img = np.nan_to_num(uv[..., 0], nan=-1e6)
    v_img = np.nan_to_num(uv[..., 1], nan=-1e6)
    v0, u0 = np.mgrid[0:h, 0:w].astype(np.float64)
    sv, su = v0.copy(), u0.copy()
    for _ in range(iterations):
        coords = np.stack([sv, su])
        lu = _sample(u_img, coords, 1)
        lv = _sample(v_img, coords, 1)
        # near holes the interpolated landing point is meaningless: keep the current guess
        ok = np.isfinite(lu) & (np.abs(lu - u0) < 5.0) & (np.abs(lv - v0) < 5.0)
        su += np.where(ok, u0 - lu, 0.0)
        sv += np.where(ok, v0 - lv, 0.0)
    coords = np.stack([sv, su])
    z = np.nan_to_num(_sample(z_src.real, coords, 1)) + 1j * np.nan_to_num(
        _sample(z_src.imag, coords, 1))
    cover = np.nan_to_num(_sample(surface.valid.astype(np.float64), coords, 1))
    return z, cover >= 0.5


def _gaussian_constant(img: np.ndarray, sigma: float) -> np.ndarray:
    """``ndimage.gaussian_filter(img, sigma, mode="constant", truncate=3)`` by FFT along each
    axis (same kernel, zero padding): wide PSFs cost O(N log N) instead of O(N σ)."""
    radius = int(3.0 * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    kernel /= kernel.sum()
    out = signal.fftconvolve(img, kernel[:, None], mode="same", axes=0)
    return signal.fftconvolve(out, kernel[None, :], mode="same", axes=1)


def fft_glare(z: np.ndarray, sigma: float) -> np.ndarray:
    """The simulator's scatter glare ``G_σ ∗ Z`` of an (H, W) complex128 image (zero padding,
    truncated at 3σ) by FFT: the same kernel, equal up to float rounding."""
    return _gaussian_constant(z.real, sigma) + 1j * _gaussian_constant(z.imag, sigma)


def _compose(moves: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """One (rotvec, translation) equal to applying ``moves`` in order (each in the frame the
    previous one produced): R = R1 R2, t = t1 + R1 t2."""
    rot, t = np.eye(3), np.zeros(3)
    for rv, tr in moves:
        t = t + rot @ np.asarray(tr, dtype=np.float64)
        rot = rot @ rotvec_to_matrix(rv)
    return matrix_to_rotvec(rot), t


def noise_std_mm(amplitude: np.ndarray, config: ToFConfig) -> np.ndarray:
    """Range noise std (mm) the config's noise law predicts at expected amplitude ``amplitude``.

    Args:
        amplitude: (H, W) float expected amplitude (simulator units).
        config: noise parameters (``noise``, and ``noise_model`` when enabled).

    Returns:
        (H, W) float64 std in mm (valid for a ≫ σ; capped at a quarter of the ambiguity range).
    """
    p = config.effect_params("noise")
    a = np.maximum(np.asarray(amplitude, dtype=np.float64), 1e-6)
    jitter = 0.0
    if config.enabled("noise_model"):
        q = config.effect_params("noise_model")
        sigma = phasor_noise_std(a, p.read_std, p.shot_gain, p.ambient, scale=q.scale,
                                 exponent=q.exponent)
        jitter = float(q.jitter_mm)
    elif config.enabled("noise"):
        sigma = phasor_noise_std(a, p.read_std, p.shot_gain, p.ambient)
    else:
        sigma = np.zeros_like(a)
    k = phase_per_mm(config.mod_freq_hz)
    std = np.hypot(sigma / (a * k), jitter)
    return np.minimum(std, 0.25 * math.pi / k)


class FramePredictor:
    """Cached, staged expected-value render of one frame (see the module docstring).

    Args:
        frame: the real frame (``reference_mm`` required: it is the scene).
        base: the configuration whose intermediate states are cached.
        frame_index: index of the frame in its recording (temperature drift).
        motion: camera velocity during the frame (time offset), or None.
        albedo: (H, W) float albedo in [0, 1], or None to infer it from the real amplitude.
        indirect_cache: shared cache of indirect phasors (see :meth:`rebased`).
        surface: the surface of the frame's reference with ``albedo`` (see :meth:`rebased`), or
            None to build it (its normals are a plane fit per pixel, the costly part).

    Attributes:
        steps: the simulator's pipeline steps the prediction walks, in order: every step but
            the ``stochastic`` effects' (noise acts on the spread, not on the expected value).
    """

    def __init__(self, frame: ToFFrame, base: ToFConfig, *, frame_index: int = 0,
                 motion: CameraMotion | None = None, albedo: np.ndarray | None = None,
                 indirect_cache: dict[tuple, np.ndarray] | None = None,
                 surface: SurfaceImage | None = None) -> None:
        if frame.reference_mm is None:
            raise MismatchError("the predictor needs the frame's reference range image")
        self.frame = frame
        self.frame_index = int(frame_index)
        self.motion = motion
        self.albedo = infer_albedo(frame, base) if albedo is None else albedo
        # holes are filled for light transport and mixing, and masked again at the end
        self.reference_valid = np.isfinite(frame.reference_mm)
        self.surface = surface_from_reference(fill_holes(frame.reference_mm), frame.intrinsics,
                                              self.albedo) if surface is None else surface
        self._indirect = {} if indirect_cache is None else indirect_cache
        self.base = base
        self.steps: tuple[Step, ...] = tuple(
            s for s in pipeline_steps() if s.effect is None or not s.effect.stochastic)
        #: the steps computed the predictor's own way when their effect is on
        self._own_steps: dict[str, Callable[[Step, ToFConfig, np.ndarray, RenderContext],
                                            np.ndarray]] = {
            "multipath": self._multipath, "lens_scatter": self._lens_scatter}
        self._checkpoints: dict[int, _State] = {}
        self._last: tuple[ToFConfig, Prediction] | None = None
        self._base_result = self._run(base, 0, _State(self.surface), record=True)

    # -- public -------------------------------------------------------------------------------

    def predict(self, config: ToFConfig | None = None) -> Prediction:
        """Expected measurement under ``config`` (None = the base configuration)."""
        if config is None or config == self.base:
            return self._base_result
        if self._last is not None and self._last[0] is config:
            return self._last[1]   # a fit asks twice: for its level, then for its cost
        start = self._first_difference(config)
        if start is None:
            rng_mm, amp = self._base_result.range_mm, self._base_result.amplitude
            return Prediction(rng_mm, amp, self._noise(amp, config))
        result = self._run(config, start, replace(self._checkpoints[start]), record=False)
        self._last = (config, result)
        return result

    def rebased(self, base: ToFConfig) -> FramePredictor:
        """The same frame predicted around another base configuration (albedo, the surface and
        its normals, and the indirect phasor are reused: they depend on the frame only)."""
        return FramePredictor(self.frame, base, frame_index=self.frame_index, motion=self.motion,
                              albedo=self.albedo, indirect_cache=self._indirect,
                              surface=self.surface)

    def indirect(self, config: ToFConfig) -> np.ndarray:
        """(H, W) complex128 unit-gain indirect phasor of the reference surface (its world:
        the reference plus the support plane extended across the light's cone)."""
        multipath = EFFECTS["multipath"]
        p = config.effect_params(multipath.name)
        key = (replace(p, gain=1.0), config.mod_freq_hz, config.light_power)
        if key not in self._indirect:
            self._indirect[key] = multipath.unit_indirect(
                self.surface, multipath.surface_world(self.surface, p), p, config.mod_freq_hz,
                config.light_power)
        return self._indirect[key]

    # -- internals ----------------------------------------------------------------------------

    def _first_difference(self, config: ToFConfig) -> int | None:
        """Index in :attr:`steps` of the first effect whose switch or parameters differ from
        the base configuration's."""
        if (config.mod_freq_hz, config.light_power) != (self.base.mod_freq_hz,
                                                         self.base.light_power):
            return 0
        for i, step in enumerate(self.steps):
            if step.effect is not None and config.effects[step.name] != self.base.effects[
                    step.name]:
                return i
        return None

    def _context(self, config: ToFConfig, surface: SurfaceImage) -> RenderContext:
        ctx = frame_context(config, self.frame.intrinsics, surface,
                            rng=np.random.default_rng(0), frame_index=self.frame_index,
                            motion=self.motion)
        ctx.true_range_mm = surface.range_mm
        return ctx

    def _run(self, config: ToFConfig, start: int, state: _State, *, record: bool) -> Prediction:
        ctx = self._context(config, state.surface)
        ctx.amplitude = state.amplitude
        for i in range(start, len(self.steps)):
            if record:
                self._checkpoints[i] = replace(state)
            self._step(self.steps[i], config, state, ctx)
        hit = state.surface.valid if state.hit is None else state.hit
        valid = (hit & np.isfinite(state.range_mm) & self.reference_valid
                 & (state.amplitude >= config.min_amplitude))
        rng_mm = np.where(valid, state.range_mm, np.nan)
        amp = np.where(valid, state.amplitude, np.nan)
        return Prediction(rng_mm, amp, self._noise(amp, config))

    def _step(self, step: Step, config: ToFConfig, state: _State, ctx: RenderContext) -> None:
        """Apply one pipeline step to ``state``: the simulator's own step, except the direct
        return, camera moves and the steps in ``_own_steps`` (see the module docstring)."""
        if step.stage == DIRECT:
            self._direct(config, state)
        elif step.stage == "geometry":
            if isinstance(step.effect, CameraMoveEffect) and \
                    step.action(config) is Action.APPLY:
                move = step.effect.camera_move(step.params(config), ctx)
                if move is not None:  # applied at the direct return
                    state.moves = (*state.moves, move)
            else:
                state.surface = run_step(step, state.surface, config, ctx)
                ctx.surface = ctx.samples = state.surface
                ctx.true_range_mm = state.surface.range_mm
        elif step.stage in ("footprint", "phasor"):
            own = self._own_steps.get(step.name)
            state.z = (own(step, config, state.z, ctx)
                       if own is not None and step.action(config) is Action.APPLY
                       else run_step(step, state.z, config, ctx))
        elif step.stage == "readout":
            state.amplitude = np.abs(state.z)
            ctx.amplitude = state.amplitude
            state.range_mm = run_step(step, state.z, config, ctx)
        else:  # range
            state.range_mm = run_step(step, state.range_mm, config, ctx)

    @staticmethod
    def _direct(config: ToFConfig, state: _State) -> None:
        """The direct return of the surface, seen from the moved camera if it moved."""
        s = state.surface
        if state.moves:
            state.z, state.hit = moved_direct_phasor(s, *_compose(list(state.moves)),
                                                     config.mod_freq_hz, config.light_power)
        else:
            state.z = direct_phasor(s.range_mm, s.normal, s.albedo, s.intrinsics.ray_directions(),
                                    config.mod_freq_hz, config.light_power)

    def _multipath(self, step: Step, config: ToFConfig, z: np.ndarray,
                   ctx: RenderContext) -> np.ndarray:
        """``multipath`` from the cached unit-gain indirect phasor of the reference surface."""
        return step.effect.add_indirect(z, self.indirect(config), step.params(config), ctx)

    @staticmethod
    def _lens_scatter(step: Step, config: ToFConfig, z: np.ndarray,
                      ctx: RenderContext) -> np.ndarray:
        """``lens_scatter`` with :func:`fft_glare` for PSFs of at least ``FFT_MIN_SIGMA_PX``."""
        params = step.params(config)
        if float(params.sigma_px) < FFT_MIN_SIGMA_PX:
            return step.effect.apply(z, params, ctx)
        return step.effect.scatter(z, params, fft_glare)

    @staticmethod
    def _noise(amplitude: np.ndarray, config: ToFConfig) -> np.ndarray:
        return np.where(np.isfinite(amplitude), noise_std_mm(amplitude, config), np.nan)
