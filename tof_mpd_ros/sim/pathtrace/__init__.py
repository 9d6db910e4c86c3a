"""Path-tracer reference for the simulator's light transport (Mitsuba 3 + mitransient).

Importing this package does not import mitsuba; :func:`scene_to_mitsuba` and
:func:`render_phasor` do when they run (optional extra ``[pathtrace]``). :mod:`.golden` and
:mod:`.light` are pure numpy, for tests that compare against the committed golden frames.
"""

from .golden import GoldenFrame, compare_fields, interior_mask, load_golden, multipath_field
from .light import SpotLight, spot_profile
from .render import (
    DIRECT_ONLY,
    ONE_BOUNCE,
    load_mitsuba,
    phasor_range_amplitude,
    range_noise_mm,
    render_phasor,
    render_phasor_passes,
    scene_to_mitsuba,
    sensor_rays,
)

__all__ = [
    "DIRECT_ONLY",
    "ONE_BOUNCE",
    "GoldenFrame",
    "SpotLight",
    "compare_fields",
    "interior_mask",
    "load_golden",
    "load_mitsuba",
    "multipath_field",
    "phasor_range_amplitude",
    "range_noise_mm",
    "render_phasor",
    "render_phasor_passes",
    "scene_to_mitsuba",
    "sensor_rays",
    "spot_profile",
]
