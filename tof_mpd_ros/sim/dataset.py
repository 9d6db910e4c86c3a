"""MD-Train / MD-Test-like datasets from the simulated cell (docs/method.md, "Data and units";
the cell: docs/physics.md).

A dataset directory holds three recordings (rosbag2 MCAP) and a summary:

* ``md_train/`` — ``n_train_scenes`` scenes of *train* library objects x 18 viewpoints;
* ``md_test/`` — ``n_test_scenes`` scenes of the disjoint *test* objects x 18 viewpoints;
* ``calibration/`` — graded-checkerboard captures for the per-pixel calibration;
* ``dataset.json`` — the spec, the renderer, per-frame scene/view indices, rejected viewpoints
  and timings.

Every scene draws from its own generator ``default_rng([seed, split, scene])``, so scenes are
independent of each other and of the number of worker processes. That also lets a cluster fan
the work out: ``generate_dataset(..., shard=Shard(i, n))`` renders the i-th of n disjoint slices
(scenes and calibration chunks dealt round-robin), and :func:`merge_dataset` checks that the
slices make one complete dataset and writes it, the same frames as one unsharded run.

The cell's renderer (``SimCell.renderer``) picks the scenes' material set: a path-traced dataset
(``"pathtrace"``) draws the same objects at the same places as the built-in one of the same seed,
some of them glossy or metal (:mod:`.objects`). The path tracer's seed of each view is drawn from
``default_rng([seed, split, scene, view])`` (:func:`pathtrace_seed`), so a path-traced dataset is
reproducible too. Calibration captures are built-in for both renderers.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import os
import shutil
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..arm.viewpoints import ViewpointConfig
from ..errors import InputError
from ..frame import ToFFrame
from .cell import SimCell
from .checkerboard import calibration_poses
from .scene import make_scene
from .viewpoints import plan_viewpoints

log = logging.getLogger(__name__)

SPLIT_IDS = {"train": 1, "test": 2, "calibration": 3}
# One second between views of the collector, one hour between scenes: stamps order the frames.
VIEW_PERIOD_NS = 1_000_000_000
SCENE_PERIOD_NS = 3600 * VIEW_PERIOD_NS
START_NS = 1_700_000_000 * 1_000_000_000


@dataclass(frozen=True)
class DatasetSpec:
    """What to generate.

    Attributes:
        n_train_scenes: scenes of train objects (the paper: 30).
        n_test_scenes: scenes of test objects (the paper: 20).
        views_per_scene: viewpoints per scene (the paper: 18).
        n_calibration: checkerboard captures (the paper: 770).
        seed: master seed.
    """

    n_train_scenes: int = 30
    n_test_scenes: int = 20
    views_per_scene: int = 18
    n_calibration: int = 770
    seed: int = 0

    @classmethod
    def small(cls, seed: int = 0) -> DatasetSpec:
        """A few minutes' worth, for tests and the demo."""
        return cls(n_train_scenes=4, n_test_scenes=2, views_per_scene=6, n_calibration=120,
                   seed=seed)


@dataclass
class SceneCapture:
    """The frames of one scene and what was planned for it."""

    split: str
    scene: int
    frames: list[ToFFrame]
    object_ids: list[int]
    rejected_views: list[tuple[int, str]] = field(default_factory=list)
    seconds: float = 0.0


def scene_rng(seed: int, split: str, scene: int) -> np.random.Generator:
    return np.random.default_rng([seed, SPLIT_IDS[split], scene])


def pathtrace_seed(seed: int, split: str, scene: int, view: int) -> int:
    """The path tracer's seed in [0, 65536) of one view of one scene (a pure function)."""
    return int(np.random.default_rng([seed, SPLIT_IDS[split], scene, view]).integers(1 << 16))


