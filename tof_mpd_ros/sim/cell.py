"""The simulated cell: a ToF camera with its structured-light reference, as one capture call.

:class:`SimCell` ties the pieces together — ray caster (:mod:`.raycast`), AMCW physics
(:mod:`.tof`), structured-light fusion (:mod:`.structured_light`) and the graded checkerboard
(:mod:`.checkerboard`) — into :class:`~tof_mpd_ros.frame.ToFFrame` captures. It is what the
dataset generator, the ``sim_cell`` node and the simulated collector all call.

Rendering window: the camera renders the recorded crop plus a margin on every side, so surfaces
just outside the crop still send interreflected light into it, and then keeps the crop. Every
capture of one camera uses the same window, so the fixed-pattern pixel errors are the same at
the same sensor pixel in calibration captures and scene captures.

Renderers (``SimCell.renderer``): ``"builtin"`` (default) ray-casts the window and runs the
camera's whole pipeline (:func:`.tof.render_tof`: footprint, world-space multipath, noise,
readout, systematic errors). ``"pathtrace"`` (optional extra ``[pathtrace]``) renders the light
transport of the window at pixel resolution with Mitsuba 3 + mitransient
(:func:`.pathtrace.render.render_phasor`: every bounce, each object's material — glossy, metal,
translucent — and each pixel's area, so mixed pixels are in it) and hands that phasor to
``render_tof(..., transport=...)``, so noise, readout and systematic errors come from the same
camera modules. The footprint stage (with its optical blur ``psf_sigma_px``), ``multipath``
and ``subsurface`` are then not applied: the path tracer's light transport replaces them. The
structured-light reference is the same ray-cast one for both. Calibration captures stay
built-in for both: the checkerboard is a single plane, which exchanges no light with itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import PAPER_CROP, Intrinsics
from ..errors import SimulationError
from ..frame import ToFFrame
from ..pose import pose_mm_to_m
from .checkerboard import CheckerboardConfig, render_checkerboard
from .pathtrace.light import SpotLight
from .raycast import render_surface
from .scene import Scene
from .structured_light import FusionConfig, StructuredLightConfig, reference_range
from .surface import SurfaceImage
from .tof import ToFConfig, render_tof
from .tof.render import ToFMeasurement, centre_samples
from .tof.world import world_from_scene

RENDERERS = ("builtin", "pathtrace")


@dataclass
class CameraModel:
    """The simulated ToF camera's image geometry.

    Attributes:
        sensor: intrinsics of the full sensor (DS325-like 320x240, ~74 deg HFOV).
        crop: (width, height) of the recorded central window (the paper's 180x140).
        margin_px: extra pixels rendered around the crop for interreflection, then dropped.
        supersample: ray samples per pixel and axis (mixed pixels); odd keeps a centre ray.
    """

    sensor: Intrinsics = field(default_factory=Intrinsics.ds325)
    crop: tuple[int, int] = PAPER_CROP
    margin_px: int = 12
    supersample: int = 3

    def __post_init__(self) -> None:
        w, h = self.crop
        if not (0 < w <= self.sensor.width and 0 < h <= self.sensor.height):
            raise SimulationError(f"crop {w}x{h} does not fit the "
                                  f"{self.sensor.width}x{self.sensor.height} sensor")
        if self.margin_px < 0:
            raise SimulationError(f"margin_px must be >= 0, got {self.margin_px}")
        if self.supersample < 1:
            raise SimulationError(f"supersample must be >= 1, got {self.supersample}")

    @property
    def window(self) -> Intrinsics:
        """Intrinsics of the rendered window (crop + margin). The margin may reach past the
        sensor (a full-sensor crop): surfaces just outside the field of view still send
        interreflected light into it, whether or not a pixel sees them."""
        return self.intrinsics.expanded(self.margin_px)

    @property
    def intrinsics(self) -> Intrinsics:
        """Intrinsics of the recorded crop."""
        return self.sensor.crop(*self.crop)

    @property
    def crop_mask(self) -> np.ndarray:
        """(h + 2m, w + 2m) bool window image, True on the recorded crop."""
        w, h = self.crop
        m = self.margin_px
        mask = np.zeros((h + 2 * m, w + 2 * m), dtype=bool)
        mask[m:m + h, m:m + w] = True
        return mask

    def keep_crop(self, image: np.ndarray) -> np.ndarray:
        """(h + 2m, w + 2m, ...) window image -> (h, w, ...) crop."""
        m = self.margin_px
        return image[m:image.shape[0] - m, m:image.shape[1] - m] if m else image


@dataclass
class SimCell:
    """A simulated ToF camera (plus structured-light reference) in front of a scene.

    Attributes:
        camera: image geometry.
        tof: AMCW physics configuration (nominal by default).
        structured_light: the SL sensor; ``fusion`` its multi-scan fusion settings.
        renderer: ``"builtin"`` or ``"pathtrace"`` (see the module docstring).
        pathtrace_spp: path tracer samples per pixel (a multiple of 16 up to 64, else of 64).
        pathtrace_max_depth: path tracer depth (−1: every bounce; Russian roulette from
            :data:`.pathtrace.render.DATASET_RR_DEPTH` on).
    """

    camera: CameraModel = field(default_factory=CameraModel)
    tof: ToFConfig = field(default_factory=ToFConfig.nominal)
    structured_light: StructuredLightConfig = field(default_factory=StructuredLightConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    renderer: str = "builtin"
    pathtrace_spp: int = 64
    pathtrace_max_depth: int = -1

    def __post_init__(self) -> None:
        if self.renderer not in RENDERERS:
            raise SimulationError(f"renderer must be one of {RENDERERS}, got {self.renderer!r}")
        if self.renderer == "pathtrace":
            _pass_size(self.pathtrace_spp)
            if self.tof.effects["hand_eye"].enabled:
                raise SimulationError("the path tracer renders from the given pose: switch "
                                      "hand_eye off with renderer='pathtrace'")

    @property
    def materials(self) -> str:
        """The object library's material set scenes for this cell are drawn from."""
        return "pathtrace" if self.renderer == "pathtrace" else "builtin"

    def capture(self, scene: Scene, camera_to_base_mm: np.ndarray, rng: np.random.Generator,
                *, frame_index: int = 0, stamp_ns: int = 0, with_reference: bool = True,
                pathtrace_seed: int = 0) -> ToFFrame:
        """One ToF frame of ``scene`` from a camera pose, with the fused SL reference.

        Args:
            scene: the scene (base frame, mm).
            camera_to_base_mm: (4, 4) ToF optical frame -> base frame, translation in mm.
            rng: source of sensor noise (ToF and SL).
            frame_index: position in the sequence (temperature drift).
            stamp_ns: capture time, integer nanoseconds.
            with_reference: also run the SL scans and fusion (the slow part).
            pathtrace_seed: the path tracer's seed in [0, 65536) (``renderer="pathtrace"``
                only; the render is a deterministic function of it).

        Returns:
            ToFFrame of the crop: radial range and amplitude, reference (NaN = missing), pose in
            metres, the true albedo.
        """
        cam = self.camera
        surface = render_surface(scene, camera_to_base_mm, cam.window.scaled(cam.supersample))
        if self.renderer == "pathtrace":
            measurement = self._render_pathtrace(scene, camera_to_base_mm, surface, rng,
                                                 frame_index, pathtrace_seed)
        else:
            measurement = self._render_builtin(scene, camera_to_base_mm, surface, rng,
                                               frame_index)
        reference = None
        if with_reference:
            reference = reference_range(scene, camera_to_base_mm, cam.intrinsics, rng,
                                        self.structured_light, self.fusion)
        albedo = centre_samples(surface, cam.supersample).albedo
        return ToFFrame(range_mm=cam.keep_crop(measurement.range_mm),
                        amplitude=cam.keep_crop(measurement.amplitude),
                        intrinsics=cam.intrinsics, mod_freq_hz=self.tof.mod_freq_hz,
                        reference_mm=reference, stamp_ns=stamp_ns,
                        pose=pose_mm_to_m(camera_to_base_mm),
                        albedo=cam.keep_crop(albedo))

    def _render_builtin(self, scene: Scene, camera_to_base_mm: np.ndarray,
                        surface: SurfaceImage, rng: np.random.Generator,
                        frame_index: int) -> ToFMeasurement:
        """The window's measurement by the built-in pipeline (world-space multipath)."""
        cam = self.camera
        world = None
        if self.tof.effects["multipath"].enabled:
            p = self.tof.params("multipath")
            world = world_from_scene(scene, camera_to_base_mm, leaf_mm=float(p["leaf_mm"]),
                                     cutoff_deg=float(p["cutoff_deg"]),
                                     beam_deg=float(p["beam_deg"]))
        # the margin's pixels need no indirect light of their own
        return render_tof(surface, self.tof, rng, supersample=cam.supersample,
                          frame_index=frame_index, receivers=cam.crop_mask, world=world)

    def _render_pathtrace(self, scene: Scene, camera_to_base_mm: np.ndarray,
                          surface: SurfaceImage, rng: np.random.Generator, frame_index: int,
                          seed: int) -> ToFMeasurement:
        """The window's measurement: path-traced transport, the camera's own sensor modules."""
        from .pathtrace.render import DATASET_RR_DEPTH, render_phasor

        cam = self.camera
        light = SpotLight.of_config(self.tof)
        # (H, W) complex128 phasor of the window, every path, simulator amplitude units
        transport = render_phasor(scene, camera_to_base_mm, cam.window,
                                  mod_freq_hz=self.tof.mod_freq_hz, spp=self.pathtrace_spp,
                                  max_depth=self.pathtrace_max_depth, seed=seed, light=light,
                                  spp_per_pass=_pass_size(self.pathtrace_spp),
                                  rr_depth=DATASET_RR_DEPTH)
        config = self.tof
        if config.effects["subsurface"].enabled:  # the path tracer has it (translucent media)
            config = config.with_effect("subsurface", enabled=False)
        return render_tof(surface, config, rng, supersample=cam.supersample,
                          frame_index=frame_index, transport=transport)

    def capture_checkerboard(self, board_to_camera_mm: np.ndarray, rng: np.random.Generator,
                             *, board: CheckerboardConfig | None = None,
                             frame_index: int = 0, stamp_ns: int = 0) -> ToFFrame:
        """A calibration capture: the graded checkerboard at a pose, reference = its true range.

        Args:
            board_to_camera_mm: (4, 4) board frame -> camera optical frame, mm.
            rng: source of sensor noise.
        """
        cam = self.camera
        surface = render_checkerboard(board_to_camera_mm, cam.window.scaled(cam.supersample),
                                      board or CheckerboardConfig())
        # A single plane exchanges no light with itself: the one-bounce transport rejects
        # every pair (both cosines are 0) and adds exactly 0, so skipping it changes no output
        # (test_fast_paths checks the equality) and saves half of a calibration capture.
        config = self.tof
        if config.effects["multipath"].enabled:
            config = config.with_effect("multipath", enabled=False)
        measurement = render_tof(surface, config, rng, supersample=cam.supersample,
                                 frame_index=frame_index)
        centre = centre_samples(surface, cam.supersample)
        # Pixels straddling the board edge mix board and nothing: not a clean reference.
        truth = np.where(_interior(centre.object_id == 1), centre.range_mm, np.nan)
        return ToFFrame(range_mm=cam.keep_crop(measurement.range_mm),
                        amplitude=cam.keep_crop(measurement.amplitude),
                        intrinsics=cam.intrinsics, mod_freq_hz=self.tof.mod_freq_hz,
                        reference_mm=cam.keep_crop(truth).astype(np.float32),
                        stamp_ns=stamp_ns, albedo=cam.keep_crop(centre.albedo))


def _pass_size(spp: int) -> int:
    """Samples per path-tracer pass for ``spp`` samples per pixel (at most 64, to bound memory).

    Raises:
        SimulationError: ``spp`` is not a positive multiple of 16 (up to 64) or of 64.
    """
    if isinstance(spp, (int, np.integer)) and spp >= 16 and spp % 16 == 0 and \
            (spp <= 64 or spp % 64 == 0):
        return int(min(spp, 64))
    raise SimulationError(f"pathtrace_spp must be 16, 32, 48, 64 or a multiple of 64, got {spp!r}")


def _interior(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of ``mask`` whose 8 neighbours are in ``mask`` too."""
    padded = np.pad(mask, 1, constant_values=False)
    out = mask.copy()
    h, w = mask.shape
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out &= padded[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
    return out
