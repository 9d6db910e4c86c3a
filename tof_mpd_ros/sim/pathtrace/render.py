"""Mitsuba 3 + mitransient rendering of a cell scene into an AMCW phasor image.

Nothing here imports mitsuba when the module is imported: :func:`load_mitsuba` does, the first
time a function below needs it (install the optional extra:
``pip install 'tof_mpd_ros[pathtrace]'``; the CPU variant ``llvm_ad_mono`` also needs a system
LLVM library, Debian's ``libllvm19``).

Units: the Mitsuba scene is built in **millimetres** (the simulator's unit), so optical path
lengths are in mm too; Mitsuba computes in float32, whose resolution at the ~1 m coordinates and
paths of the cell is < 1e-4 mm.

How the phasor is formed: mitransient's ``transient_path`` integrator hands each path
contribution ``w`` with its optical path length ``L`` (camera → surfaces → light, mm) to the
film; its ``phasor_hdr_film`` accumulates, for each of a few frequencies ν (cycles per mm of
path), ``w · e^{-i 2π ν L}`` per pixel — an exact, continuous phase with no time binning. The film
picks its frequencies as ``fftfreq(temporal_bins, bin_width_opl)`` around ``1 / wl_mean``; with
``temporal_bins = 4``, ``bin_width_opl = λ / 4`` and ``wl_mean = λ = c / f_mod`` one of them is
exactly ν = f_mod / c. The simulator's convention (``tof/phasor.py``) is ``a · e^{+i 2π f L / c}``
with ``a`` = π × radiance × light power, so :func:`render_phasor` returns
``π · I0 · conj(film value)``: for the direct path L = 2 r and the phase is 4π f r / c.

Camera: a small Python sensor plugin (``tof_pinhole``) casts the exact pinhole rays of an
:class:`~tof_mpd_ros.camera.Intrinsics` (any fx, fy, cx, cy; the crop of a sensor is off-centre
in general) from the optical frame (x right, y down, z forward); the film's box pixel filter
spreads each pixel's samples uniformly over its footprint, so depth-edge pixels mix their
surfaces as a finite pixel does. Light: Mitsuba's ``spot`` emitter at the camera centre along the
optical axis (:mod:`.light`). Surfaces: each object's material (:mod:`.materials`: Lambertian
``diffuse`` of its albedo, glossy plastic, rough metals, and translucent plastics as a scattering
volume behind an index-matched surface); table = rectangle, box = cube, cylinder = quadric side
+ two disks (outward normals, so the three bound one volume), sphere = analytic sphere, prism =
triangle mesh. Integrator: ``transient_path``; ``transient_prbvolpath`` when a scene holds a
translucent object (media).

``max_depth`` is Mitsuba's path depth: the number of path segments leaving the camera, the last
one ending on the light. 2 = direct only (camera → surface → light), 3 = direct + exactly one
indirect bounce, n = up to n − 2 indirect bounces; −1 = unbounded. Russian roulette is switched
off (``rr_depth = max_depth``), so a depth-limited render is exactly the truncated series,
unless ``rr_depth`` is given: then paths longer than it end at random (Russian roulette; the
estimate stays unbiased), which bounds the random walks in bright translucent objects
(:data:`DATASET_RR_DEPTH`).
"""

from __future__ import annotations

import glob
import math
import os
import re
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from ...camera import Intrinsics
from ...errors import SimulationError
from ...frame import DEFAULT_MOD_FREQ_HZ
from ...validation import check_array
from ..scene import PlacedObject, Scene, Table
from ..tof.phasor import SPEED_OF_LIGHT_MM_S, phasor_to_range
from .light import SpotLight
from .materials import has_medium, interior_medium, surface_bsdf

