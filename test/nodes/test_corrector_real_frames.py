"""The corrector node on a second real camera: the Analog Devices ToF office frames
(``data/realdata/adi_tof_office``: 512x512, modes 2 and 3; docs/real_cameras.md).

One corrector process (the shipped weights, ``input_convention:=radial``: the ADI depth is radial
range) receives each mode as a camera driver publishes it: 16UC1 depth in mm (0 = invalid; pixels
of confidence above 4 set to 0, as docs/real_cameras.md asks), mono16 active brightness and a
CameraInfo of the assumed 75° centred pinhole, all stamped alike; mode 3 once more as 32FC1
metres with NaN. The node is given the paper's central 180x140 window (``crop_width`` /
``crop_height``; the shipped weights cover the whole 320x240 sensor), so it crops: the output is
that window, with the window's CameraInfo.

The numbers asserted (measured on a Zen 4 machine; the bounds and why are beside each test):
the output equals the offline stream corrector (``DepthStreamCorrector``, the node's own
pipeline) within the 16UC1 rounding; a pixel is valid out exactly when it was valid in with an
amplitude > 0; on the office's walls (realdata's plane reference) the correction is a few mm and
the walls stay planar. These frames have no ground truth: the checks are of plumbing, geometry
and magnitude, not of accuracy.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from ros_harness import domain_id, start_node, stop_node  # noqa: E402
from scipy.ndimage import binary_erosion  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from test_corrector_node import (  # noqa: E402
    OUTPUT,
    RELIABLE_DEEP,
    decoded,
    fields,
    first_round_trip,
    listener,
    node_count,
    send,
    wait_for_corrector,
)

from tof_mpd_ros.correction.default_weights import default_weights_path  # noqa: E402
from tof_mpd_ros.correction.depth_stream import (  # noqa: E402
    DepthStreamCorrector,
    decode_amplitude,
    decode_depth,
)
from tof_mpd_ros.correction.weights import load_weights  # noqa: E402
from tof_mpd_ros.mismatch import realdata  # noqa: E402
from tof_mpd_ros.nodes.ros_messages import (  # noqa: E402
    camera_info_message,
    image_message,
    intrinsics_of,
    stamp_ns,
)
from tof_mpd_ros.recordings.adi import adi_intrinsics  # noqa: E402

ADI_DOMAIN = domain_id(13)
FRAME_ID = "adi_tof_optical_frame"
WINDOW = (140, 180)  # (H, W) of the shipped weights: the node's central window
TOP, LEFT = (512 - 140) // 2, (512 - 180) // 2  # 186, 166
MAX_CONFIDENCE = realdata.ADI_MAX_CONFIDENCE  # 4: docs/real_cameras.md
# The inputs the node gets: (mode, depth encoding), in the order they are sent.
INPUTS = ((2, "16UC1"), (3, "16UC1"), (3, "32FC1"))
IDS = [f"mode{m}-{e}" for m, e in INPUTS]
# The three input subscriptions reliable, through the standard QoS overrides: a 512x512 frame is
# 0.5 MB, and best effort loses fragments of frames this large on a busy host (a lost amplitude
# image would be counted as a drop). The outputs are reliable by default.
RELIABLE_INPUTS = {f"qos_overrides./tof/{topic}.subscription.reliability": "reliable"
                   for topic in ("depth/image_raw", "amplitude/image_raw", "depth/camera_info")}
# Walls: crop pixels whose input point lies within this of one of realdata's planes, eroded by
# WALL_ERODE_PX (away from the arm's silhouette and the panels' edges), with WALL_MIN_PX left.
WALL_MM, WALL_ERODE_PX, WALL_MIN_PX = 30.0, 3, 1000


@dataclass
class AdiRun:
    """What one corrector process made of the inputs: per input, the messages sent and the
    output received; the diagnostics after the last; the exit code and log."""

    sent: dict[tuple[int, str], tuple[Image, Image, CameraInfo]] = field(default_factory=dict)
    stamps: dict[tuple[int, str], int] = field(default_factory=dict)
    images: dict[int, Image] = field(default_factory=dict)
    infos: dict[int, CameraInfo] = field(default_factory=dict)
    n_sent: int = 0
    values: dict[str, str] = field(default_factory=dict)
    exit_code: int | None = None
    log: str = ""

    def output(self, key: tuple[int, str]) -> tuple[Image, CameraInfo]:
        return self.images[self.stamps[key]], self.infos[self.stamps[key]]


def adi_messages(adi_dir: Path, mode: int, encoding: str) -> tuple[Image, Image, CameraInfo]:
    """One mode as a driver would publish it: depth (0 / NaN where the depth is 0 or the
    confidence above MAX_CONFIDENCE), mono16 amplitude, the assumed pinhole's CameraInfo."""
    depth = np.load(adi_dir / f"depth_mode{mode}.npy")
    amplitude = np.load(adi_dir / f"amplitude_mode{mode}.npy")
    confidence = np.load(adi_dir / f"confidence_mode{mode}.npy")
    assert depth.shape == (512, 512) and depth.dtype == amplitude.dtype == np.uint16
    depth = np.where(confidence <= MAX_CONFIDENCE, depth, 0).astype(np.uint16)
    if encoding == "32FC1":
        depth = np.where(depth > 0, depth / np.float32(1000.0), np.nan).astype(np.float32)
    return (image_message(depth, encoding, FRAME_ID), image_message(amplitude, "mono16", FRAME_ID),
            camera_info_message(adi_intrinsics(), FRAME_ID))


