"""One weights file for the whole correction model, loadable without executing code.

Format: an ``.npz`` (zip) of named float32/uint8/str arrays read with ``allow_pickle=False``:

* ``metadata``: a 0-d str array holding JSON: ``format``, ``format_version``, ``kind``
  (``"patch"``: the paper's F and G, the default of files that do not say; ``"fcn"``: the
  fully-convolutional network of :mod:`.fcn`), ``crop`` (width, height), ``architecture``
  (both networks, or the FCN's), ``encoding`` and ``geodesic`` constants (patch kind) or
  ``max_sigma_mm`` (fcn kind),
  ``package_version``, ``code_revision``, ``training_data_digest``, ``created_utc``,
  ``array_digest`` (SHA-256 over every other array) and free-form ``extra`` provenance;
* ``calibration/<name>``: :meth:`IntrinsicCalibration.to_arrays`;
* ``range_net/<param>`` and ``boundary_nets/<param>``: the networks' state dicts (patch kind);
  ``fcn/<param>``: the network's (fcn kind).

Every way a file can be wrong (missing, not a zip, truncated, bit-flipped, other format or version,
arrays that do not fit the declared architecture, another crop) raises :class:`WeightsError`
saying what was expected and what was found.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import json
import os
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .. import __version__
from ..atomic_file import write_atomically
from ..calibration.intrinsic import IntrinsicCalibration
from ..errors import TofMpdError, WeightsError
from ..npz_file import read_npz
from .encoding import EncodingConfig
from .fcn import FCNArchitecture, FCNCorrectionModel, ResidualFCN
from .networks import BoundaryNets, RangeRecoveryNet
from .pipeline import CorrectionModel, GeodesicParams

FORMAT = "tof_mpd_ros.correction_model"
FORMAT_VERSION = 1
#: the model kinds a file can hold and the array prefixes each has
KINDS = {"patch": ("calibration/", "range_net/", "boundary_nets/"),
         "fcn": ("calibration/", "fcn/")}
AnyModel = CorrectionModel | FCNCorrectionModel


def code_revision() -> str:
    """``git describe --always --dirty`` of the source tree, or ``"unknown"`` outside git."""
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty"],
                             cwd=Path(__file__).resolve().parent, capture_output=True,
                             text=True, timeout=5, check=True)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() or "unknown"


def architecture(model: AnyModel) -> dict[str, Any]:
    """The networks' shapes as plain JSON data."""
    if isinstance(model, FCNCorrectionModel):
        return {"fcn": model.architecture.as_dict()}
    f, g = model.range_net, model.boundary_nets
    return {"range_net": {"n_features": f.n_features, "hidden": list(f.hidden),
                          "target_clip_mm": f.target_clip_mm},
            "boundary_nets": {"n_features": g.n_features, "hidden": list(g.hidden),
                              "n_heads": g.n_heads}}


