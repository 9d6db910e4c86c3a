"""What each material of the object library is to the path tracer: Mitsuba 3 BSDF and medium dicts.

Pure Python (plain dicts, no mitsuba import), so the mapping is testable without the extra.

| material (``objects.MATERIAL_*``) | Mitsuba | parameters |
| --- | --- | --- |
| diffuse | ``diffuse`` | reflectance = albedo |
| glossy plastic | ``roughplastic`` (GGX) | diffuse base = albedo, clear coat n = 1.49, α = 0.1 |
| aluminium | ``roughconductor`` (GGX) | n + ik = 2.80 + 8.45i (≈ 850 nm), α = 0.15 |
| steel | ``roughconductor`` (GGX) | n + ik = 2.90 + 3.30i (≈ 850 nm), α = 0.25 |
| translucent plastic | ``null`` surface + ``homogeneous`` medium | ℓ = 1 mm, n = 1.49 (see below) |
| wax | ``null`` surface + ``homogeneous`` medium | ℓ = 2 mm, n = 1.44 |

Roughness α is the GGX width (about the RMS slope of the micro-surface): a machined aluminium part
and a ground steel one, and a moulded plastic with a satin coat. The metals' albedo in the library
is their normal-incidence reflectance (:func:`..objects.normal_reflectance`); the BSDF ignores it
(the refractive index fixes the reflectance, with its Fresnel rise at grazing angles).

**Subsurface plastics.** Light enters a translucent object, scatters inside and leaves late and a
little further on: a volumetric random walk. Mitsuba 3 has no BSSRDF (dipole) model, and
mitransient's volumetric integrator ``transient_prbvolpath`` handles homogeneous media with the
path length of every in-medium segment. What we chose, and why:

* **An index-matched (``null``) boundary**, not a refracting ``roughdielectric`` one. mitransient
  (1.3.1) adds the segment from a light-sampling vertex to the light at the vertex's current
  refractive index; at an exit vertex on a refracting boundary that is the interior's n, so the
  last segment, in air, would count n times its length (tens of mm of false range). A ``null``
  boundary keeps every segment at n = 1: no Fresnel reflection at the surface (a real plastic
  reflects ~4 % specularly), no total internal reflection.
* **A time-equivalent medium.** With n = 1 inside, light would cross the medium n times too
  fast. A medium with every coefficient divided by n (σ_t = 1 / (n ℓ), ℓ the transport mean free
  path, isotropic phase function) has the same single-scattering albedo and n-times longer
  geometric paths, so the distribution of *optical* path lengths — the delay the ToF camera
  measures — and the total reflectance are those of the real material; the lateral spread of
  the re-emerging light is n times too wide (1.5 mm instead of 1 mm for ℓ = 1 mm).
* **Albedo as diffuse reflectance.** The single-scattering albedo α' is chosen so that a
  semi-infinite slab with an index-matched boundary reflects the object's ``albedo`` in total,
  by the diffusion approximation of Jensen et al. (2001):
  ``R_d = α'/2 · (1 + e^{−4/3 · s}) · e^{−s}``, ``s = √(3 (1 − α'))``. The path tracer agrees:
  a box of α' = 0.5 / 0.9 / 0.99 returns 0.10 / 0.39 / 0.74 of a white Lambertian's amplitude,
  the formula gives 0.088 / 0.385 / 0.747.

Bright translucent objects (α' → 1) take long random walks (albedo 0.8 needs α' ≈ 0.994, 0.9
needs 0.9987: light that re-emerges has scattered hundreds to thousands of times); the dataset
renderer therefore uses Russian roulette after 64 path vertices
(:data:`.render.DATASET_RR_DEPTH`): unbiased, 4× faster on such a box, but its per-pixel noise
is heavy-tailed — on a 150 mm box of α' = 0.9975 (albedo ≈ 0.86), σ_t = 1/mm at 32 samples per
pixel the mean delay over the box is 15.4 mm (15.8 mm without roulette) while the median pixel
reads 10.5 mm (14.5 mm).
"""

from __future__ import annotations

import math
from typing import Any

from ...errors import InputError
from ..objects import (
    MATERIAL_ALUMINIUM,
    MATERIAL_GLOSSY_PLASTIC,
    MATERIAL_NAMES,
    MATERIAL_STEEL,
    MATERIAL_TRANSLUCENT_PLASTIC,
    MATERIAL_WAX,
    METAL_IOR,
)

#: glossy plastic: clear coat index and GGX roughness
GLOSSY_IOR = 1.49
GLOSSY_ALPHA = 0.1
#: metals: GGX roughness
METAL_ALPHA = {MATERIAL_ALUMINIUM: 0.15, MATERIAL_STEEL: 0.25}
#: translucent materials: (refractive index n, transport mean free path ℓ in mm)
TRANSLUCENT = {MATERIAL_TRANSLUCENT_PLASTIC: (1.49, 1.0), MATERIAL_WAX: (1.44, 2.0)}


