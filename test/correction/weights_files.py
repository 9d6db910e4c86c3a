"""Write edited copies of a weights file, re-sealed like a valid writer would (so a test of a
refusal reaches the check it means, not the digest)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tof_mpd_ros.correction.weights import array_digest


def rewrite_weights(src: Path, dst: Path, edit) -> Path:
    """Copy an npz applying ``edit(arrays, meta)``, re-sealing the digest."""
    with np.load(src, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(str(arrays.pop("metadata")))
    edit(arrays, meta)
    meta["array_digest"] = array_digest(arrays)
    arrays["metadata"] = np.array(json.dumps(meta))
    with open(dst, "wb") as fh:
        np.savez(fh, **arrays)
    return dst