def array_digest(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 over names, dtypes, shapes and bytes of ``arrays`` (sorted by name)."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _networks(model: AnyModel) -> tuple[tuple[str, torch.nn.Module], ...]:
    """(array prefix, network) of each network of ``model``."""
    if isinstance(model, FCNCorrectionModel):
        return (("fcn/", model.net),)
    return (("range_net/", model.range_net), ("boundary_nets/", model.boundary_nets))


def _kind_metadata(model: AnyModel) -> dict[str, Any]:
    """The metadata entries that depend on the model's kind."""
    if isinstance(model, FCNCorrectionModel):
        return {"max_sigma_mm": model.max_sigma_mm}
    return {"encoding": model.encoding.as_dict(), "geodesic": dataclasses.asdict(model.geodesic)}


def _model_arrays(model: AnyModel) -> dict[str, np.ndarray]:
    arrays = {f"calibration/{k}": v for k, v in model.calibration.to_arrays().items()}
    for prefix, net in _networks(model):
        for k, v in net.state_dict().items():
            arrays[prefix + k] = v.detach().to("cpu", torch.float32).numpy()
    return arrays


def save_weights(path: str | os.PathLike[str], model: AnyModel, *,
                 training_data_digest: str = "", overwrite: bool = False) -> Path:
    """Write ``model`` to one ``.npz`` file atomically (temporary file, then rename).

    Args:
        path: destination file.
        model: the model to save (either kind); ``model.metadata`` is stored under ``extra``
            (must be JSON).
        training_data_digest: digest of the data the networks were trained on.
        overwrite: replace an existing file (refused by default).

    Returns:
        The path written.

    Raises:
        WeightsError: the file exists and ``overwrite`` is False, metadata is not JSON, or the
            write fails.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise WeightsError(f"weights file {path} exists; pass overwrite=True to replace it")
    arrays = _model_arrays(model)
    h, w = model.shape
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": model.kind,
            "crop": {"width": w, "height": h}, "architecture": architecture(model),
            **_kind_metadata(model),
            "package_version": __version__, "code_revision": code_revision(),
            "training_data_digest": training_data_digest
            or str(model.metadata.get("training_data_digest", "")),
            "created_utc": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
            "array_digest": array_digest(arrays), "extra": model.metadata}
    try:
        arrays["metadata"] = np.array(json.dumps(meta, sort_keys=True))
    except (TypeError, ValueError) as err:
        raise WeightsError(f"model.metadata must be JSON-serialisable: {err}") from err
    try:
        return write_atomically(path, lambda stream: np.savez(stream, **arrays))
    except OSError as err:
        raise WeightsError(f"cannot write weights file {path}: {err}") from err


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    """Every array of the npz, without pickle; any read failure becomes a WeightsError."""
    if not path.is_file():
        raise WeightsError(f"weights file not found: {path}")
    return read_npz(path, WeightsError, f"weights file (expected a {FORMAT} .npz; truncated "
                    "or corrupt?)")


def _read_metadata(path: Path, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    if "metadata" not in arrays:
        raise WeightsError(f"{path} has no 'metadata' entry; expected a {FORMAT} file")
    try:
        meta = json.loads(str(arrays.pop("metadata")))
    except (json.JSONDecodeError, TypeError, RecursionError) as err:  # deep nesting: recursion
        raise WeightsError(f"{path}: metadata is not valid JSON: {err}") from err
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        found = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise WeightsError(f"{path}: expected format {FORMAT!r}, found {found!r}")
    if meta.get("format_version") != FORMAT_VERSION:
        raise WeightsError(f"{path}: format version {meta.get('format_version')!r} is not "
                           f"supported by this code (expects {FORMAT_VERSION}); "
                           f"written by tof_mpd_ros {meta.get('package_version', '?')}")
    if meta.get("array_digest") != array_digest(arrays):
        raise WeightsError(f"{path}: array contents do not match the stored digest (corrupt "
                           "or edited file)")
    return meta


def _sub(arrays: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    return {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}


def _net(path: Path, cls: type[torch.nn.Module], args: tuple[Any, ...],
         params: dict[str, np.ndarray], name: str) -> torch.nn.Module:
    """Network ``cls(*args)`` holding ``params``, built only once the file's arrays have the
    shapes the declared architecture gives and finite values. The shapes are taken from a
    network on the meta device, which allocates nothing: a declared width of 10^6 would
    otherwise allocate terabytes before any comparison."""
    try:
        with torch.device("meta"):
            expected = {k: tuple(v.shape) for k, v in cls(*args).state_dict().items()}
    except (TypeError, ValueError, RuntimeError, TofMpdError) as err:
        raise WeightsError(f"{path}: {name} architecture {args} cannot be built: "
                           f"{type(err).__name__}: {err}") from err
    found = {k: tuple(v.shape) for k, v in params.items()}
    if expected != found:
        diff = sorted(set(expected.items()) ^ set(found.items()))
        raise WeightsError(f"{path}: {name} parameters do not match its declared architecture; "
                           f"expected {expected}, found {found} (differences: {diff})")
    for key, value in params.items():
        if value.dtype.kind not in "fiu" or not np.isfinite(value).all():
            raise WeightsError(f"{path}: {name} parameter {key} must hold finite real numbers "
                               f"(dtype {value.dtype})")
    net = cls(*args)
    net.load_state_dict({k: torch.from_numpy(np.array(v, np.float32)) for k, v in params.items()})
    return net


def _extra(path: Path, meta: dict[str, Any]) -> dict[str, Any]:
    extra = meta.get("extra", {})
    if not isinstance(extra, dict):
        raise WeightsError(f"{path}: metadata 'extra' is a {type(extra).__name__}, not an object")
    return dict(extra)


def _check_crop(path: Path, meta: dict[str, Any], shape: tuple[int, int]) -> None:
    crop = meta.get("crop")
    if not isinstance(crop, dict) or (crop.get("height"), crop.get("width")) != shape:
        raise WeightsError(f"{path}: metadata crop {crop} disagrees with the calibration's "
                           f"{shape[1]}x{shape[0]}")


def _build_fcn(path: Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]
               ) -> FCNCorrectionModel:
    try:
        arch = FCNArchitecture(**{**meta["architecture"]["fcn"],
                                  "widths": tuple(meta["architecture"]["fcn"]["widths"])})
        max_sigma = float(meta["max_sigma_mm"])
        calibration = IntrinsicCalibration.from_arrays(_sub(arrays, "calibration/"))
    except (KeyError, TypeError, ValueError, TofMpdError) as err:
        raise WeightsError(f"{path}: malformed metadata or calibration: "
                           f"{type(err).__name__}: {err}") from err
    net = _net(path, ResidualFCN, (arch,), _sub(arrays, "fcn/"), "fcn")
    try:
        model = FCNCorrectionModel(calibration, net, max_sigma, _extra(path, meta))
    except TofMpdError as err:
        raise WeightsError(f"{path}: {err}") from err
    _check_crop(path, meta, model.shape)
    return model


def _build(path: Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> CorrectionModel:
    try:
        arch = meta["architecture"]
        encoding = EncodingConfig(**meta["encoding"])
        geodesic = GeodesicParams(**meta["geodesic"])
        f_arch, g_arch = arch["range_net"], arch["boundary_nets"]
        f_args = (int(f_arch["n_features"]), tuple(f_arch["hidden"]),
                  float(f_arch["target_clip_mm"]))
        g_args = (int(g_arch["n_features"]), tuple(g_arch["hidden"]), int(g_arch["n_heads"]))
        calibration = IntrinsicCalibration.from_arrays(_sub(arrays, "calibration/"))
    except (KeyError, TypeError, ValueError, TofMpdError) as err:
        raise WeightsError(f"{path}: malformed metadata or calibration: "
                           f"{type(err).__name__}: {err}") from err
    f = _net(path, RangeRecoveryNet, f_args, _sub(arrays, "range_net/"), "range_net")
    g = _net(path, BoundaryNets, g_args, _sub(arrays, "boundary_nets/"), "boundary_nets")
    try:
        model = CorrectionModel(calibration, encoding, f, g, geodesic, _extra(path, meta))
    except TofMpdError as err:
        raise WeightsError(f"{path}: networks do not fit the encoding: {err}") from err
    _check_crop(path, meta, model.shape)
    return model


def load_weights(path: str | os.PathLike[str], *,
                 expected_shape: tuple[int, int] | None = None) -> AnyModel:
    """Read a weights file written by :func:`save_weights`.

    Args:
        path: the ``.npz`` file.
        expected_shape: ``(H, W)`` of the frames it will correct; another crop is an error.

    Returns:
        The model of the file's kind: a :class:`CorrectionModel` (``"patch"``) or an
        :class:`~.fcn.FCNCorrectionModel` (``"fcn"``), on the CPU in float32; ``metadata``
        holds the stored ``extra`` plus the file's provenance under ``"file"``.

    Raises:
        WeightsError: missing, corrupt, truncated, other format/version, unknown kind, wrong
            architecture, or a crop other than ``expected_shape``.
    """
    path = Path(path)
    arrays = _read_arrays(path)
    meta = _read_metadata(path, arrays)
    kind = meta.get("kind", "patch")
    if kind not in KINDS:
        raise WeightsError(f"{path}: model kind {kind!r} is not one this code knows "
                           f"({', '.join(KINDS)})")
    unknown = [k for k in arrays if not k.startswith(KINDS[kind])]
    if unknown:
        raise WeightsError(f"{path}: unexpected entries for a {kind!r} model: {unknown}")
    model = (_build_fcn if kind == "fcn" else _build)(path, meta, arrays)
    if expected_shape is not None and tuple(expected_shape) != model.shape:
        h, w = model.shape
        raise WeightsError(f"{path}: weights are for a {w}x{h} (W x H) crop, expected "
                           f"{expected_shape[1]}x{expected_shape[0]}")
    model.metadata["file"] = {k: v for k, v in meta.items() if k != "extra"}
    return model