#: Mitsuba variant: CPU (LLVM JIT), one spectral channel
VARIANT = "llvm_ad_mono"
#: ``max_depth`` for direct light only (camera → surface → light)
DIRECT_ONLY = 2
#: ``max_depth`` for direct light plus exactly one indirect bounce
ONE_BOUNCE = 3
#: Russian roulette from this path depth on in path-traced datasets (all bounces, unbiased)
DATASET_RR_DEPTH = 64
#: where to look for the LLVM library when DRJIT_LIBLLVM_PATH is unset: drjit's own search
#: paths (Debian's multiarch folders) and versioned LLVM trees
_LLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
               "/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*")
_SENSOR_PLUGIN = "tof_pinhole"

_STATE: dict[str, ModuleType] = {}


def _find_llvm() -> str:
    """Path of the LLVM shared library for drjit's CPU backend (sets ``DRJIT_LIBLLVM_PATH``).

    Raises:
        SimulationError: the variable points nowhere, or no library is installed.
    """
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    if given:
        if not os.path.isfile(given):
            raise SimulationError(f"DRJIT_LIBLLVM_PATH={given!r} is not a file: point it at an "
                                  "LLVM shared library (libLLVM*.so) or unset it")
        return given
    found = {p for pattern in _LLVM_GLOBS for p in glob.glob(pattern) if os.path.isfile(p)}
    if not found:
        raise SimulationError("the path tracer's CPU variant needs an LLVM shared library and "
                              "none was found: install one (Debian: apt-get install libllvm19) "
                              "or set DRJIT_LIBLLVM_PATH to its path")
    # the newest version: compare the numbers in the file names (libLLVM-19.so, libLLVM.so.19.1)
    newest = max(found, key=lambda p: ([int(n) for n in re.findall(r"\d+", os.path.basename(p))],
                                       p))
    os.environ["DRJIT_LIBLLVM_PATH"] = newest
    return newest


def load_mitsuba() -> ModuleType:
    """Import mitsuba (variant :data:`VARIANT`) and mitransient, and register our sensor.

    Returns:
        The ``mitsuba`` module, ready to use.

    Raises:
        SimulationError: mitsuba/mitransient are not installed (the ``[pathtrace]`` extra), or
            drjit's LLVM backend cannot start.
    """
    if "mi" in _STATE:
        return _STATE["mi"]
    _find_llvm()
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as err:
        raise SimulationError("the path-tracer reference needs mitsuba and mitransient: install "
                              "the optional extra, pip install 'tof_mpd_ros[pathtrace]'") from err
    mi.set_variant(VARIANT)
    if not dr.has_backend(dr.JitBackend.LLVM):
        raise SimulationError("drjit's LLVM backend is inactive although an LLVM library was "
                              f"found ({os.environ.get('DRJIT_LIBLLVM_PATH')}): check that it is "
                              "a complete libLLVM shared library, or set DRJIT_LIBLLVM_PATH")
    try:
        import mitransient  # noqa: F401  (registers transient_path and phasor_hdr_film)
    except ImportError as err:
        raise SimulationError("the path-tracer reference needs mitransient: install the "
                              "optional extra, pip install 'tof_mpd_ros[pathtrace]'") from err
    _register_sensor(mi, dr)
    _STATE["mi"] = mi
    return mi


def versions() -> dict[str, str]:
    """``{"mitsuba": ..., "mitransient": ..., "drjit": ...}`` version strings (loads mitsuba)."""
    mi = load_mitsuba()
    import drjit as dr
    import mitransient
    return {"mitsuba": mi.__version__, "mitransient": mitransient.__version__,
            "drjit": dr.__version__}


