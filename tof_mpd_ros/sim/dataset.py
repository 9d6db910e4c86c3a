"""MD-Train / MD-Test-like datasets from the simulated cell (docs/method.md, "Data and units";
the cell: docs/physics.md).

A dataset directory holds three recordings (rosbag2 MCAP) and a summary:

* ``md_train/`` — ``n_train_scenes`` scenes of *train* library objects x 18 viewpoints;
* ``md_test/`` — ``n_test_scenes`` scenes of the disjoint *test* objects x 18 viewpoints;
* ``calibration/`` — graded-checkerboard captures for the per-pixel calibration;
* ``dataset.json`` — the spec, the renderer, per-frame scene/view indices, rejected viewpoints
  and timings.

Every scene draws from its own generator ``default_rng([seed, split, scene])``, so scenes are
independent of each other and of the number of worker processes.

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
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..arm.viewpoints import ViewpointConfig
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


def _jobs(spec: DatasetSpec) -> list[tuple[str, int]]:
    return ([("train", i) for i in range(spec.n_train_scenes)]
            + [("test", i) for i in range(spec.n_test_scenes)])


def _run_job(job: tuple[str, int], spec: DatasetSpec, cell: SimCell | None) -> SceneCapture:
    return capture_scene(job[0], job[1], spec, cell)


def _run_calibration_chunk(chunk: tuple[int, int], spec: DatasetSpec,
                           cell: SimCell | None) -> SceneCapture:
    start = time.perf_counter()
    frames = capture_calibration(spec, cell, chunk=chunk)
    return SceneCapture("calibration", chunk[0], frames, [], [], time.perf_counter() - start)


def _init_worker(threads: int, pathtrace: bool = False) -> None:
    """Worker start-up: numba kernels (and the path tracer) use ``threads`` threads."""
    import numba

    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    if pathtrace:
        from .pathtrace.render import load_mitsuba

        load_mitsuba()
        import drjit

        drjit.set_thread_count(threads)


def iter_captures(spec: DatasetSpec, *, workers: int = 1,
                  cell: SimCell | None = None) -> Iterator[SceneCapture]:
    """Every scene (train, then test) and the calibration captures in chunks, in order.

    Args:
        spec: what to generate.
        workers: processes; 1 renders in this process.
        cell: the simulated cell (None = the nominal one).
    """
    chunks = [(i, min(i + 50, spec.n_calibration)) for i in range(0, spec.n_calibration, 50)]
    tasks: list[tuple[Callable, tuple]] = ([(_run_job, (job, spec, cell)) for job in _jobs(spec)]
                                           + [(_run_calibration_chunk, (c, spec, cell))
                                              for c in chunks])
    if workers <= 1:
        for fn, args in tasks:
            yield fn(*args)
        return
    # spawn, not fork: numba's threading layer in a parent that already rendered is not
    # fork-safe. The workers share the cores, so each runs its kernels on its share of them
    # rather than all of them (outputs do not depend on the thread count).
    threads = max(1, (os.cpu_count() or 1) // workers)
    pathtrace = cell is not None and cell.renderer == "pathtrace"
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                             initializer=_init_worker, initargs=(threads, pathtrace)) as pool:
        futures = [pool.submit(fn, *args) for fn, args in tasks]
        for future in futures:  # in submission order, so recordings are written in order
            yield future.result()


def renderer_summary(cell: SimCell | None) -> dict:
    """What rendered the scenes, for ``dataset.json``: name, material set and, for the path
    tracer, samples per pixel, depth, Russian-roulette depth and library versions."""
    cell = SimCell() if cell is None else cell
    out: dict = {"name": cell.renderer, "materials": cell.materials,
                 "calibration": "builtin"}
    if cell.renderer == "pathtrace":
        from .pathtrace.render import DATASET_RR_DEPTH, versions

        out.update({"spp": cell.pathtrace_spp, "max_depth": cell.pathtrace_max_depth,
                    "rr_depth": DATASET_RR_DEPTH, "versions": versions()})
    return out


def generate_dataset(out_dir: str | Path, spec: DatasetSpec, *, workers: int = 1,
                     compression: str = "zstd", progress: bool = True,
                     cell: SimCell | None = None) -> dict:
    """Render the dataset into ``out_dir`` (which must not exist yet).

    Returns:
        The summary written to ``dataset.json``.
    """
    from tqdm import tqdm

    from ..recordings.writer import RecordingWriter

    out = Path(out_dir)
    if out.exists():
        raise FileExistsError(f"{out} already exists")
    renderer = renderer_summary(cell)  # loads the path tracer first, if there is one
    out.mkdir(parents=True, exist_ok=False)
    names = {"train": "md_train", "test": "md_test", "calibration": "calibration"}
    writers = {split: RecordingWriter(out / name, compression=compression)
               for split, name in names.items()}
    summary: dict = {"spec": asdict(spec), "renderer": renderer,
                     "recordings": names, "scenes": [], "seconds": 0.0}
    total = spec.n_train_scenes + spec.n_test_scenes + -(-spec.n_calibration // 50)
    start = time.perf_counter()
    try:
        for writer in writers.values():
            writer.__enter__()
        with tqdm(total=total, desc="simulating cell", unit="scene", disable=not progress) as bar:
            for capture in iter_captures(spec, workers=workers, cell=cell):
                for frame in capture.frames:
                    writers[capture.split].write_frame(frame)
                if capture.split != "calibration":
                    summary["scenes"].append({
                        "split": capture.split, "scene": capture.scene,
                        "objects": capture.object_ids, "frames": len(capture.frames),
                        "first_stamp_ns": capture.frames[0].stamp_ns,
                        "rejected_views": capture.rejected_views,
                        "seconds": round(capture.seconds, 2)})
                bar.update(1)
    finally:
        for writer in writers.values():
            writer.__exit__(None, None, None)
    summary["seconds"] = round(time.perf_counter() - start, 1)
    summary["frames"] = {split: sum(s["frames"] for s in summary["scenes"]
                                    if s["split"] == split) for split in ("train", "test")}
    summary["frames"]["calibration"] = spec.n_calibration
    (out / "dataset.json").write_text(json.dumps(summary, indent=2))
    log.info("dataset written to %s in %.0f s", out, summary["seconds"])
    return summary
