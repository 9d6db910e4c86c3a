"""Dataset generation: recordings, disjoint objects, determinism."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from sim_helpers import small_camera

from tof_mpd_ros.recordings import RecordingReader
from tof_mpd_ros.sim.cell import SimCell
from tof_mpd_ros.sim.dataset import DatasetSpec, capture_scene, generate_dataset, iter_captures

SPEC = DatasetSpec(n_train_scenes=2, n_test_scenes=1, views_per_scene=3, n_calibration=4,
                   seed=5)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ds") / "cell"
    generate_dataset(out, SPEC, cell=SimCell(camera=small_camera()), progress=False)
    return out


def test_layout_and_counts(dataset: Path) -> None:
    summary = json.loads((dataset / "dataset.json").read_text())
    assert summary["frames"] == {"train": 6, "test": 3, "calibration": 4}
    for name, count in (("md_train", 6), ("md_test", 3), ("calibration", 4)):
        assert (dataset / name / "metadata.yaml").is_file()
        with RecordingReader(dataset / name) as reader:
            frames = list(reader.frames())
        assert len(frames) == count
        assert all(f.reference_mm is not None for f in frames)
        stamps = [f.stamp_ns for f in frames]
        assert stamps == sorted(stamps) and len(set(stamps)) == count


def test_train_and_test_objects_are_disjoint(dataset: Path) -> None:
    scenes = json.loads((dataset / "dataset.json").read_text())["scenes"]
    train = {o for s in scenes if s["split"] == "train" for o in s["objects"]}
    test = {o for s in scenes if s["split"] == "test" for o in s["objects"]}
    assert train and test and not train & test


def test_recorded_frames_carry_camera_poses_above_the_table(dataset: Path) -> None:
    with RecordingReader(dataset / "md_train") as reader:
        poses = np.stack([f.pose for f in reader.frames()])
    heights_m = poses[:, 2, 3]
    assert np.all(heights_m > 0.18) and np.all(heights_m < 0.7)
    assert np.all(poses[:, 2, 2] < -0.8), "optical axes point down towards the table"


def test_scenes_are_deterministic_and_independent_of_order() -> None:
    cell = SimCell(camera=small_camera())
    a = capture_scene("test", 3, SPEC, cell)
    b = capture_scene("test", 3, SPEC, cell)
    np.testing.assert_array_equal(a.frames[0].range_mm, b.frames[0].range_mm)
    assert a.object_ids == b.object_ids


def test_existing_output_is_refused(dataset: Path) -> None:
    with pytest.raises(FileExistsError):
        generate_dataset(dataset, SPEC, progress=False)


def test_worker_processes_give_the_same_frames() -> None:
    spec = DatasetSpec(n_train_scenes=1, n_test_scenes=0, views_per_scene=2, n_calibration=2,
                       seed=3)
    cell = SimCell(camera=small_camera())
    serial = [f for c in iter_captures(spec, workers=1, cell=cell) for f in c.frames]
    pooled = [f for c in iter_captures(spec, workers=2, cell=cell) for f in c.frames]
    assert len(serial) == len(pooled) == 4
    for a, b in zip(serial, pooled, strict=True):
        np.testing.assert_array_equal(a.range_mm, b.range_mm)
        np.testing.assert_array_equal(a.reference_mm, b.reference_mm)
