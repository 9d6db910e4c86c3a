"""Scenes of the simulated cell: a table with a few library objects resting on it.

Frame and units: everything is in the robot's *base* frame (the UR5e DH base, z up) in
millimetres. The robot stands on the table, so the table top is the plane z = ``table.height_mm``
(0 by default) and objects are placed in front of the robot around ``workspace_centre_mm``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError, SimulationError
from ..pose import make_pose, rot_z
from .objects import ObjectSpec, library_split

# Where objects are arranged in front of the robot (base frame, mm). Chosen so that camera
# poses 180-350 mm above the objects are comfortably inside the UR5e's reach.
DEFAULT_WORKSPACE_CENTRE_MM = (450.0, 0.0)


@dataclass(frozen=True)
class Table:
    """The table top: a horizontal rectangle.

    Attributes:
        height_mm: z of the table top in the base frame, mm.
        centre_xy_mm: (x, y) of the rectangle's centre in the base frame, mm.
        half_extent_mm: (half length along x, half width along y), mm.
        albedo: diffuse near-infrared reflectance in [0, 1].
        material_id: material index (0 = default diffuse).
    """

    height_mm: float = 0.0
    centre_xy_mm: tuple[float, float] = (450.0, 0.0)
    half_extent_mm: tuple[float, float] = (1000.0, 1000.0)
    albedo: float = 0.6
    material_id: int = 0


@dataclass(frozen=True, eq=False)
class PlacedObject:
    """A library object resting on the table.

    Attributes:
        spec: the library object.
        scene_index: 1-based index in the scene; ``SurfaceImage.object_id`` reports it.
        x_mm, y_mm: position of the footprint centre in the base frame, mm.
        z_mm: z of the object's bottom (the table top), mm.
        yaw_rad: rotation about the vertical axis, radians.
    """

    spec: ObjectSpec
    scene_index: int
    x_mm: float
    y_mm: float
    z_mm: float
    yaw_rad: float

    @property
    def object_to_base_mm(self) -> np.ndarray:
        """(4, 4) float64 object-frame -> base-frame transform, translation in mm."""
        return make_pose(rot_z(self.yaw_rad), np.array([self.x_mm, self.y_mm, self.z_mm]))

    def footprint_base(self) -> np.ndarray:
        """(K, 2) float64 footprint polygon (x, y) in the base frame, mm, counter-clockwise."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        rot = np.array([[c, -s], [s, c]])
        return self.spec.footprint() @ rot.T + np.array([self.x_mm, self.y_mm])

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre ((3,) float64, base frame, mm) and radius (mm) of a sphere enclosing it."""
        half = np.asarray(self.spec.dims_mm) / 2.0
        centre_local = np.array([0.0, 0.0, half[2]])
        # The prism apex may lean out by at most its offset; the box half-diagonal covers it
        # because |apex_offset| <= 0.3 * width < width / 2.
        radius = float(np.linalg.norm(half))
        return centre_local + np.array([self.x_mm, self.y_mm, self.z_mm]), radius


@dataclass(frozen=True)
class Scene:
    """A table and the objects on it.

    Attributes:
        table: the table top.
        objects: the placed objects, ``scene_index`` 1..len(objects) in order.
        split: which library half the objects came from (``"train"``, ``"test"`` or
            ``"custom"``).
    """

    table: Table
    objects: tuple[PlacedObject, ...] = field(default_factory=tuple)
    split: str = "custom"

    def objects_centroid_mm(self) -> np.ndarray:
        """(3,) float64: mean of the objects' bounding-box centres (base frame, mm); the table
        centre when the scene is empty."""
        if not self.objects:
            return np.array([*self.table.centre_xy_mm, self.table.height_mm])
        centres = [[o.x_mm, o.y_mm, o.z_mm + o.spec.height_mm / 2.0] for o in self.objects]
        return np.mean(np.asarray(centres), axis=0)

    def as_dict(self) -> dict[str, object]:
        """Plain-type description (JSON-ready) of the table and objects, mm and radians."""
        table = self.table
        return {
            "split": self.split,
            "table": {"height_mm": table.height_mm, "centre_xy_mm": list(table.centre_xy_mm),
                      "half_extent_mm": list(table.half_extent_mm), "albedo": table.albedo,
                      "material_id": table.material_id},
            "objects": [{"scene_index": o.scene_index, "library_id": o.spec.library_id,
                         "kind": o.spec.kind, "dims_mm": list(o.spec.dims_mm),
                         "apex_offset_mm": o.spec.apex_offset_mm, "albedo": o.spec.albedo,
                         "material_id": o.spec.material_id, "x_mm": o.x_mm, "y_mm": o.y_mm,
                         "z_mm": o.z_mm, "yaw_rad": o.yaw_rad} for o in self.objects],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Scene:
        """Inverse of :meth:`as_dict`: ``Scene.from_dict(scene.as_dict())`` has the same table,
        objects and floats as ``scene`` (so a ray cast of it is bit-identical), also after a JSON
        round trip.

        Raises:
            InputError: a missing or malformed field.
        """
        try:
            t = data["table"]
            table = Table(height_mm=float(t["height_mm"]),
                          centre_xy_mm=(float(t["centre_xy_mm"][0]), float(t["centre_xy_mm"][1])),
                          half_extent_mm=(float(t["half_extent_mm"][0]),
                                          float(t["half_extent_mm"][1])),
                          albedo=float(t["albedo"]), material_id=int(t["material_id"]))
            objects = []
            for o in data["objects"]:
                dims = tuple(float(v) for v in o["dims_mm"])
                if len(dims) != 3:
                    raise InputError(f"object dims_mm must have 3 entries, got {o['dims_mm']}")
                spec = ObjectSpec(int(o["library_id"]), str(o["kind"]), dims, float(o["albedo"]),
                                  int(o["material_id"]), float(o["apex_offset_mm"]))
                objects.append(PlacedObject(spec, int(o["scene_index"]), float(o["x_mm"]),
                                            float(o["y_mm"]), float(o["z_mm"]),
                                            float(o["yaw_rad"])))
            return cls(table, tuple(objects), str(data["split"]))
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(f"not a scene description ({type(err).__name__}: {err})") from err

    def top_height_mm(self) -> float:
        """z (base frame, mm) of the highest object top; the table top when empty."""
        return max((o.z_mm + o.spec.height_mm for o in self.objects),
                   default=self.table.height_mm)


@dataclass(frozen=True)
class SceneConfig:
    """How :func:`make_scene` arranges objects.

    Attributes:
        n_objects: inclusive range of the number of objects per scene.
        workspace_centre_mm: (x, y) centre of the placement square, base frame, mm.
        placement_half_size_mm: every footprint lies inside the square of this half size.
        min_gap_mm: minimum clearance between footprints, mm.
        table_albedo: range of the table albedo, drawn per scene.
        table_height_mm: z of the table top in the base frame, mm.
        max_tries: placement attempts per object before the arrangement is redrawn.
        max_arrangements: redraws before giving up with :class:`SimulationError`.
    """

    n_objects: tuple[int, int] = (2, 5)
    workspace_centre_mm: tuple[float, float] = DEFAULT_WORKSPACE_CENTRE_MM
    placement_half_size_mm: float = 200.0
    min_gap_mm: float = 10.0
    table_albedo: tuple[float, float] = (0.5, 0.7)
    table_height_mm: float = 0.0
    max_tries: int = 200
    max_arrangements: int = 50


def footprints_separated(a: np.ndarray, b: np.ndarray, gap_mm: float) -> bool:
    """True if two convex polygons are at least ``gap_mm`` apart.

    Separating-axis test: the distance between convex sets is at least the gap between their
    projections on any unit axis, and for polygons one of the edge normals attains it.

    Args:
        a, b: (K, 2) float convex polygons, counter-clockwise, same unit as ``gap_mm``.
    """
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        axes = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        pa, pb = a @ axes.T, b @ axes.T
        gaps = np.maximum(pb.min(axis=0) - pa.max(axis=0), pa.min(axis=0) - pb.max(axis=0))
        if np.any(gaps >= gap_mm):
            return True
    return False


def _try_place(spec: ObjectSpec, index: int, placed: list[PlacedObject], config: SceneConfig,
               rng: np.random.Generator) -> PlacedObject | None:
    """One object at a random free spot inside the placement square, or None."""
    cx, cy = config.workspace_centre_mm
    half = config.placement_half_size_mm
    for _ in range(config.max_tries):
        candidate = PlacedObject(spec, index, cx + rng.uniform(-half, half),
                                 cy + rng.uniform(-half, half), config.table_height_mm,
                                 rng.uniform(-math.pi, math.pi))
        fp = candidate.footprint_base()
        inside = np.all(np.abs(fp - np.array([cx, cy])) <= half)
        if inside and all(footprints_separated(fp, o.footprint_base(), config.min_gap_mm)
                          for o in placed):
            return candidate
    return None


def make_scene(split: str, rng: np.random.Generator,
               config: SceneConfig = SceneConfig(), *, materials: str = "builtin") -> Scene:
    """A random arrangement of 2-5 objects of one library split on the table.

    Objects are distinct library objects, rest on the table with a random yaw, and their
    footprints are ``config.min_gap_mm`` apart and inside the placement square.

    Args:
        split: ``"train"`` or ``"test"``.
        rng: source of randomness (the scene is a deterministic function of its state).
        config: arrangement parameters.
        materials: the library's material set (:data:`.objects.MATERIAL_SETS`): ``"builtin"``,
            or ``"pathtrace"`` for the path tracer (some objects glossy or metal). The draws are
            the same, so for one ``rng`` state both give the same objects at the same places;
            only their materials differ.

    Raises:
        InputError: unknown split, material set or inconsistent config.
        SimulationError: no free arrangement found within ``config.max_arrangements`` redraws.
    """
    objects = library_split(split, materials)
    lo, hi = config.n_objects
    if not 1 <= lo <= hi <= len(objects):
        raise InputError(f"n_objects must satisfy 1 <= lo <= hi <= {len(objects)}, "
                         f"got {config.n_objects}")
    table = Table(height_mm=config.table_height_mm, centre_xy_mm=config.workspace_centre_mm,
                  albedo=float(rng.uniform(*config.table_albedo)))
    n = int(rng.integers(lo, hi + 1))
    for _ in range(config.max_arrangements):
        chosen = rng.choice(len(objects), size=n, replace=False)
        placed: list[PlacedObject] = []
        for index, i in enumerate(chosen, start=1):
            obj = _try_place(objects[int(i)], index, placed, config, rng)
            if obj is None:
                break
            placed.append(obj)
        if len(placed) == n:
            return Scene(table, tuple(placed), split)
    raise SimulationError(f"could not arrange {n} objects of the {split!r} split in a "
                          f"{2 * config.placement_half_size_mm:.0f} mm square after "
                          f"{config.max_arrangements} attempts")


def make_box_scene(size_mm: tuple[float, float, float] = (150.0, 150.0, 100.0), *,
                   albedo: float = 0.5, table_albedo: float = 0.6,
                   centre_xy_mm: tuple[float, float] = DEFAULT_WORKSPACE_CENTRE_MM,
                   yaw_rad: float = 0.0, table_height_mm: float = 0.0) -> Scene:
    """One box on the table, for physics tests (the paper's Fig. 1 wood box).

    Args:
        size_mm: box extents (x, y, z) in mm, before the yaw.
        albedo: the box's reflectance in [0, 1].
        table_albedo: the table's reflectance in [0, 1].
        centre_xy_mm: footprint centre in the base frame, mm.
        yaw_rad: rotation about the vertical, radians.
        table_height_mm: z of the table top in the base frame, mm.
    """
    spec = ObjectSpec(0, "box", tuple(float(s) for s in size_mm), float(albedo))
    box = PlacedObject(spec, 1, float(centre_xy_mm[0]), float(centre_xy_mm[1]),
                       table_height_mm, float(yaw_rad))
    table = Table(height_mm=table_height_mm, centre_xy_mm=centre_xy_mm, albedo=table_albedo)
    return Scene(table, (box,), "custom")