@pytest.fixture(scope="module")
def adi_run(adi_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> AdiRun:
    """The corrector with the shipped weights, radial input, in namespace /tof; each input of
    INPUTS sent until it came back (the first: until discovery is done), then the node's
    counters after the last and a clean stop."""
    log = tmp_path_factory.mktemp("adi_node") / "corrector.log"
    run = AdiRun()
    process = start_node("corrector", {"input_convention": "radial", "crop_width": 180,
                                       "crop_height": 140, "diagnostics_period_s": 0.25,
                                       **RELIABLE_INPUTS},
                         ADI_DOMAIN, log, remap=("__ns:=/tof",))
    try:
        with listener(ADI_DOMAIN) as lis:
            node = lis.node
            base = OUTPUT.rsplit("/", 1)[0]
            node.create_subscription(Image, OUTPUT,
                                     lambda m: run.images.__setitem__(stamp_ns(m), m),
                                     RELIABLE_DEEP)
            node.create_subscription(CameraInfo, f"{base}/camera_info",
                                     lambda m: run.infos.__setitem__(stamp_ns(m), m),
                                     RELIABLE_DEEP)
            pubs = [node.create_publisher(kind, topic, RELIABLE_DEEP) for kind, topic in
                    ((Image, "/tof/depth/image_raw"), (Image, "/tof/amplitude/image_raw"),
                     (CameraInfo, "/tof/depth/camera_info"))]
            wait_for_corrector(lis, process, log)
            assert lis.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in pubs),
                                  120.0)

            def back(stamp: int) -> bool:
                return stamp in run.images and stamp in run.infos

            for i, key in enumerate(INPUTS):
                run.sent[key] = adi_messages(adi_dir, *key)
                if i == 0:  # until discovery is done both ways: one or more frames
                    stamps = first_round_trip(lis, pubs, run.sent[key], back, process, log)
                    run.stamps[key] = next(s for s in stamps if back(s))
                    run.n_sent += len(stamps)
                    continue
                # discovery is done and both ways are reliable: one frame is enough
                lis.spin_until(lambda: node_count(lis, "published") >= run.n_sent, 300.0)
                run.stamps[key] = time.time_ns()
                send(pubs, run.sent[key], run.stamps[key])
                run.n_sent += 1
                assert lis.spin_until(lambda k=key: back(run.stamps[k]), 300.0), \
                    (key, lis.latest_values(), log.read_text()[-3000:])
            # The node's counters after its last frame (two diagnostics periods).
            lis.spin_until(lambda: node_count(lis, "published") >= run.n_sent, 60.0)
            n_diag = len(lis.diagnostics)
            lis.spin_until(lambda: len(lis.diagnostics) >= n_diag + 2, 60.0)
            run.values = lis.latest_values()
    finally:
        run.exit_code = stop_node(process)
        run.log = log.read_text()
    return run


@pytest.fixture(scope="module")
def offline() -> DepthStreamCorrector:
    """The node's pipeline in this process, with the shipped weights and radial input."""
    return DepthStreamCorrector(load_weights(default_weights_path()), input_convention="radial",
                                crop=(180, 140))


def window_of(msg: Image) -> np.ndarray:
    """(140, 180) float64 mm of the input depth's central window, NaN = invalid."""
    return decode_depth(*fields(msg))[TOP:TOP + WINDOW[0], LEFT:LEFT + WINDOW[1]].astype(
        np.float64)


def output_mm(msg: Image) -> np.ndarray:
    """(H, W) float64 mm of a corrected image, NaN = invalid (0 in 16UC1)."""
    return decode_depth(*fields(msg)).astype(np.float64)


