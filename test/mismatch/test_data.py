"""Frames, motion from poses and stamps, and the train / held-out split."""

from __future__ import annotations

import numpy as np
import pytest

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.errors import MismatchError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.mismatch.data import camera_motion, check_frames, split_frames

K = Intrinsics.from_fov(16, 12, 74.0)


def _frame(t_s: float, x_m: float, reference: bool = True) -> ToFFrame:
    pose = np.eye(4)
    pose[:3, :3] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]  # camera x = base y, z = base x
    pose[1, 3] = x_m
    img = np.full(K.shape, 300.0)
    return ToFFrame(img, img, K, reference_mm=img if reference else None,
                    stamp_ns=round(t_s * 1e9), pose=pose)


def test_motion_in_camera_frame_from_poses_and_stamps():
    frames = [_frame(0.1 * i, 0.01 * i) for i in range(4)]  # 100 mm/s along base y
    motion = camera_motion(frames)
    np.testing.assert_allclose(motion[1].linear_mm_s, (100.0, 0.0, 0.0), atol=1e-6)
    np.testing.assert_allclose(motion[1].angular_rad_s, 0.0, atol=1e-9)


def test_far_apart_frames_are_at_rest():
    frames = [_frame(2.0 * i, 0.01 * i) for i in range(3)]
    assert camera_motion(frames) == [None, None, None]


def test_split_alternates_frames_and_tiles_a_single_frame():
    frames = [_frame(0.1 * i, 0.0) for i in range(4)]
    split = split_frames(frames)
    assert [m.all() for m in split.train] == [True, False, True, False]
    single = split_frames(frames[:1])
    assert single.how == "tiles"
    assert (single.train[0] ^ single.test[0]).all() and 0.4 < single.train[0].mean() < 0.6


def test_frames_without_reference_are_refused():
    with pytest.raises(MismatchError, match="no reference"):
        check_frames([_frame(0.0, 0.0, reference=False)])
    with pytest.raises(MismatchError, match="no frames"):
        check_frames([])