def capture_scene(split: str, scene_index: int, spec: DatasetSpec,
                  cell: SimCell | None = None) -> SceneCapture:
    """Build one scene, plan its views and capture every view with its SL reference."""
    start = time.perf_counter()
    cell = SimCell() if cell is None else cell
    rng = scene_rng(spec.seed, split, scene_index)
    scene = make_scene(split, rng, materials=cell.materials)
    n_bands = 3 if spec.views_per_scene % 3 == 0 else 1
    plan = plan_viewpoints(scene, rng, ViewpointConfig(n_views=spec.views_per_scene,
                                                       n_height_bands=n_bands))
    base_ns = START_NS + SPLIT_IDS[split] * 100 * SCENE_PERIOD_NS + scene_index * SCENE_PERIOD_NS
    frames = [cell.capture(scene, view.camera_to_base_mm, rng, frame_index=view.index,
                           stamp_ns=base_ns + view.index * VIEW_PERIOD_NS,
                           pathtrace_seed=pathtrace_seed(spec.seed, split, scene_index,
                                                         view.index))
              for view in plan.viewpoints]
    return SceneCapture(split, scene_index, frames,
                        [o.spec.library_id for o in scene.objects],
                        [(int(c), str(r)) for c, r in plan.rejected],
                        time.perf_counter() - start)


def capture_calibration(spec: DatasetSpec, cell: SimCell | None = None,
                        chunk: tuple[int, int] | None = None) -> list[ToFFrame]:
    """Checkerboard captures ``chunk = (start, stop)`` of ``spec.n_calibration`` (all: None)."""
    cell = SimCell() if cell is None else cell
    rng = scene_rng(spec.seed, "calibration", 0)
    poses = calibration_poses(spec.n_calibration, rng)
    start, stop = chunk if chunk is not None else (0, spec.n_calibration)
    base_ns = START_NS + SPLIT_IDS["calibration"] * 100 * SCENE_PERIOD_NS
    return [cell.capture_checkerboard(poses[i], np.random.default_rng([spec.seed, 99, i]),
                                      frame_index=i, stamp_ns=base_ns + i * VIEW_PERIOD_NS)
            for i in range(start, stop)]


#: checkerboard captures rendered per task
CALIBRATION_CHUNK = 50


@dataclass(frozen=True)
class Shard:
    """Slice ``index`` of ``count`` of a dataset's tasks (0-based): every ``count``-th task from
    the ``index``-th, so each slice gets a share of train and test scenes and calibration."""

    index: int = 0
    count: int = 1

    def __post_init__(self) -> None:
        if not 0 <= self.index < self.count:
            raise ValueError(f"shard {self.index}/{self.count}: need 0 <= I < N")

    @classmethod
    def parse(cls, text: str) -> Shard:
        """``"I/N"`` -> ``Shard(I, N)``."""
        try:
            index, count = (int(x) for x in text.split("/"))
        except ValueError:
            raise ValueError(f"shard {text!r}: expected I/N, e.g. 0/4") from None
        return cls(index, count)

    def take(self, tasks: list[tuple[str, int]]) -> list[tuple[str, int]]:
        return tasks[self.index::self.count]


def dataset_tasks(spec: DatasetSpec) -> list[tuple[str, int]]:
    """Every task of ``spec`` in order: ``(split, scene)`` for the scenes, then
    ``("calibration", first capture)`` per chunk of ``CALIBRATION_CHUNK`` captures."""
    return ([("train", i) for i in range(spec.n_train_scenes)]
            + [("test", i) for i in range(spec.n_test_scenes)]
            + [("calibration", i) for i in range(0, spec.n_calibration, CALIBRATION_CHUNK)])


def _run_task(task: tuple[str, int], spec: DatasetSpec, cell: SimCell | None) -> SceneCapture:
    split, index = task
    if split != "calibration":
        return capture_scene(split, index, spec, cell)
    start = time.perf_counter()
    chunk = (index, min(index + CALIBRATION_CHUNK, spec.n_calibration))
    frames = capture_calibration(spec, cell, chunk=chunk)
    return SceneCapture("calibration", index, frames, [], [], time.perf_counter() - start)


def _init_worker(threads: int, pathtrace: bool = False) -> None:
    """Worker start-up: numba kernels (and the path tracer) use ``threads`` threads."""
    import numba

    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    if pathtrace:
        from .pathtrace.render import load_mitsuba

        load_mitsuba()
        import drjit

        drjit.set_thread_count(threads)