def _register_sensor(mi: Any, dr: Any) -> None:
    """Register the ``tof_pinhole`` sensor: exact pinhole rays of fx, fy, cx, cy (pixels)."""

    class PinholeSensor(mi.Sensor):
        """Pinhole camera in the optical frame (x right, y down, z forward).

        Film position s in [0, 1]² maps to the continuous pixel coordinate
        ``(u, v) = s · (W, H) − 0.5`` (pixel centres at integers, as :class:`Intrinsics`), and
        the ray direction is ``R · ((u − cx)/fx, (v − cy)/fy, 1)`` normalised, from the camera
        centre (``to_world`` = camera-to-world, no scale).
        """

        def __init__(self, props: Any) -> None:
            super().__init__(props)
            self.fx = float(props.get("fx"))
            self.fy = float(props.get("fy"))
            self.cx = float(props.get("cx"))
            self.cy = float(props.get("cy"))
            size = self.film().size()
            self.size_wh = (float(size.x), float(size.y))

        def _ray(self, time: Any, sample2: Any) -> Any:
            u = sample2.x * self.size_wh[0] - 0.5
            v = sample2.y * self.size_wh[1] - 0.5
            local = mi.Vector3f((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
            to_world = self.world_transform()
            direction = dr.normalize(to_world @ local)
            origin = to_world @ mi.Point3f(0.0, 0.0, 0.0)
            return mi.RayDifferential3f(mi.Ray3f(origin, direction, time, []))

        def sample_ray(self, time: Any, sample1: Any, sample2: Any, sample3: Any,
                       active: Any = True) -> tuple[Any, Any]:
            return self._ray(time, sample2), mi.Spectrum(1.0)

        def sample_ray_differential(self, time: Any, sample1: Any, sample2: Any, sample3: Any,
                                    active: Any = True) -> tuple[Any, Any]:
            return self._ray(time, sample2), mi.Spectrum(1.0)

        def bbox(self) -> Any:
            p = self.world_transform() @ mi.ScalarPoint3f(0.0, 0.0, 0.0)
            return mi.ScalarBoundingBox3f(p, p)

        def to_string(self) -> str:
            return (f"PinholeSensor[fx={self.fx}, fy={self.fy}, cx={self.cx}, cy={self.cy}, "
                    f"size={self.size_wh}]")

    mi.register_sensor(_SENSOR_PLUGIN, lambda props: PinholeSensor(props))


def _transform(mi: Any, matrix: np.ndarray) -> Any:
    """(4, 4) float64 numpy matrix -> Mitsuba scalar affine transform (float32)."""
    return mi.ScalarTransform4f(np.asarray(matrix, dtype=np.float64).tolist())


def _appearance(mi: Any, spec: Any, *, loaded: bool = False) -> dict[str, Any]:
    """``{"bsdf": ..., ["interior": ...]}`` of an object spec (dicts, or loaded objects)."""
    out: dict[str, Any] = {"bsdf": surface_bsdf(spec.material_id, spec.albedo)}
    medium = interior_medium(spec.material_id, spec.albedo)
    if medium is not None:
        out["interior"] = medium
    return {k: mi.load_dict(v) for k, v in out.items()} if loaded else out


def scene_has_media(scene: Scene) -> bool:
    """True when an object of ``scene`` is rendered as a scattering volume (translucent)."""
    return any(has_medium(o.spec.material_id) for o in scene.objects)


def _object_matrix(obj: PlacedObject) -> np.ndarray:
    """(4, 4) float64 object frame -> base frame (yaw about z, then translation), mm."""
    return obj.object_to_base_mm


def _prism_mesh(mi: Any, obj: PlacedObject, name: str) -> Any:
    """The triangular prism of ``obj`` as a closed, outward-wound triangle mesh (base frame)."""
    sx, sy, sz = obj.spec.dims_mm
    apex = obj.spec.apex_offset_mm
    section = np.array([[-sx / 2.0, 0.0], [sx / 2.0, 0.0], [apex, sz]])  # x-z cross-section
    local = np.array([[x, y, z] for y in (-sy / 2.0, sy / 2.0) for x, z in section])
    pose = _object_matrix(obj)
    verts = local @ pose[:3, :3].T + pose[:3, 3]
    faces = np.array([[0, 1, 2], [3, 5, 4],  # the two triangular ends
                      [0, 3, 4], [0, 4, 1], [1, 4, 5], [1, 5, 2], [2, 5, 3], [2, 3, 0]])
    centre = verts.mean(axis=0)
    for f in faces:  # wind every triangle so its normal points away from the centroid
        a, b, c = verts[f]
        if np.dot(np.cross(b - a, c - a), (a + b + c) / 3.0 - centre) < 0.0:
            f[[1, 2]] = f[[2, 1]]
    props = mi.Properties()
    for key, value in _appearance(mi, obj.spec, loaded=True).items():
        props[key] = value
    mesh = mi.Mesh(name, len(verts), len(faces), props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(verts.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    return mesh


def _object_shapes(mi: Any, obj: PlacedObject) -> dict[str, Any]:
    """Mitsuba shapes (dict entries) of one placed object, base frame, mm."""
    key = f"object_{obj.scene_index}"
    spec = obj.spec
    look = _appearance(mi, spec)
    if spec.kind == "box":
        sx, sy, sz = spec.dims_mm
        scale = np.diag([sx / 2.0, sy / 2.0, sz / 2.0, 1.0])
        lift = np.eye(4)
        lift[2, 3] = sz / 2.0
        matrix = _object_matrix(obj) @ lift @ scale
        return {key: {"type": "cube", "to_world": _transform(mi, matrix), **look}}
    if spec.kind == "cylinder":
        r, h = spec.dims_mm[0] / 2.0, spec.dims_mm[2]
        base = np.array([obj.x_mm, obj.y_mm, obj.z_mm])
        top = base + np.array([0.0, 0.0, h])
        top_cap = np.diag([r, r, 1.0, 1.0])
        top_cap[:3, 3] = top
        bottom_cap = np.diag([r, -r, -1.0, 1.0])  # turned over: its normal points down
        bottom_cap[:3, 3] = base
        return {f"{key}_side": {"type": "cylinder", "p0": base.tolist(),
                                "p1": top.tolist(), "radius": r, **look},
                f"{key}_top": {"type": "disk", "to_world": _transform(mi, top_cap), **look},
                f"{key}_bottom": {"type": "disk", "to_world": _transform(mi, bottom_cap),
                                  **look}}
    if spec.kind == "sphere":
        r = spec.dims_mm[0] / 2.0
        return {key: {"type": "sphere", "center": [obj.x_mm, obj.y_mm, obj.z_mm + r],
                      "radius": r, **look}}
    return {key: _prism_mesh(mi, obj, key)}


def _film(intrinsics: Intrinsics, mod_freq_hz: float) -> dict[str, Any]:
    """phasor_hdr_film whose frequencies include exactly f_mod / c (cycles per mm of path)."""
    wavelength_mm = SPEED_OF_LIGHT_MM_S / mod_freq_hz
    return {"type": "phasor_hdr_film", "width": intrinsics.width, "height": intrinsics.height,
            "temporal_bins": 4, "bin_width_opl": wavelength_mm / 4.0, "start_opl": 0.0,
            "wl_mean": wavelength_mm, "wl_sigma": 1e12 * wavelength_mm,
            "rfilter": {"type": "box"}}


def scene_to_mitsuba(scene: Scene, camera_to_base_mm: np.ndarray, intrinsics: Intrinsics, *,
                     light: SpotLight | None = None,
                     mod_freq_hz: float = DEFAULT_MOD_FREQ_HZ) -> dict[str, Any]:
    """Mitsuba scene dict of a cell scene seen by a ToF camera with a co-located spot light.

    Args:
        scene: table and objects (base frame, mm).
        camera_to_base_mm: (4, 4) float pose of the camera optical frame (x right, y down,
            z forward) in the base frame, translation in mm, rotation without scale.
        intrinsics: the image grid (any fx, fy, cx, cy).
        light: the spot light at the camera centre (default :class:`SpotLight`); its radiant
            intensity in the dict is 1 (scaled by ``light.light_power`` in :func:`render_phasor`).
        mod_freq_hz: modulation frequency of the phasor film, Hz.

    Returns:
        A dict for ``mitsuba.load_dict`` (loads mitsuba): scene units mm, the ``tof_pinhole``
        sensor with a ``phasor_hdr_film`` (box pixel filter, independent sampler), a ``spot``
        emitter, and shapes with each object's material (:mod:`.materials`). It holds Mitsuba
        objects (transforms, meshes), so it is not JSON.

    Raises:
        InputError: malformed pose.
        SimulationError: mitsuba missing, or a non-positive modulation frequency.
    """
    pose = check_array("camera_to_base_mm", camera_to_base_mm, ndim=2, shape=(4, 4),
                       dtype_kind="fiu").astype(np.float64)
    if not (math.isfinite(mod_freq_hz) and mod_freq_hz > 0.0):
        raise SimulationError(f"mod_freq_hz must be > 0, got {mod_freq_hz}")
    spot = light if light is not None else SpotLight()
    mi = load_mitsuba()
    to_world = _transform(mi, pose)
    table = scene.table
    table_matrix = np.diag([table.half_extent_mm[0], table.half_extent_mm[1], 1.0, 1.0])
    table_matrix[:3, 3] = [table.centre_xy_mm[0], table.centre_xy_mm[1], table.height_mm]
    out: dict[str, Any] = {
        "type": "scene",
        "sensor": {"type": _SENSOR_PLUGIN, "fx": intrinsics.fx, "fy": intrinsics.fy,
                   "cx": intrinsics.cx, "cy": intrinsics.cy, "to_world": to_world,
                   "film": _film(intrinsics, mod_freq_hz),
                   "sampler": {"type": "independent", "sample_count": 1}},
        "light": {"type": "spot", "to_world": to_world, "intensity": 1.0,
                  "cutoff_angle": float(spot.cone_half_angle_deg),
                  "beam_width": float(spot.beam_width_deg)},
        "table": {"type": "rectangle", "to_world": _transform(mi, table_matrix),
                  "bsdf": surface_bsdf(table.material_id, table.albedo)},
    }
    for obj in scene.objects:
        out.update(_object_shapes(mi, obj))
    return out


@dataclass(frozen=True)
class _Loaded:
    scene: Any
    integrator: Any
    frequency_index: int


def _load(scene: Scene, pose: np.ndarray, intrinsics: Intrinsics, light: SpotLight,
          mod_freq_hz: float, max_depth: int, rr_depth: int | None) -> _Loaded:
    mi = load_mitsuba()
    if not (max_depth == -1 or max_depth >= 1):
        raise SimulationError(f"max_depth must be -1 (unbounded) or >= 1, got {max_depth}")
    if rr_depth is not None and rr_depth < 1:
        raise SimulationError(f"rr_depth must be >= 1 or None, got {rr_depth}")
    mscene = mi.load_dict(scene_to_mitsuba(scene, pose, intrinsics, light=light,
                                           mod_freq_hz=mod_freq_hz))
    if rr_depth is None:  # no Russian roulette: a depth-limited render is the truncated series
        rr_depth = max_depth if max_depth > 0 else 1 << 20
    kind = "transient_prbvolpath" if scene_has_media(scene) else "transient_path"
    integrator = mi.load_dict({"type": kind, "max_depth": int(max_depth),
                               "rr_depth": int(rr_depth)})
    freqs = np.array([float(f[0]) if np.ndim(f) else float(f)
                      for f in mscene.sensors()[0].film().frequencies])
    want = mod_freq_hz / SPEED_OF_LIGHT_MM_S
    hits = np.flatnonzero(np.abs(freqs - want) <= 1e-6 * want)
    if hits.size != 1:
        raise SimulationError(f"the phasor film has no frequency {want:.6e}/mm (it has "
                              f"{freqs.tolist()}): mitransient's film changed?")
    return _Loaded(mscene, integrator, int(hits[0]))


def render_phasor_passes(scene: Scene, camera_to_base_mm: np.ndarray, intrinsics: Intrinsics, *,
                         mod_freq_hz: float, spp: int, max_depth: int, seed: int,
                         light: SpotLight | None = None,
                         spp_per_pass: int = 64, rr_depth: int | None = None) -> np.ndarray:
    """Independent partial renders of :func:`render_phasor` (their mean is the phasor).

    Args:
        scene, camera_to_base_mm, intrinsics, mod_freq_hz, max_depth, light: see
            :func:`render_phasor`.
        spp: total samples per pixel, a multiple of ``spp_per_pass``.
        seed: base seed; pass k uses the Mitsuba seed ``seed · 2^16 + k`` (seeds < 2^16).
        spp_per_pass: samples per pixel of each pass (memory grows with it).
        rr_depth: Russian roulette from this path depth on (None: none, see the module
            docstring).

    Returns:
        (P, H, W) complex128 phasors of the P = spp / spp_per_pass passes, simulator amplitude
        units (π × radiance × light power), convention ``a · e^{+i 2π f L / c}``.

    Raises:
        SimulationError: bad sample counts or seed, mitsuba missing.
    """
    if spp_per_pass < 1 or spp < spp_per_pass or spp % spp_per_pass:
        raise SimulationError(f"spp ({spp}) must be a positive multiple of spp_per_pass "
                              f"({spp_per_pass})")
    if not 0 <= seed < 1 << 16:
        raise SimulationError(f"seed must be in [0, 65536), got {seed}")
    pose = check_array("camera_to_base_mm", camera_to_base_mm, ndim=2, shape=(4, 4),
                       dtype_kind="fiu").astype(np.float64)
    spot = light if light is not None else SpotLight()
    loaded = _load(scene, pose, intrinsics, spot, mod_freq_hz, max_depth, rr_depth)
    passes = spp // spp_per_pass
    out = np.empty((passes, intrinsics.height, intrinsics.width), dtype=np.complex128)
    for k in range(passes):
        _, phasors = loaded.integrator.render(loaded.scene, sensor=0, seed=(seed << 16) + k,
                                              spp=spp_per_pass)
        values = np.asarray(phasors, dtype=np.float64)[:, :, loaded.frequency_index, :]
        # film: Σ w e^{-i 2π ν L}; ours: π I0 Σ w e^{+i 2π ν L}
        out[k] = math.pi * spot.light_power * (values[..., 0] - 1j * values[..., 1])
    return out


def render_phasor(scene: Scene, camera_to_base_mm: np.ndarray, intrinsics: Intrinsics, *,
                  mod_freq_hz: float, spp: int, max_depth: int, seed: int,
                  light: SpotLight | None = None, spp_per_pass: int = 64,
                  rr_depth: int | None = None) -> np.ndarray:
    """Path-traced AMCW phasor of every pixel (no noise model, no systematic errors).

    Args:
        scene: table and objects (base frame, mm).
        camera_to_base_mm: (4, 4) float camera optical frame -> base frame, translation in mm.
        intrinsics: the image grid (any fx, fy, cx, cy).
        mod_freq_hz: modulation frequency, Hz.
        spp: samples per pixel (a multiple of ``spp_per_pass``), spread uniformly over each
            pixel's footprint.
        max_depth: Mitsuba path depth: :data:`DIRECT_ONLY` (2), :data:`ONE_BOUNCE` (3), larger
            for more bounces, −1 unbounded.
        seed: random seed in [0, 65536); the render is a deterministic function of it.
        light: the co-located spot light (default :class:`SpotLight`).
        spp_per_pass: samples per pixel per Mitsuba render call (bounds memory; passes are
            accumulated in float64).
        rr_depth: Russian roulette from this path depth on; None (default) = none, so a
            depth-limited render is exactly the truncated series.

    Returns:
        (H, W) complex128 phasor ``Σ a · e^{+i 2π f L / c}`` over the pixel's paths (L: path
        length, mm; so range = L / 2 for the direct path), a in the simulator's amplitude units
        (π × radiance × ``light.light_power``); 0 where no path reaches the light.
    """
    return render_phasor_passes(scene, camera_to_base_mm, intrinsics, mod_freq_hz=mod_freq_hz,
                                spp=spp, max_depth=max_depth, seed=seed, light=light,
                                spp_per_pass=spp_per_pass, rr_depth=rr_depth).mean(axis=0)


def phasor_range_amplitude(phasor: np.ndarray, mod_freq_hz: float, *,
                           min_amplitude: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Range and amplitude of a phasor image (pure numpy).

    Args:
        phasor: (H, W) complex phasors, convention ``a · e^{+i 4π f r / c}``.
        mod_freq_hz: modulation frequency, Hz.
        min_amplitude: pixels with amplitude <= this are NaN in the range (0: only pixels
            without light).

    Returns:
        range_mm: (H, W) float64 radial range in mm, wrapped into [0, c/2f), NaN where dark.
        amplitude: (H, W) float64 |phasor| in the simulator's amplitude units.
    """
    z = check_array("phasor", phasor, ndim=2, dtype_kind="c")
    amplitude = np.abs(z)
    range_mm = np.where(amplitude > min_amplitude, phasor_to_range(z, mod_freq_hz), np.nan)
    return range_mm, amplitude


def range_noise_mm(passes: np.ndarray, mod_freq_hz: float) -> np.ndarray:
    """Standard error of the range of the mean of independent partial renders (pure numpy).

    The range moves with the phasor component perpendicular to the mean phasor Z̄:
    σ_r = std(Im(Z_k · conj(Z̄)/|Z̄|)) / √P / (|Z̄| · 4π f / c).

    Args:
        passes: (P, H, W) complex phasors of P ≥ 2 independent passes.
        mod_freq_hz: modulation frequency, Hz.

    Returns:
        (H, W) float64 standard error of the range of the mean, mm; NaN where dark.
    """
    z = check_array("passes", passes, ndim=3, dtype_kind="c")
    if z.shape[0] < 2:
        raise SimulationError(f"range_noise_mm needs >= 2 passes, got {z.shape[0]}")
    mean = z.mean(axis=0)
    amp = np.abs(mean)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(amp > 0, mean / amp, 0.0)
        perp = (z * np.conj(unit)).imag
        k = 4.0 * math.pi * mod_freq_hz / SPEED_OF_LIGHT_MM_S
        sigma = perp.std(axis=0, ddof=1) / math.sqrt(z.shape[0]) / (amp * k)
    return np.where(amp > 0, sigma, np.nan)


def sensor_rays(camera_to_base_mm: np.ndarray, intrinsics: Intrinsics,
                pixels: np.ndarray) -> np.ndarray:
    """Directions of the Mitsuba sensor's rays through given (continuous) pixel coordinates.

    For checking the projection against :class:`Intrinsics`.

    Args:
        camera_to_base_mm: (4, 4) float camera optical frame -> base frame, mm.
        intrinsics: the image grid.
        pixels: (N, 2) float ``(u, v)`` pixel coordinates (centres at integers).

    Returns:
        (N, 3) float64 unit ray directions in the base frame, as Mitsuba computes them.
    """
    uv = check_array("pixels", pixels, ndim=2, shape=(None, 2), dtype_kind="fiu")
    mi = load_mitsuba()
    sensor = mi.load_dict(scene_to_mitsuba(Scene(Table()), camera_to_base_mm,
                                           intrinsics)["sensor"])
    film = np.array([intrinsics.width, intrinsics.height], dtype=np.float64)
    s = (uv + 0.5) / film
    ray, _ = sensor.sample_ray(0.0, 0.0, mi.Point2f(s[:, 0], s[:, 1]), mi.Point2f(0.5, 0.5))
    return np.stack([np.asarray(ray.d.x), np.asarray(ray.d.y), np.asarray(ray.d.z)],
                    axis=1).astype(np.float64)
