"""Dataset generation: recordings, disjoint objects, determinism."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from sim_helpers import small_camera

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.recordings import RecordingReader
from tof_mpd_ros.sim.cell import SimCell
from tof_mpd_ros.sim.dataset import (
    DatasetSpec,
    Shard,
    capture_scene,
    dataset_tasks,
    generate_dataset,
    iter_captures,
    merge_dataset,
)

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


def _frames(path: Path) -> list:
    with RecordingReader(path) as reader:
        return list(reader.frames())


@pytest.fixture(scope="module")
def shards(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """SPEC rendered as two shards: 0/2 = train 0 + test 0 (no calibration), 1/2 = train 1 +
    the calibration chunk."""
    root = tmp_path_factory.mktemp("shards")
    out = []
    for i in range(2):
        generate_dataset(root / str(i), SPEC, cell=SimCell(camera=small_camera()),
                         progress=False, shard=Shard(i, 2))
        out.append(root / str(i))
    return out


def test_shards_are_disjoint_slices(shards: list[Path]) -> None:
    first, second = (json.loads((s / "dataset.json").read_text()) for s in shards)
    assert first["shard"]["tasks"] == [["train", 0], ["test", 0]]
    assert second["shard"]["tasks"] == [["train", 1], ["calibration", 0]]
    assert first["frames"] == {"train": 3, "test": 3, "calibration": 0}
    assert second["frames"] == {"train": 3, "test": 0, "calibration": 4}
    assert dataset_tasks(SPEC) == sorted(
        [tuple(t) for s in (first, second) for t in s["shard"]["tasks"]],
        key=dataset_tasks(SPEC).index)


def test_merged_shards_are_the_unsharded_dataset(dataset: Path, shards: list[Path],
                                                 tmp_path: Path) -> None:
    """Merged (given in any order), the shards hold the very frames of one unsharded run, in
    its order, bit for bit, and the same scenes in dataset.json."""
    merged = tmp_path / "merged"
    summary = merge_dataset(merged, list(reversed(shards)))
    whole = json.loads((dataset / "dataset.json").read_text())
    assert summary["frames"] == whole["frames"] == {"train": 6, "test": 3, "calibration": 4}
    assert [m["index"] for m in summary["merged_from"]] == [0, 1]

    def scenes(d):
        return [{k: v for k, v in s.items() if k != "seconds"} for s in d["scenes"]]

    assert scenes(summary) == scenes(whole)
    for name in ("md_train", "md_test", "calibration"):
        ours, theirs = _frames(merged / name), _frames(dataset / name)
        assert [f.stamp_ns for f in ours] == [f.stamp_ns for f in theirs]
        for a, b in zip(ours, theirs, strict=True):
            for field in ("range_mm", "amplitude", "reference_mm", "pose"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
            assert a.intrinsics == b.intrinsics and a.mod_freq_hz == b.mod_freq_hz


def test_merge_refuses_what_is_not_one_complete_dataset(dataset: Path, shards: list[Path],
                                                        tmp_path: Path) -> None:
    out = tmp_path / "merged"
    cases = {
        "missing [1]": [shards[0]],
        "given twice [0]": [shards[0], shards[0], shards[1]],
        "not a shard": [dataset, *shards],
        "no dataset.json": [tmp_path, *shards],
    }
    for words, dirs in cases.items():
        with pytest.raises(InputError, match=re.escape(words)):
            merge_dataset(out, dirs)
        assert not out.exists()
    # a shard of another seed
    other = tmp_path / "other"
    generate_dataset(other, DatasetSpec(**{**SPEC.__dict__, "seed": 6}),
                     cell=SimCell(camera=small_camera()), progress=False, shard=Shard(1, 2))
    with pytest.raises(InputError, match="another spec"):
        merge_dataset(out, [shards[0], other])
    assert not out.exists()


def test_shard_parsing() -> None:
    assert Shard.parse("3/4") == Shard(3, 4)
    for bad in ("4/4", "-1/2", "1/0", "one/two", "1"):
        with pytest.raises(ValueError, match="shard"):
            Shard.parse(bad)
    tasks = [("train", i) for i in range(7)]
    slices = [Shard(i, 3).take(tasks) for i in range(3)]
    assert sorted(t for s in slices for t in s) == tasks