def _check_material(material_id: int, albedo: float) -> None:
    if material_id not in MATERIAL_NAMES:
        raise InputError(f"material_id must be one of {sorted(MATERIAL_NAMES)}, "
                         f"got {material_id!r}")
    if not 0.0 <= albedo <= 1.0:
        raise InputError(f"albedo must be in [0, 1], got {albedo}")


def surface_bsdf(material_id: int, albedo: float) -> dict[str, Any]:
    """Mitsuba BSDF dict of a surface of the object library's material and albedo.

    Args:
        material_id: one of ``objects.MATERIAL_NAMES``.
        albedo: the object's albedo in [0, 1] (see the table in the module docstring for what
            it means per material).

    Returns:
        A plain dict for ``mitsuba.load_dict`` (floats and strings only; mono variant).

    Raises:
        InputError: unknown material or albedo outside [0, 1].
    """
    _check_material(material_id, albedo)
    if material_id == MATERIAL_GLOSSY_PLASTIC:
        return {"type": "roughplastic", "distribution": "ggx", "alpha": GLOSSY_ALPHA,
                "int_ior": GLOSSY_IOR, "ext_ior": 1.0, "nonlinear": False,
                "diffuse_reflectance": {"type": "uniform", "value": float(albedo)}}
    if material_id in METAL_IOR:
        n, k = METAL_IOR[material_id]
        return {"type": "roughconductor", "distribution": "ggx",
                "alpha": METAL_ALPHA[material_id], "eta": n, "k": k}
    if material_id in TRANSLUCENT:
        return {"type": "null"}
    return {"type": "diffuse", "reflectance": {"type": "uniform", "value": float(albedo)}}


def interior_medium(material_id: int, albedo: float) -> dict[str, Any] | None:
    """Mitsuba medium dict inside an object of this material (None: an opaque surface).

    Args:
        material_id: one of ``objects.MATERIAL_NAMES``.
        albedo: the object's albedo in [0, 1], its total diffuse reflectance.

    Returns:
        A ``homogeneous`` medium (extinction σ_t in 1/mm, single-scattering albedo, isotropic
        phase function) for the translucent materials, None for the others.

    Raises:
        InputError: unknown material or albedo outside [0, 1].
    """
    _check_material(material_id, albedo)
    if material_id not in TRANSLUCENT:
        return None
    n, mean_free_path_mm = TRANSLUCENT[material_id]
    return {"type": "homogeneous", "sigma_t": 1.0 / (n * mean_free_path_mm),
            "albedo": single_scattering_albedo(albedo), "phase": {"type": "isotropic"}}


def has_medium(material_id: int) -> bool:
    """True for the materials rendered as a volume (:func:`interior_medium` is not None)."""
    return material_id in TRANSLUCENT


def diffuse_reflectance(single_albedo: float) -> float:
    """Total diffuse reflectance of a semi-infinite, index-matched scattering medium.

    The diffusion approximation (Jensen et al. 2001) with boundary factor A = 1:
    ``R_d = α'/2 · (1 + e^{−4/3 · s}) · e^{−s}``, ``s = √(3 (1 − α'))``.

    Args:
        single_albedo: α' in [0, 1], the medium's single-scattering albedo.

    Returns:
        R_d in [0, 1]; increasing in α', 0 at α' = 0 and 1 at α' = 1.
    """
    if not 0.0 <= single_albedo <= 1.0:
        raise InputError(f"single-scattering albedo must be in [0, 1], got {single_albedo}")
    s = math.sqrt(3.0 * (1.0 - single_albedo))
    return 0.5 * single_albedo * (1.0 + math.exp(-4.0 / 3.0 * s)) * math.exp(-s)


def single_scattering_albedo(reflectance: float) -> float:
    """Inverse of :func:`diffuse_reflectance`: the α' whose medium reflects ``reflectance``.

    Args:
        reflectance: total diffuse reflectance in [0, 1].

    Returns:
        α' in [0, 1] (bisection to 1e-12).
    """
    if not 0.0 <= reflectance <= 1.0:
        raise InputError(f"reflectance must be in [0, 1], got {reflectance}")
    lo, hi = 0.0, 1.0
    while hi - lo > 1e-12:
        mid = 0.5 * (lo + hi)
        if diffuse_reflectance(mid) < reflectance:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


__all__ = ["GLOSSY_ALPHA", "GLOSSY_IOR", "METAL_ALPHA", "TRANSLUCENT",
           "diffuse_reflectance", "has_medium", "interior_medium", "single_scattering_albedo",
           "surface_bsdf"]
