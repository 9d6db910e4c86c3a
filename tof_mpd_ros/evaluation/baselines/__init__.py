"""The six competing methods of the paper's evaluation (§V "Baseline Methods").

Every method corrects one *calibrated* frame — ``range_mm`` (H, W) float32 radial range in mm and
``amplitude`` (H, W) float32, NaN = invalid — into (H, W) float32 corrected range in mm, NaN where
the input is invalid. Uniform interface (:class:`.base.Baseline`)::

    method = BASELINES["RF-WF"]()            # constructor arguments = fit parameters
    method.fit(train_frames)                 # no-op for the unsupervised ones
    best, table = grid_search(method, val_frames, method.param_grid)
    corrected = method.apply(frame.range_mm, frame.amplitude, **best)

=======  ============================================================  ===========
name     method                                                        learned
=======  ============================================================  ===========
JBF      amplitude-guided joint bilateral filter (OpenCV ximgproc)      no
WMF      amplitude-guided weighted median filter (OpenCV ximgproc)      no
RF-WF    forest confidence + confidence-weighted Gaussian filter        yes
RFD      forest regressing R* − R on F's patch features                 yes
TV       amplitude-weighted TV denoising, Chambolle–Pock                no
PD       patch-dictionary MRF (generic synthetic dictionary)            no
=======  ============================================================  ===========
"""

from __future__ import annotations

from .base import Baseline, FrameLike
from .grid import grid_search, within_threshold
from .jbf import JBF, joint_bilateral
from .pd import PD, patch_mrf
from .rfd import RFD
from .rfwf import RFWF
from .tv import TV, total_variation
from .wmf import WMF, weighted_median

BASELINES: dict[str, type[Baseline]] = {
    "JBF": JBF,
    "WMF": WMF,
    "RF-WF": RFWF,
    "RFD": RFD,
    "TV": TV,
    "PD": PD,
}

__all__ = [
    "BASELINES", "JBF", "PD", "RFD", "RFWF", "TV", "WMF", "Baseline", "FrameLike", "grid_search",
    "joint_bilateral", "patch_mrf", "total_variation", "weighted_median", "within_threshold",
]
