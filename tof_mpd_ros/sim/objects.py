"""The object library of the simulated cell: boxes, cylinders, spheres and triangular prisms.

The library is generated once from a fixed seed, so an object's identity (``library_id``) means
the same shape, size, albedo and material in every run. It is split by identity into disjoint
``train`` and ``test`` halves, as the paper's MD-Train / MD-Test datasets use disjoint objects.

Every shape is described in its own *object frame*, in millimetres: origin at the centre of the
footprint on the table, z up, so the object rests on the table at z = 0 and occupies z in
[0, height].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
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
MATERIAL_NAMES = {MATERIAL_DIFFUSE: "diffuse", MATERIAL_TRANSLUCENT_PLASTIC: "translucent_plastic",
                  MATERIAL_WAX: "wax"}
NON_DEFAULT_MATERIAL_FRACTION = 0.15

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
        albedo: diffuse near-infrared reflectance in [0, 1].
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


@lru_cache(maxsize=1)
def object_library() -> tuple[ObjectSpec, ...]:
    """All LIBRARY_SIZE objects, identical in every run (ids 1..LIBRARY_SIZE, kinds cycling)."""
    rng = np.random.default_rng(LIBRARY_SEED)
    return tuple(_make_object(i + 1, KINDS[i % len(KINDS)], rng) for i in range(LIBRARY_SIZE))


@lru_cache(maxsize=2)
def library_split(split: str) -> tuple[ObjectSpec, ...]:
    """The ``"train"`` or ``"test"`` half of the library, disjoint by object identity.

    Each kind is split evenly, so both halves hold every kind of shape.

    Raises:
        InputError: for an unknown split name.
    """
    if split not in SPLITS:
        raise InputError(f"split must be one of {SPLITS}, got {split!r}")
    rng = np.random.default_rng(LIBRARY_SEED + 1)
    chosen: list[ObjectSpec] = []
    for kind in KINDS:
        of_kind = [o for o in object_library() if o.kind == kind]
        order = rng.permutation(len(of_kind))
        half = order[: len(of_kind) // 2] if split == "train" else order[len(of_kind) // 2:]
        chosen.extend(of_kind[i] for i in sorted(half))
    return tuple(sorted(chosen, key=lambda o: o.library_id))
