"""``tof-mpd sim``: generate datasets from the simulated cell, predict ToF from references."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from ..errors import InputError, SimulationError
from .arguments import window_size
from .output import add_output

#: the one-line error when ``--renderer pathtrace`` cannot load the path tracer
PATHTRACE_MISSING = ("--renderer pathtrace needs the optional path tracer: pip install "
                     "'.[pathtrace]' (Mitsuba 3 + mitransient) and a system LLVM library "
                     "(Debian/Ubuntu: apt-get install libllvm19) [{reason}]")


def register(subparsers: argparse._SubParsersAction) -> None:
    sim = subparsers.add_parser("sim", help="simulated cell: datasets and predictions",
                                description="The simulated robotic ToF cell.")
    commands = sim.add_subparsers(dest="sim_command", metavar="SIM_COMMAND", required=True)

    _register_dataset(commands)
    _register_merge(commands)

    predict = commands.add_parser(
        "predict", help="predict the ToF measurement of each frame from its reference",
        description="For every frame of an NPZ or a recording, predict the ToF range and "
                    "amplitude from its reference range image (the geometry) with the simulated "
                    "camera, and write the same kind of file with the predicted measurement. "
                    "Light transport runs over the reference's surfaces, the support plane "
                    "extended across the light's cone and, for frames with poses, the surfaces "
                    "that other views of the same scene saw (--fuse-views). About 1-3 s per "
                    "180x140 frame.",
        epilog="example: tof-mpd sim predict real.npz -o predicted.npz")
    predict.add_argument("input", type=Path, help="recording directory or .npz with references")
    add_output(predict, "output recording directory or .npz", was_positional=True)
    predict.add_argument("--sim-config", type=Path,
                         help="simulator configuration JSON (ToFConfig.to_dict); default nominal")
    predict.add_argument("--albedo", type=float, default=None,
                         help="albedo assumed where the file has none (default 0.5)")
    predict.add_argument("--seed", type=int, default=0)
    predict.add_argument("--fuse-views", type=int, default=4, metavar="N",
                         help="fuse up to N other frames of the same scene (by pose and "
                              "agreeing geometry) into each frame's world; 0 = each frame "
                              "alone (default 4)")
    predict.set_defaults(func=run_predict)


def _register_dataset(commands: argparse._SubParsersAction) -> None:
    dataset = commands.add_parser(
        "dataset", help="render MD-Train/MD-Test-like recordings",
        description="Render an MD-Train-like and an MD-Test-like dataset (disjoint objects) with "
                    "ToF range + amplitude, fused structured-light references, arm poses and "
                    "checkerboard calibration captures. Writes OUT/md_train, OUT/md_test, "
                    "OUT/calibration (rosbag2 MCAP recordings) and OUT/dataset.json. Takes "
                    "about 1-2 s per frame per core: the full paper-sized set (900 frames + 770 "
                    "captures) about 15-25 min on 2 cores; --small about 1-2 min. "
                    "--renderer pathtrace renders the light transport with Mitsuba 3 "
                    "(optional extra [pathtrace]; objects may then be glossy, metal or "
                    "translucent) and applies the same camera modules on top; several seconds "
                    "per frame (docs/physics.md, Path-traced datasets).",
        epilog="example: tof-mpd sim dataset -o data/ --small")
    add_output(dataset, "output directory (must not exist)", was_positional=True)
    dataset.add_argument("--small", action="store_true",
                         help="4 train + 2 test scenes x 6 views, 120 captures")
    dataset.add_argument("--train-scenes", type=int, help="train scenes (default 30)")
    dataset.add_argument("--test-scenes", type=int, help="test scenes (default 20)")
    dataset.add_argument("--views", type=int, help="views per scene (default 18)")
    dataset.add_argument("--calibration", type=int, help="checkerboard captures (default 770)")
    dataset.add_argument("--seed", type=int, default=0)
    dataset.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                         help="worker processes (default: all cores)")
    dataset.add_argument("--renderer", choices=("builtin", "pathtrace"), default="builtin",
                         help="light transport: the built-in renderer (default) or the Mitsuba "
                              "path tracer (needs the [pathtrace] extra)")
    dataset.add_argument("--spp", type=int, default=64,
                         help="path tracer samples per pixel (16, 32, 48, 64 or a multiple of "
                              "64; default 64)")
    dataset.add_argument("--crop", metavar="WxH", type=window_size, default=None,
                         help="recorded central window of the 320x240 sensor: the paper's "
                              "180x140 (default) or e.g. 320x240 for the whole sensor")
    dataset.add_argument("--shard", metavar="I/N", default=None,
                         help="render only the I-th of N disjoint slices (0-based: scenes and "
                              "calibration chunks dealt round-robin), e.g. one SLURM array "
                              "task each; join them with `tof-mpd sim merge`")
    dataset.set_defaults(func=run_dataset)


def _register_merge(commands: argparse._SubParsersAction) -> None:
    merge = commands.add_parser(
        "merge", help="join the shards of a dataset rendered with --shard",
        description="Check that SHARD directories (each from `tof-mpd sim dataset --shard I/N` "
                    "with the same spec, seed and renderer) make one complete dataset — every "
                    "slice once, every scene of each slice present — and write it to OUT: the "
                    "same recordings, message for message, as one unsharded run.",
        epilog="example: tof-mpd sim merge -o data/ shards/0 shards/1 shards/2 shards/3")
    add_output(merge, "output directory (must not exist)")
    merge.add_argument("shards", type=Path, nargs="+", metavar="SHARD",
                       help="shard directories")
    merge.set_defaults(func=run_merge)


def _spec(args: argparse.Namespace):
    from ..sim.dataset import DatasetSpec

    spec = DatasetSpec.small(args.seed) if args.small else DatasetSpec(seed=args.seed)
    overrides = {"n_train_scenes": args.train_scenes, "n_test_scenes": args.test_scenes,
                 "views_per_scene": args.views, "n_calibration": args.calibration}
    values = {**spec.__dict__, **{k: v for k, v in overrides.items() if v is not None}}
    scenes = (values["n_train_scenes"], values["n_test_scenes"])
    if min(scenes) < 0 or sum(scenes) < 1 or values["views_per_scene"] < 1:
        raise InputError("need scene counts >= 0 (at least one scene) and views >= 1")
    return DatasetSpec(**values)


def _cell(args: argparse.Namespace):
    """The simulated cell with the chosen renderer (the path tracer loaded and checked)."""
    from ..sim.cell import CameraModel, SimCell

    if args.renderer == "pathtrace":
        from ..sim.pathtrace import render as pathtrace

        try:
            pathtrace.load_mitsuba()
        except SimulationError as err:
            reason = " ".join(str(err).split())
            raise SimulationError(PATHTRACE_MISSING.format(reason=reason)) from err
    try:
        camera = CameraModel() if args.crop is None else CameraModel(crop=args.crop)
    except SimulationError as err:
        raise InputError(f"--crop: {err}") from err
    try:
        return SimCell(camera=camera, renderer=args.renderer, pathtrace_spp=args.spp)
    except SimulationError as err:
        raise InputError(f"--spp: {err}") from err


def run_dataset(args: argparse.Namespace) -> int:
    from ..sim.dataset import Shard, generate_dataset

    if args.output.exists():
        raise InputError(f"{args.output} already exists; choose a new directory")
    try:
        shard = None if args.shard is None else Shard.parse(args.shard)
    except ValueError as err:
        raise InputError(f"--shard: {err}") from err
    spec = _spec(args)
    summary = generate_dataset(args.output, spec, workers=args.workers, cell=_cell(args),
                               shard=shard)
    print(json.dumps({"out": str(args.output), "renderer": summary["renderer"]["name"],
                      "frames": summary["frames"], "seconds": summary["seconds"],
                      **({"shard": args.shard} if shard else {})}))
    return 0


def run_merge(args: argparse.Namespace) -> int:
    from ..sim.dataset import merge_dataset

    if args.output.exists():
        raise InputError(f"{args.output} already exists; choose a new directory")
    summary = merge_dataset(args.output, args.shards)
    print(json.dumps({"out": str(args.output), "shards": len(args.shards),
                      "frames": summary["frames"]}))
    return 0


def load_config(path: Path | None):
    """A ToFConfig from a JSON file (``ToFConfig.to_dict`` layout), or the nominal one."""
    from ..sim.tof import ToFConfig

    if path is None:
        return ToFConfig.nominal()
    try:
        return ToFConfig.from_dict(json.loads(Path(path).read_text()))
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise InputError(f"{path}: not a simulator configuration: {err}") from err


def run_predict(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from ..frame import ToFFrame
    from ..pose import pose_m_to_mm
    from ..recordings import count_frames, iter_frames, write_frames
    from ..sim.tof import render_from_reference
    from ..sim.tof.reference_world import ReferenceView, fusion_views

    config = load_config(args.sim_config)
    rng = np.random.default_rng(args.seed)
    if args.fuse_views < 0:
        raise InputError("--fuse-views must be >= 0")
    refs, poses = _references_and_poses(args.input) if args.fuse_views else ([], [])

    def predicted():
        for index, frame in enumerate(tqdm(iter_frames(args.input), desc="predicting",
                                           total=count_frames(args.input), unit="frame")):
            if frame.reference_mm is None or not np.isfinite(frame.reference_mm).any():
                raise InputError(f"{args.input}: frame {index} has no reference to predict from")
            albedo = frame.albedo if frame.albedo is not None else args.albedo
            others = []
            if args.fuse_views:
                others = [ReferenceView(refs[j], poses[j], albedo if np.isscalar(albedo)
                                        else None)
                          for j in fusion_views(refs, poses, frame.intrinsics, index,
                                                max_views=args.fuse_views)]
            pose = None if frame.pose is None else pose_m_to_mm(frame.pose)
            m = render_from_reference(frame.reference_mm, frame.intrinsics, albedo, config, rng,
                                      frame_index=index, other_views=others,
                                      camera_to_world_mm=pose)
            yield ToFFrame(m.range_mm, m.amplitude, frame.intrinsics, config.mod_freq_hz,
                           frame.reference_mm, frame.stamp_ns, frame.pose, frame.albedo)

    count = write_frames(args.output, predicted())
    print(json.dumps({"output": str(args.output), "frames": count}))
    return 0


def _references_and_poses(path: Path) -> tuple[list, list]:
    """Every frame's reference (mm) and camera → world pose (mm), None where absent."""
    from ..pose import pose_m_to_mm
    from ..recordings import iter_frames

    refs, poses = [], []
    for frame in iter_frames(path):
        refs.append(frame.reference_mm)
        poses.append(None if frame.pose is None else pose_m_to_mm(frame.pose))
    return refs, poses
