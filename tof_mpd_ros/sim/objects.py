"""The object library of the simulated cell: boxes, cylinders, spheres and triangular prisms.

The library is generated once from a fixed seed, so an object's identity (``library_id``) means
the same shape, size, albedo and material in every run. It is split by identity into disjoint
``train`` and ``test`` halves, as the paper's MD-Train / MD-Test datasets use disjoint objects.

Every shape is described in its own *object frame*, in millimetres: origin at the centre of the
footprint on the table, z up, so the object rests on the table at z = 0 and occupies z in
[0, height].

Materials come in two sets (``MATERIAL_SETS``), chosen by the renderer a dataset is made for:

* ``"builtin"`` (the default, what the built-in renderer's datasets use): Lambertian diffusers,
  and about 15 % translucent plastic or wax (the ``subsurface`` effect's materials);
* ``"pathtrace"`` (``tof-mpd sim dataset --renderer pathtrace``): the same library — same shapes,
  sizes, albedos, translucent objects, and the same draws in :func:`~.scene.make_scene` — with
  about a quarter of the diffuse objects made glossy plastic (a diffuse base of the object's
  albedo under a rough clear coat) and a quarter metal (aluminium or steel, rough). A metal's
  ``albedo`` is its normal-incidence reflectance in the near infrared (from ``METAL_IOR``).

The path tracer (:mod:`.pathtrace.materials`) renders every material as what it is. The built-in
renderer has no specular or glossy transport: it treats glossy plastic and metal as Lambertian
diffusers of their ``albedo`` (so a metal box is a bright diffuse box to it), and the
translucent materials as diffuse unless ``subsurface`` is on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Literal

import numpy as np

from ..errors import InputError

KINDS = ("box", "cylinder", "sphere", "prism")
Split = Literal["train", "test"]
SPLITS: tuple[str, ...] = ("train", "test")

# The seed is part of the library's definition: changing it changes every dataset.
LIBRARY_SEED = 20160516
LIBRARY_SIZE = 64
SIZE_RANGE_MM = (100.0, 200.0)
ALBEDO_RANGE = (0.1, 0.9)
# Smallest dimension relative to the largest one, so no object degenerates into a sheet.
MIN_ASPECT = 0.4

# Material ids read by the sensor physics; 0 is a plain Lambertian diffuser.
MATERIAL_DIFFUSE = 0
MATERIAL_TRANSLUCENT_PLASTIC = 1
MATERIAL_WAX = 2
#: path-traced datasets only (the built-in renderer draws them as diffusers of their albedo)
MATERIAL_GLOSSY_PLASTIC = 3
MATERIAL_ALUMINIUM = 4
MATERIAL_STEEL = 5
MATERIAL_NAMES = {MATERIAL_DIFFUSE: "diffuse", MATERIAL_TRANSLUCENT_PLASTIC: "translucent_plastic",
                  MATERIAL_WAX: "wax", MATERIAL_GLOSSY_PLASTIC: "glossy_plastic",
                  MATERIAL_ALUMINIUM: "aluminium", MATERIAL_STEEL: "steel"}
NON_DEFAULT_MATERIAL_FRACTION = 0.15
#: complex refractive index (n, k) of the metals near 850 nm (the ToF LED), approximate
#: literature values: normal-incidence reflectance ≈ 0.87 (aluminium) and ≈ 0.55 (steel ~ iron)
METAL_IOR = {MATERIAL_ALUMINIUM: (2.80, 8.45), MATERIAL_STEEL: (2.90, 3.30)}

MATERIAL_SETS = ("builtin", "pathtrace")
#: share of the library's diffuse objects made glossy plastic / metal in the "pathtrace" set
GLOSSY_FRACTION = 0.25
METAL_FRACTION = 0.25

# Circles are approximated by a circumscribed polygon of this many sides for footprint checks.
_CIRCLE_SIDES = 24


@dataclass(frozen=True)
class ObjectSpec:
    """One object of the library (shape, size and surface), in its object frame.

    Attributes:
        library_id: identity in the library, 1..LIBRARY_SIZE.
        kind: ``"box"``, ``"cylinder"`` (upright), ``"sphere"`` or ``"prism"`` (triangular
            cross-section in the x-z plane, extruded along y, lying on a rectangular face).
        dims_mm: (3,) extents in mm along object x, y, z: box (sx, sy, sz); cylinder
            (2r, 2r, h); sphere (2r, 2r, 2r); prism (base width, length, apex height).
        albedo: diffuse near-infrared reflectance in [0, 1] (a glossy plastic's diffuse base, a
            metal's normal-incidence reflectance; what the built-in renderer uses for all).
        material_id: 0 = default diffuse; see ``MATERIAL_NAMES`` for the others.
        apex_offset_mm: prism only, x of the apex relative to the base centre, mm.
    """

    library_id: int
    kind: str
    dims_mm: tuple[float, float, float]
    albedo: float
    material_id: int = MATERIAL_DIFFUSE
    apex_offset_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"object kind must be one of {KINDS}, got {self.kind!r}")
        if min(self.dims_mm) <= 0:
            raise InputError(f"object dims_mm must be > 0, got {self.dims_mm}")
        if not 0.0 <= self.albedo <= 1.0:
            raise InputError(f"object albedo must be in [0, 1], got {self.albedo}")

    @property
    def height_mm(self) -> float:
        """Top of the object above the table, mm."""
        return self.dims_mm[2]

    @property
    def largest_extent_mm(self) -> float:
        """Largest of the three extents, mm (the 100-200 mm of the paper)."""
        return max(self.dims_mm)

    def footprint(self) -> np.ndarray:
        """Convex polygon that contains the object's projection onto the table.

        Returns:
            (K, 2) float64 vertices (x, y) in the object frame, mm, counter-clockwise.
        """
        sx, sy, _ = self.dims_mm
        if self.kind in ("box", "prism"):
            hx, hy = sx / 2.0, sy / 2.0
            return np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        # Circumscribed polygon so that the circle lies inside it.
        radius = sx / 2.0 / math.cos(math.pi / _CIRCLE_SIDES)
        angles = np.arange(_CIRCLE_SIDES) * (2.0 * math.pi / _CIRCLE_SIDES)
        return radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)

    def polyhedron_planes(self) -> tuple[np.ndarray, np.ndarray]:
        """Half-spaces ``normals @ x <= offsets`` whose intersection is a box or prism.

        Returns:
            normals: (K, 3) float64 outward unit normals in the object frame.
            offsets: (K,) float64 plane offsets, mm.

        Raises:
            InputError: for curved kinds (cylinder, sphere).
        """
        sx, sy, sz = self.dims_mm
        if self.kind == "box":
            normals = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1],
                                [0, 0, -1]])
            return normals, np.array([sx / 2, sx / 2, sy / 2, sy / 2, sz, 0.0])
        if self.kind != "prism":
            raise InputError(f"{self.kind} is not a polyhedron")
        apex = np.array([self.apex_offset_mm, sz])
        normals = [[0.0, 1, 0], [0, -1, 0], [0, 0, -1]]
        offsets = [sy / 2, sy / 2, 0.0]
        for corner in (np.array([sx / 2, 0.0]), np.array([-sx / 2, 0.0])):
            edge = apex - corner
            # Outward normal of the slanted face in x-z: perpendicular to the edge, away from
            # the opposite corner.
            n = np.array([edge[1], -edge[0]]) * np.sign(corner[0])
            n /= np.linalg.norm(n)
            normals.append([n[0], 0.0, n[1]])
            offsets.append(float(n @ corner))
        return np.array(normals), np.array(offsets)


def _smaller(largest: float, rng: np.random.Generator) -> float:
    """A random extent between MIN_ASPECT * largest and largest (mm)."""
    return largest * rng.uniform(MIN_ASPECT, 1.0)


def _draw_dims(kind: str, rng: np.random.Generator) -> tuple[tuple[float, float, float], float]:
    """Random extents (mm) with the largest in SIZE_RANGE_MM, and a prism apex offset (mm)."""
    largest = rng.uniform(*SIZE_RANGE_MM)
    if kind == "sphere":
        return (largest, largest, largest), 0.0
    if kind == "cylinder":
        if rng.random() < 0.5:
            diameter, height = largest, _smaller(largest, rng)
        else:
            diameter, height = _smaller(largest, rng), largest
        return (diameter, diameter, height), 0.0
    dims = [largest, _smaller(largest, rng), _smaller(largest, rng)]
    rng.shuffle(dims)
    apex = rng.uniform(-0.3, 0.3) * dims[0] if kind == "prism" else 0.0
    return (dims[0], dims[1], dims[2]), apex


def _make_object(library_id: int, kind: str, rng: np.random.Generator) -> ObjectSpec:
    dims, apex = _draw_dims(kind, rng)
    albedo = rng.uniform(*ALBEDO_RANGE)
    material = MATERIAL_DIFFUSE
    if rng.random() < NON_DEFAULT_MATERIAL_FRACTION:
        material = int(rng.choice([MATERIAL_TRANSLUCENT_PLASTIC, MATERIAL_WAX]))
    return ObjectSpec(library_id, kind, dims, float(albedo), material, float(apex))


def normal_reflectance(n: float, k: float) -> float:
    """Reflectance at normal incidence of a surface of complex refractive index n + ik, in air:
    ``((n − 1)² + k²) / ((n + 1)² + k²)``."""
    return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)


def _pathtrace_material(spec: ObjectSpec) -> ObjectSpec:
    """The object as the "pathtrace" set has it: a diffuse object may turn glossy or metal.

    The draw comes from the object's own generator (library seed, 2, library id), so the
    built-in library's draws are untouched and an object's material is the same in every run.
    """
    if spec.material_id != MATERIAL_DIFFUSE:
        return spec
    rng = np.random.default_rng([LIBRARY_SEED, 2, spec.library_id])
    u = rng.random()
    if u < GLOSSY_FRACTION:
        return replace(spec, material_id=MATERIAL_GLOSSY_PLASTIC)
    if u < GLOSSY_FRACTION + METAL_FRACTION:
        metal = MATERIAL_ALUMINIUM if rng.random() < 0.5 else MATERIAL_STEEL
        return replace(spec, material_id=metal, albedo=normal_reflectance(*METAL_IOR[metal]))
    return spec


def _check_materials(materials: str) -> None:
    if materials not in MATERIAL_SETS:
        raise InputError(f"materials must be one of {MATERIAL_SETS}, got {materials!r}")


@lru_cache(maxsize=2)
def object_library(materials: str = "builtin") -> tuple[ObjectSpec, ...]:
    """All LIBRARY_SIZE objects, identical in every run (ids 1..LIBRARY_SIZE, kinds cycling).

    Args:
        materials: ``"builtin"`` (diffuse, translucent plastic, wax) or ``"pathtrace"`` (the
            same objects, some of the diffuse ones glossy or metal); see the module docstring.

    Raises:
        InputError: for an unknown material set.
    """
    _check_materials(materials)
    rng = np.random.default_rng(LIBRARY_SEED)
    library = tuple(_make_object(i + 1, KINDS[i % len(KINDS)], rng) for i in range(LIBRARY_SIZE))
    if materials == "pathtrace":
        return tuple(_pathtrace_material(o) for o in library)
    return library


@lru_cache(maxsize=4)
def library_split(split: str, materials: str = "builtin") -> tuple[ObjectSpec, ...]:
    """The ``"train"`` or ``"test"`` half of the library, disjoint by object identity.

    Each kind is split evenly, so both halves hold every kind of shape. Both material sets
    split the same identities.

    Raises:
        InputError: for an unknown split name or material set.
    """
    if split not in SPLITS:
        raise InputError(f"split must be one of {SPLITS}, got {split!r}")
    library = object_library(materials)
    rng = np.random.default_rng(LIBRARY_SEED + 1)
    chosen: list[ObjectSpec] = []
    for kind in KINDS:
        of_kind = [o for o in library if o.kind == kind]
        order = rng.permutation(len(of_kind))
        half = order[: len(of_kind) // 2] if split == "train" else order[len(of_kind) // 2:]
        chosen.extend(of_kind[i] for i in sorted(half))
    return tuple(sorted(chosen, key=lambda o: o.library_id))