def walls(adi_dir: Path, mode: int, raw_mm: np.ndarray) -> list[np.ndarray]:
    """(140, 180) bool masks of the window's walls: realdata's planes of this mode (fitted on
    the 128x128 block-reduced frame, away from creases), the window's input points within
    WALL_MM of one, eroded; those with at least WALL_MIN_PX pixels."""
    _, reference = realdata.load_adi(adi_dir, mode)
    window = adi_intrinsics().crop(WINDOW[1], WINDOW[0])
    points = window.backproject(raw_mm)
    with np.errstate(invalid="ignore"):
        distance = np.abs(points @ reference.planes[:, :3].T + reference.planes[:, 3])
    distance = np.where(np.isfinite(distance), distance, np.inf)
    nearest, which = distance.min(axis=-1), distance.argmin(axis=-1)
    masks = [binary_erosion((nearest < WALL_MM) & (which == p), iterations=WALL_ERODE_PX)
             for p in range(reference.planes.shape[0])]
    return [m for m in masks if m.sum() >= WALL_MIN_PX]


def plane_rms_mm(points: np.ndarray) -> float:
    """RMS distance in mm of (N, 3) points to their least-squares plane."""
    plane = realdata.fit_plane(points)
    return float(np.sqrt(np.mean((points @ plane[:3] + plane[3]) ** 2)))


# -- the process, its counters -----------------------------------------------------------------
def test_every_adi_frame_sent_was_corrected_with_no_drop(adi_run: AdiRun) -> None:
    assert adi_run.exit_code == 0, adi_run.log[-3000:]
    assert adi_run.values["dropped_total"] == "0", adi_run.values
    assert int(adi_run.values["published"]) == adi_run.n_sent >= len(INPUTS), adi_run.values
    # the node says which window it processes
    assert "central 180x140 window, radial convention" in adi_run.log


# -- each output: header, encoding, size, CameraInfo -------------------------------------------
@pytest.mark.parametrize("key", INPUTS, ids=IDS)
def test_adi_output_keeps_the_header_and_has_the_windows_camera_info(
        adi_run: AdiRun, key: tuple[int, str]) -> None:
    out, info = adi_run.output(key)
    depth_in, _, info_in = adi_run.sent[key]
    assert (out.encoding, out.height, out.width) == (key[1], *WINDOW)  # encoding "input"
    for msg in (out, info):
        assert stamp_ns(msg) == adi_run.stamps[key] and msg.header.frame_id == FRAME_ID
    assert (depth_in.width, depth_in.height) == (512, 512)
    # The window's CameraInfo: principal point shifted by the crop's offset, focal kept.
    assert (info.width, info.height) == (WINDOW[1], WINDOW[0])
    np.testing.assert_allclose([info.k[0], info.k[2], info.k[4], info.k[5]],
                               [info_in.k[0], info_in.k[2] - LEFT, info_in.k[4],
                                info_in.k[5] - TOP])
    np.testing.assert_allclose([info.k[0], info.k[2], info.k[5]], [333.6257, 89.5, 69.5],
                               atol=1e-4)
    assert info.distortion_model == "plumb_bob" and not any(info.d)


# -- each output: validity and equality with the offline pipeline ------------------------------
@pytest.mark.parametrize("key", INPUTS, ids=IDS)
def test_adi_invalid_pixels_stay_invalid_and_valid_ones_valid(adi_run: AdiRun,
                                                                key: tuple[int, str]) -> None:
    """Valid out exactly where the input window is valid and its amplitude > 0 (the method
    needs an amplitude: mode 2 reads 0 at 1.5 % of its window's valid pixels). Invalid is 0 in
    16UC1, NaN in 32FC1."""
    out, _ = adi_run.output(key)
    depth_in, amplitude_in, _ = adi_run.sent[key]
    raw = window_of(depth_in)
    amplitude = decoded(amplitude_in)[TOP:TOP + WINDOW[0], LEFT:LEFT + WINDOW[1]]
    valid_in = np.isfinite(raw) & (amplitude > 0)
    values = decoded(out)
    valid_out = values > 0 if key[1] == "16UC1" else np.isfinite(values)
    assert np.array_equal(valid_out, valid_in)
    if key[1] == "16UC1":
        assert not values[~valid_in].any()
    else:
        assert np.isnan(values[~valid_in]).all() and (values[valid_in] > 0).all()
    # confidence <= 4 keeps 87 % (mode 2) / 90 % (mode 3) of the window
    assert {2: 0.85, 3: 0.88}[key[0]] < valid_in.mean() < {2: 0.89, 3: 0.92}[key[0]]