def iter_captures(spec: DatasetSpec, *, workers: int = 1, cell: SimCell | None = None,
                  shard: Shard = Shard()) -> Iterator[SceneCapture]:
    """Every scene (train, then test) and the calibration captures in chunks, in order
    (:func:`dataset_tasks`; of ``shard``'s slice only).

    Args:
        spec: what to generate.
        workers: processes; 1 renders in this process.
        cell: the simulated cell (None = the nominal one).
        shard: the slice of the tasks to run (default all).
    """
    tasks = shard.take(dataset_tasks(spec))
    if workers <= 1:
        for task in tasks:
            yield _run_task(task, spec, cell)
        return
    # spawn, not fork: numba's threading layer in a parent that already rendered is not
    # fork-safe. The workers share the cores, so each runs its kernels on its share of them
    # rather than all of them (outputs do not depend on the thread count).
    threads = max(1, (os.cpu_count() or 1) // workers)
    pathtrace = cell is not None and cell.renderer == "pathtrace"
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                             initializer=_init_worker, initargs=(threads, pathtrace)) as pool:
        futures = [pool.submit(_run_task, task, spec, cell) for task in tasks]
        for future in futures:  # in submission order, so recordings are written in order
            yield future.result()


def renderer_summary(cell: SimCell | None) -> dict:
    """What rendered the scenes, for ``dataset.json``: name, material set, the recorded crop
    (width, height) and, for the path
    tracer, samples per pixel, depth, Russian-roulette depth and library versions."""
    cell = SimCell() if cell is None else cell
    out: dict = {"name": cell.renderer, "materials": cell.materials,
                 "calibration": "builtin", "crop": list(cell.camera.crop)}
    if cell.renderer == "pathtrace":
        from .pathtrace.render import DATASET_RR_DEPTH, versions

        out.update({"spp": cell.pathtrace_spp, "max_depth": cell.pathtrace_max_depth,
                    "rr_depth": DATASET_RR_DEPTH, "versions": versions()})
    return out


def generate_dataset(out_dir: str | Path, spec: DatasetSpec, *, workers: int = 1,
                     compression: str = "zstd", progress: bool = True,
                     cell: SimCell | None = None, shard: Shard | None = None) -> dict:
    """Render the dataset (or ``shard``'s slice of it) into ``out_dir`` (which must not exist
    yet). A shard's ``dataset.json`` names its slice and tasks, for :func:`merge_dataset`.

    Returns:
        The summary written to ``dataset.json``.
    """
    from tqdm import tqdm

    from ..recordings.writer import RecordingWriter

    out = Path(out_dir)
    if out.exists():
        raise FileExistsError(f"{out} already exists")
    renderer = renderer_summary(cell)  # loads the path tracer first, if there is one
    tasks = (shard or Shard()).take(dataset_tasks(spec))
    out.mkdir(parents=True, exist_ok=False)
    writers = {split: RecordingWriter(out / name, compression=compression)
               for split, name in RECORDINGS.items()}
    summary: dict = {"spec": asdict(spec), "renderer": renderer,
                     "recordings": dict(RECORDINGS), "scenes": [], "seconds": 0.0}
    if shard is not None:
        summary["shard"] = {"index": shard.index, "count": shard.count,
                            "tasks": [list(t) for t in tasks]}
    calibration_frames = 0
    start = time.perf_counter()
    try:
        for writer in writers.values():
            writer.__enter__()
        desc = "simulating cell" + (f" (shard {shard.index}/{shard.count})" if shard else "")
        with tqdm(total=len(tasks), desc=desc, unit="task", disable=not progress) as bar:
            for capture in iter_captures(spec, workers=workers, cell=cell,
                                         shard=shard or Shard()):
                for frame in capture.frames:
                    writers[capture.split].write_frame(frame)
                if capture.split == "calibration":
                    calibration_frames += len(capture.frames)
                else:
                    summary["scenes"].append(_scene_entry(capture))
                bar.update(1)
    finally:
        for writer in writers.values():
            writer.__exit__(None, None, None)
    summary["seconds"] = round(time.perf_counter() - start, 1)
    summary["frames"] = _frame_counts(summary["scenes"], calibration_frames)
    (out / "dataset.json").write_text(json.dumps(summary, indent=2))
    log.info("dataset written to %s in %.0f s", out, summary["seconds"])
    return summary


#: split -> recording directory of a dataset
RECORDINGS = {"train": "md_train", "test": "md_test", "calibration": "calibration"}


def _scene_entry(capture: SceneCapture) -> dict:
    return {"split": capture.split, "scene": capture.scene, "objects": capture.object_ids,
            "frames": len(capture.frames), "first_stamp_ns": capture.frames[0].stamp_ns,
            "rejected_views": capture.rejected_views, "seconds": round(capture.seconds, 2)}


def _frame_counts(scenes: Sequence[dict], calibration_frames: int) -> dict[str, int]:
    counts = {split: sum(s["frames"] for s in scenes if s["split"] == split)
              for split in ("train", "test")}
    counts["calibration"] = calibration_frames
    return counts


