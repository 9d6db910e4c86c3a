"""``tof-mpd recording info | import-npz | export-npz | import-adi``."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ..recordings import RANGE_ENCODINGS, RecordingReader, export_npz, import_npz
from ..recordings.reader import RecordingInfo
from .output import add_output


def register(subparsers: Any) -> None:
    """Add the ``recording`` command and its subcommands."""
    parser = subparsers.add_parser(
        "recording", help="inspect recordings; convert between recordings and .npz",
        description="rosbag2 MCAP recordings (directory with metadata.yaml + .mcap) and the "
                    ".npz interchange (docs/recordings.md).")
    sub = parser.add_subparsers(dest="recording_command", metavar="SUBCOMMAND", required=True)
    for add in (_register_info, _register_import_npz, _register_export_npz, _register_import_adi):
        add(sub)


def _register_info(sub: Any) -> None:
    info = sub.add_parser(
        "info", help="topics, types, counts, duration, size, range convention",
        description="Reads a recording directory or .mcap file (summary section; a file left "
                    "open by a crashed writer is scanned instead) and prints what `ros2 bag "
                    "info` shows plus the range convention. Writes nothing. Takes well under a "
                    "second for a closed file; a scan reads the whole file (~1 s per 500 MB).")
    info.add_argument("path", help="recording directory or .mcap file")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    info.set_defaults(func=_info)


def _register_import_npz(sub: Any) -> None:
    imp = sub.add_parser(
        "import-npz", help="write the frames of an .npz into a new recording",
        description="Reads an interchange .npz (range_mm, amplitude, [reference_mm], fx fy cx "
                    "cy mod_freq_hz, [stamp_ns], [pose]) and writes a new rosbag2 MCAP "
                    "recording directory OUT. Refuses to overwrite unless --overwrite. "
                    "Takes about 20-50 ms per 320x240 frame with zstd (less with --compression "
                    "none).",
        epilog="example: tof-mpd recording import-npz frames.npz -o my_recording/")
    imp.add_argument("npz", help="input .npz")
    add_output(imp, "recording directory to create", was_positional=True)
    imp.add_argument("--encoding", choices=RANGE_ENCODINGS, default="64FC1",
                     help="range/reference image encoding (default 64FC1: lossless for "
                          "float32 mm; 32FC1 m and 16UC1 mm are REP 118)")
    imp.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd",
                     help="MCAP chunk compression (default zstd)")
    imp.add_argument("--overwrite", action="store_true", help="replace an existing recording")
    imp.add_argument("--json", action="store_true", help="print the result as JSON")
    imp.set_defaults(func=_import)


def _register_export_npz(sub: Any) -> None:
    exp = sub.add_parser(
        "export-npz", help="write every frame of a recording to an .npz",
        description="Reads a recording directory or .mcap file and writes its frames (radial "
                    "range in mm, amplitude, reference, intrinsics, stamps, camera-to-base "
                    "poses) to an interchange .npz. Refuses to overwrite unless --overwrite. "
                    "Takes about 10 ms per 320x240 frame and holds all frames in memory.",
        epilog="example: tof-mpd recording export-npz my_recording/ -o frames.npz")
    exp.add_argument("recording", help="recording directory or .mcap file")
    add_output(exp, "output .npz", was_positional=True)
    exp.add_argument("--skip-bad", action="store_true",
                     help="drop corrupt chunks and unbuildable frames (counted) instead of "
                          "failing")
    exp.add_argument("--overwrite", action="store_true", help="replace an existing file")
    exp.add_argument("--json", action="store_true", help="print the result as JSON")
    exp.set_defaults(func=_export)


def _register_import_adi(sub: Any) -> None:
    adi = sub.add_parser(
        "import-adi", help="write one mode of an Analog Devices ToF folder as an .npz",
        description="Reads one camera mode of a folder of Analog Devices ToF frames "
                    "(depth_modeN.npy uint16 mm, amplitude_modeN.npy, confidence_modeN.npy; "
                    "the layout of data/realdata/adi_tof_office) and writes it as an "
                    "interchange .npz (or, for an OUT not ending in .npz, a new recording "
                    "directory) at full resolution. The depth is radial range and is kept as "
                    "range_mm; pixels of depth 0 or confidence above --max-confidence are NaN "
                    "(the interchange has no confidence field); intrinsics are the assumed "
                    "75-degree centred pinhole (no calibration ships). See "
                    "docs/real_cameras.md. Refuses to overwrite unless --overwrite. Takes "
                    "about a second.",
        epilog="example: tof-mpd recording import-adi data/realdata/adi_tof_office "
               "--mode 3 -o adi_mode3.npz")
    adi.add_argument("folder", help="folder of ADI frames")
    add_output(adi, ".npz (or recording directory) to create")
    adi.add_argument("--mode", type=int,
                     help="camera mode N to import (required when the folder holds several)")
    adi.add_argument("--max-confidence", type=int, default=None,
                     help="pixels with a larger confidence value (higher = less reliable) are "
                          "invalid (default 4; 255 keeps every pixel of depth > 0)")
    adi.add_argument("--fov-deg", type=float, default=None,
                     help="horizontal field of view of the assumed pinhole (default 75)")
    adi.add_argument("--overwrite", action="store_true", help="replace an existing output")
    adi.add_argument("--json", action="store_true", help="print the result as JSON")
    adi.set_defaults(func=_import_adi)


def _info(args: argparse.Namespace) -> int:
    with RecordingReader(args.path) as reader:
        info = reader.info()
    if args.json:
        print(json.dumps(info.as_dict(), indent=2))
    else:
        print(format_info(info))
    return 0


def format_info(info: RecordingInfo) -> str:
    """A ``ros2 bag info``-like table."""
    lines = [
        f"Files:             {', '.join(f.name for f in info.files)}",
        f"Bag size:          {_size(info.size_bytes)}",
        "Storage id:        mcap" + ("" if info.closed else "  (not closed: recovered)"),
        f"Duration:          {info.duration_ns / 1e9:.9f}s",
        f"Start:             {info.start_ns / 1e9:.9f}",
        f"End:               {info.end_ns / 1e9:.9f}",
        f"Messages:          {info.message_count}",
        f"Range convention:  {info.range_convention}",
        "Topic information:",
    ]
    width = max((len(t.name) for t in info.topics), default=0)
    lines += [f"  {t.name:<{width}}  {t.msgtype:<34} {t.count:>7}" for t in info.topics]
    custom = {k: v for k, v in info.custom_data.items() if ".topic." not in k}
    if custom:
        lines.append("Custom data:")
        lines += [f"  {k}: {v}" for k, v in custom.items()]
    return "\n".join(lines)


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{n} B"
        n /= 1024  # type: ignore[assignment]
    return f"{n} B"


def _import(args: argparse.Namespace) -> int:
    count = import_npz(args.npz, args.output, range_encoding=args.encoding,
                       compression=args.compression, overwrite=args.overwrite)
    _report(args, {"frames": count, "npz": args.npz, "recording": str(args.output),
                   "encoding": args.encoding}, f"wrote {count} frames to {args.output}")
    return 0


def _export(args: argparse.Namespace) -> int:
    count = export_npz(args.recording, args.output, overwrite=args.overwrite,
                       on_error="skip" if args.skip_bad else "raise")
    _report(args, {"frames": count, "recording": args.recording, "npz": str(args.output)},
            f"wrote {count} frames to {args.output}")
    return 0


def _import_adi(args: argparse.Namespace) -> int:
    import numpy as np

    from ..errors import RecordingError
    from ..recordings import write_frames
    from ..recordings.adi import adi_modes, read_adi

    modes = adi_modes(args.folder)
    if not modes:
        raise RecordingError(f"{args.folder}: no ADI frames (depth_modeN.npy, "
                             "amplitude_modeN.npy, confidence_modeN.npy)")
    mode = args.mode
    if mode is None:
        if len(modes) > 1:
            raise RecordingError(f"{args.folder} holds modes {', '.join(map(str, modes))}; "
                                 "choose one with --mode")
        mode = modes[0]
    frame = read_adi(args.folder, mode, max_confidence=args.max_confidence,
                     fov_deg=args.fov_deg)
    count = write_frames(args.output, [frame], overwrite=args.overwrite)
    k = frame.intrinsics
    valid = float(np.isfinite(frame.range_mm).mean())
    _report(args, {"frames": count, "folder": args.folder, "mode": mode,
                   "output": str(args.output), "width": k.width, "height": k.height,
                   "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
                   "valid_fraction": round(valid, 4)},
            f"wrote mode {mode} ({k.width}x{k.height}, {100 * valid:.1f} % valid) to "
            f"{args.output}")
    return 0


def _report(args: argparse.Namespace, result: dict[str, Any], text: str) -> None:
    print(json.dumps(result) if args.json else text, file=sys.stdout)