@pytest.mark.parametrize("key", INPUTS, ids=IDS)
def test_adi_output_equals_the_offline_pipeline(adi_run: AdiRun, offline: DepthStreamCorrector,
                                                key: tuple[int, str]) -> None:
    """The node adds nothing and loses nothing: its output is ``DepthStreamCorrector`` run here
    on the same messages, within 16UC1's rounding to whole mm (float metres: 1e-3 mm)."""
    out, _ = adi_run.output(key)
    depth_in, amplitude_in, info_in = adi_run.sent[key]
    expected = offline.correct(decode_depth(*fields(depth_in)),
                               decode_amplitude(*fields(amplitude_in)),
                               intrinsics_of(info_in)).depth_mm
    got = output_mm(out)
    assert np.array_equal(np.isfinite(got), np.isfinite(expected))
    ok = np.isfinite(got)
    np.testing.assert_allclose(got[ok], expected[ok], atol=0.5001 if key[1] == "16UC1" else 1e-3)


# -- each mode: magnitude and geometry on the office's walls -----------------------------------
@pytest.mark.parametrize("mode", [2, 3])
def test_adi_correction_on_the_walls_is_a_few_millimetres(adi_run: AdiRun, adi_dir: Path,
                                                          mode: int) -> None:
    """|corrected − input| on the walls (panels ~2.1 m away, head-on, away from creases and the
    arm). Measured through the node (16UC1, whole mm), modes 2 / 3: median 4 / 5 mm, 95th
    percentile 11 / 9 mm, max 26 / 18 mm; over the whole window median 4 / 4 mm (the 99th
    percentile, 242 / 69 mm, lies on the arm's silhouette, where the geodesic filter moves mixed
    pixels to one side or the other).

    Multipath on a flat wall far from its creases is small, a few mm; what the shipped weights
    change here is mostly their per-pixel calibration, fitted for the simulated DS325 cell at
    0.2–0.35 m: its gain spread (c1 within ±1.7 %) applied at 2 m is a smooth pattern from
    about −8 mm at the window's top to +6 mm at its bottom (docs/real_cameras.md). Bounds:
    median < 8 mm, 95th percentile < 20 mm (1 % of the range), max < 50 mm: the camera's noise
    (RMS 2.6–4 mm about the walls' planes) plus that pattern, with room for a machine's
    rounding. A mm/m mix-up, or an output
    that is not the input's window, would be metres or tens of mm outside them.
    """
    out, _ = adi_run.output((mode, "16UC1"))
    raw = window_of(adi_run.sent[(mode, "16UC1")][0])
    corrected = output_mm(out)
    masks = walls(adi_dir, mode, raw)
    assert len(masks) >= 2  # the back panel and the panel beside it, in both modes
    on_walls = np.any(masks, axis=0) & np.isfinite(corrected)
    assert on_walls.mean() > 0.2  # mode 2: 22 %, mode 3: 46 % of the window
    change = np.abs(corrected - raw)[on_walls]
    assert np.median(change) < 8.0, np.median(change)
    assert np.percentile(change, 95) < 20.0, np.percentile(change, 95)
    assert change.max() < 50.0, change.max()
    # and over the whole window (the arm's silhouette included) the typical change is as small
    everywhere = np.isfinite(corrected)
    assert np.median(np.abs(corrected - raw)[everywhere]) < 8.0


@pytest.mark.parametrize("mode", [2, 3])
def test_adi_walls_stay_planar(adi_run: AdiRun, adi_dir: Path, mode: int) -> None:
    """Each wall's points, input and corrected, fitted with a plane: the corrected RMS at most
    2 mm above the input's. Measured (mode 2: back panel, side panel; mode 3: the same):
    input 4.03, 3.47; 2.60, 3.25 mm (the camera's noise at 2 m), corrected 3.41, 3.75; 2.92,
    4.64 mm. The largest increase, +1.4 mm on mode 3's side panel, is the shipped
    calibration's pattern (see the test above); the filtering flattens mode 2's noisier back
    panel (4.03 -> 3.41 mm). A geometry the node bent (a wrong window, a unit or encoding
    error) would add tens of mm."""
    out, _ = adi_run.output((mode, "16UC1"))
    raw = window_of(adi_run.sent[(mode, "16UC1")][0])
    corrected = output_mm(out)
    window = adi_intrinsics().crop(WINDOW[1], WINDOW[0])
    p_in, p_out = window.backproject(raw), window.backproject(corrected)
    for mask in walls(adi_dir, mode, raw):
        use = mask & np.isfinite(corrected)
        rms_in, rms_out = plane_rms_mm(p_in[use]), plane_rms_mm(p_out[use])
        assert rms_in < 6.0, rms_in  # a wall, not the arm
        assert rms_out <= rms_in + 2.0, (use.sum(), rms_in, rms_out)