def merge_dataset(out_dir: str | Path, shard_dirs: Sequence[str | Path], *,
                  compression: str = "zstd") -> dict:
    """Check that ``shard_dirs`` (each written by ``generate_dataset(..., shard=...)``) make
    one complete dataset, and write it into ``out_dir``: the same recordings, message for
    message, as one unsharded run, and its ``dataset.json`` (``merged_from`` names the
    shards).

    Raises:
        InputError: a shard without its ``dataset.json`` (unfinished) or not a shard; shards
            of different specs, renderers or counts; a shard missing or given twice; a
            shard's tasks not its slice, or a scene of its slice missing.
        FileExistsError: ``out_dir`` exists.
    """
    from ..recordings.merge import merge_recordings

    out = Path(out_dir)
    if out.exists():
        raise FileExistsError(f"{out} already exists")
    shards = _read_shards(shard_dirs)
    first = shards[0][1]
    spec = DatasetSpec(**first["spec"])
    scenes = sorted((s for _, summary in shards for s in summary["scenes"]),
                    key=lambda s: (SPLIT_IDS[s["split"]], s["scene"]))
    frames = _frame_counts(scenes, spec.n_calibration)
    out.mkdir(parents=True)
    try:
        for split, name in RECORDINGS.items():
            log.info("merging %s of %d shards", name, len(shards))
            counts = merge_recordings(out / name, [path / name for path, _ in shards],
                                      compression=compression)
            # every frame writes one message per topic
            if max(counts.values(), default=0) != frames[split]:
                raise InputError(f"the shards' {name} recordings hold "
                                 f"{max(counts.values(), default=0)} frames, their summaries "
                                 f"{frames[split]}")
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)  # no half-merged dataset is left behind
        raise
    summary = {"spec": asdict(spec), "renderer": first["renderer"],
               "recordings": dict(RECORDINGS), "scenes": scenes,
               "seconds": round(sum(sm["seconds"] for _, sm in shards), 1),
               "frames": frames, "merged_from": [{"path": str(path), "index": sm["shard"]["index"]}
                               for path, sm in shards]}
    (out / "dataset.json").write_text(json.dumps(summary, indent=2))
    return summary


def _read_shards(shard_dirs: Sequence[str | Path]) -> list[tuple[Path, dict]]:
    """The shards' summaries, in shard order, checked to make one complete dataset."""
    if not shard_dirs:
        raise InputError("nothing to merge: no shard directories given")
    shards = []
    for d in map(Path, shard_dirs):
        meta = d / "dataset.json"
        if not meta.is_file():
            raise InputError(f"{d}: no dataset.json (not a dataset, or its shard did not "
                             "finish)")
        summary = json.loads(meta.read_text())
        if "shard" not in summary:
            raise InputError(f"{d}: not a shard (made without --shard)")
        shards.append((d, summary))
    shards.sort(key=lambda x: x[1]["shard"]["index"])
    first = shards[0][1]
    count = first["shard"]["count"]
    for d, summary in shards:
        for key in ("spec", "renderer"):
            if summary[key] != first[key]:
                raise InputError(f"{d}: another {key} than {shards[0][0]}'s: not shards of "
                                 "one dataset")
        if summary["shard"]["count"] != count:
            raise InputError(f"{d}: shard of {summary['shard']['count']}, not of {count}")
    indices = [summary["shard"]["index"] for _, summary in shards]
    missing = sorted(set(range(count)) - set(indices))
    twice = sorted({i for i in indices if indices.count(i) > 1})
    if missing or twice:
        raise InputError(f"shards of {count}: missing {missing or 'none'}, given twice "
                         f"{twice or 'none'}")
    tasks = dataset_tasks(DatasetSpec(**first["spec"]))
    for d, summary in shards:
        expected = Shard(summary["shard"]["index"], count).take(tasks)
        if [tuple(t) for t in summary["shard"]["tasks"]] != expected:
            raise InputError(f"{d}: its tasks are not shard "
                             f"{summary['shard']['index']}/{count}'s slice")
        have = {(s["split"], s["scene"]) for s in summary["scenes"]}
        lost = [t for t in expected if t[0] != "calibration" and tuple(t) not in have]
        if lost:
            raise InputError(f"{d}: scenes {lost} of its slice are missing")
    return shards
