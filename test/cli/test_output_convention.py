"""One CLI convention (issue 14, item 5): inputs positional, every written output
``-o/--output``; the old positional-output form fails with one line saying what to type."""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tof_mpd_ros.calibration import IntrinsicCalibration, save_calibration
from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.cli.main import build_parser, main
from tof_mpd_ros.cli.output import CliParser, OldOutputForm, add_output
from tof_mpd_ros.correction.encoding import EncodingConfig
from tof_mpd_ros.correction.fcn import FCNCorrectionModel
from tof_mpd_ros.correction.pipeline import CorrectionModel
from tof_mpd_ros.correction.weights import save_weights
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings import import_npz, save_npz

H, W = 18, 24
HOUR_NS = 3_600 * 10**9
#: the only subcommands that write nothing
READ_ONLY = {"tof-mpd recording info"}


def _frame(rng: np.random.Generator, stamp_ns: int) -> ToFFrame:
    """A table at ~400 mm with a nearer box; measured = truth + 6 mm + noise."""
    truth = np.full((H, W), 400.0) + rng.uniform(-5, 5)
    truth[5:12, 6:15] -= rng.uniform(50, 80)
    amplitude = (400.0 / truth) ** 2
    measured = truth + 6.0 + rng.normal(0, 1.0, truth.shape)
    return ToFFrame(measured.astype(np.float32), amplitude.astype(np.float32),
                    Intrinsics.from_fov(W, H, 74.0), reference_mm=truth.astype(np.float32),
                    stamp_ns=stamp_ns)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Tiny inputs of every writing command: frames (two capture sessions), a recording, a
    calibration and an untrained model of the frames' size."""
    d = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(0)
    frames = [_frame(rng, s * HOUR_NS + k * 10**9) for s in range(2) for k in range(2)]
    paths = {"frames": d / "frames.npz", "one": d / "one.npz", "recording": d / "recording",
             "calibration": d / "calibration.npz", "weights": d / "weights.npz"}
    save_npz(paths["frames"], frames)
    save_npz(paths["one"], frames[:1])
    import_npz(paths["one"], paths["recording"])
    calibration = IntrinsicCalibration(np.full((H, W), -6.0), np.ones((H, W)),
                                       np.zeros((H, W)), np.ones((H, W), bool))
    save_calibration(paths["calibration"], calibration)
    encoding = EncodingConfig(range_min_mm=300.0, range_max_mm=450.0, amplitude_min=0.2,
                              amplitude_max=2.0)
    save_weights(paths["weights"], CorrectionModel.untrained(calibration, encoding, seed=0))
    paths["fcn"] = save_weights(d / "fcn.npz", FCNCorrectionModel.untrained(calibration, seed=0))
    paths["adi"] = d / "adi"  # one mode of an Analog Devices folder (docs/real_cameras.md)
    paths["adi"].mkdir()
    for name, value, dtype in (("depth", 400, np.uint16), ("amplitude", 100, np.uint16),
                               ("confidence", 0, np.uint8)):
        np.save(paths["adi"] / f"{name}_mode3.npy", np.full((H, W), value, dtype))
    # two shards of a one-scene dataset, for `sim merge`
    for i in range(2):
        paths[f"shard{i}"] = d / f"shard{i}"
        assert main(["sim", "dataset", "-o", str(paths[f"shard{i}"]), "--shard", f"{i}/2",
                     *SHARDED.split()]) == 0
    return paths


SHARDED = "--train-scenes 1 --test-scenes 0 --views 1 --calibration 1 --workers 1"


# Each writing subcommand on tiny inputs, ``{name}`` replaced by the input's path; the tests
# append the output option.
WRITING = {
    "recording import-npz": "recording import-npz {one}",
    "recording export-npz": "recording export-npz {recording}",
    "recording import-adi": "recording import-adi {adi}",
    "sim dataset": "sim dataset --train-scenes 1 --test-scenes 0 --views 1 --calibration 1 "
                   "--workers 1",
    "sim predict": "sim predict {one} --fuse-views 0",
    "sim merge": "sim merge {shard0} {shard1}",
    "calibrate intrinsic": "calibrate intrinsic {frames}",
    "calibrate install": "calibrate install {calibration} --weights {weights}",
    "calibrate sigma": "calibrate sigma {frames} --weights {fcn}",
    "calibrate hand-eye": "calibrate hand-eye {tmp}/session --simulate --views 4 --min-views 3",
    "train": "train {frames} --calibration {calibration} --epochs 1 "
             "--max-samples-per-frame 100 --target-clip-mm 15 --edge-thresholds paper",
    "correct": "correct {frames} --weights {weights}",
    "evaluate": "evaluate {frames} --weights {weights}",
    "benchmark": "benchmark --train {frames} --test {one} --weights {weights} --quick "
                 "--methods JBF --examples 1 --no-progress",
}
#: commands whose output is one .npz file (a directory otherwise, or a JSON for hand-eye)
NPZ_OUTPUTS = {"recording export-npz", "recording import-adi", "sim predict", "calibrate intrinsic",
               "calibrate install", "calibrate sigma", "train", "correct"}
#: run for minutes even on tiny inputs: their -o/--output is only parsed here
TOO_SLOW = {"mismatch": "mismatch real.npz", "mismatch-benchmark": "mismatch-benchmark",
            "demo": "demo"}


@pytest.mark.parametrize("command", sorted(WRITING))
def test_every_writing_subcommand_writes_where_o_says(
        command: str, inputs: dict[str, Path], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out" / ("result.npz" if command in NPZ_OUTPUTS else "result")
    out.parent.mkdir()
    argv = [*shlex.split(WRITING[command].format(tmp=tmp_path, **inputs)), "-o", str(out)]
    assert main(argv) == 0, capsys.readouterr().err
    assert out.exists()
    # nothing else but the summary some commands write next to their output
    assert {p.name for p in out.parent.iterdir()} <= {out.name, out.with_suffix(".json").name}


def _leaf_parsers(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    """Every parser that runs a command (no further subcommand)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield parser
    for action in subs:
        for child in dict.fromkeys(action.choices.values()):  # aliases map to the same parser
            yield from _leaf_parsers(child)


def test_every_subcommand_that_writes_has_o_output_and_no_positional_output() -> None:
    leaves = {p.prog: p for p in _leaf_parsers(build_parser())}
    assert {"tof-mpd correct", "tof-mpd sim dataset", "tof-mpd mismatch"} <= set(leaves)
    tested = {f"tof-mpd {c}" for c in (*WRITING, *TOO_SLOW)}
    assert set(leaves) == tested | READ_ONLY  # a new command joins WRITING or READ_ONLY
    for prog, parser in leaves.items():
        outputs = [a for a in parser._actions if a.dest == "output"]
        assert [a.option_strings for a in outputs] == ([] if prog in READ_ONLY
                                                       else [["-o", "--output"]]), prog
        positionals = [a.dest for a in parser._actions if not a.option_strings]
        assert not any("out" in name for name in positionals), prog


@pytest.mark.parametrize("command", sorted({**WRITING, **TOO_SLOW}))
@pytest.mark.parametrize("flag", ["-o", "--output"])
def test_every_writing_subcommand_parses_o_and_output(command: str, flag: str) -> None:
    line = {**WRITING, **TOO_SLOW}[command].format(**dict.fromkeys(
        ("tmp", "one", "frames", "recording", "calibration", "weights", "fcn", "adi", "shard0",
         "shard1"), "in"))
    args = build_parser().parse_args([*shlex.split(line), flag, "somewhere/out"])
    assert args.output == Path("somewhere/out")


# the old form of every command that took its output positionally, its output and the one
# line it must give
OLD_FORMS = [
    ("correct in.npz out.npz --weights w.npz", "out.npz",
     "tof-mpd correct: the output is now -o/--output: "
     "tof-mpd correct in.npz -o out.npz --weights w.npz"),
    ("sim dataset data/ --small", "data/",
     "tof-mpd sim dataset: the output is now -o/--output: tof-mpd sim dataset -o data/ --small"),
    ("sim predict real.npz predicted.npz", "predicted.npz",
     "tof-mpd sim predict: the output is now -o/--output: "
     "tof-mpd sim predict real.npz -o predicted.npz"),
    ("recording import-npz in.npz rec/ --json", "rec/",
     "tof-mpd recording import-npz: the output is now -o/--output: "
     "tof-mpd recording import-npz in.npz -o rec/ --json"),
    ("recording export-npz rec/ out.npz", "out.npz",
     "tof-mpd recording export-npz: the output is now -o/--output: "
     "tof-mpd recording export-npz rec/ -o out.npz"),
    # options before the output, a global option and a path to quote: still the exact command
    ("-v correct in.npz --device cpu 'my out.npz'", "my out.npz",
     "tof-mpd correct: the output is now -o/--output: "
     "tof-mpd -v correct in.npz --device cpu -o 'my out.npz'"),
]


@pytest.mark.parametrize(("old", "output", "hint"), OLD_FORMS, ids=[o for o, _, _ in OLD_FORMS])
def test_old_positional_output_fails_with_the_command_to_type(
        old: str, output: str, hint: str, tmp_path: Path,
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(shlex.split(old)) == 2
    captured = capsys.readouterr()
    assert captured.err == hint + "\n" and captured.out == ""
    assert list(tmp_path.iterdir()) == []  # refused before anything ran
    typed = shlex.split(hint.split(": ", 2)[2])
    args = build_parser().parse_args(typed[1:])  # the command the hint gives is a valid one
    assert args.output == Path(output)


@pytest.mark.parametrize("argv", ["correct in.npz", "correct in.npz a.npz b.npz",
                                  "correct in.npz out.npz --device"])
def test_other_mistakes_keep_argparse_s_message(argv: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(shlex.split(argv))
    assert exit_.value.code == 2
    assert "tof-mpd correct: error: " in capsys.readouterr().err


def test_help_examples_follow_the_convention() -> None:
    examples = {p.prog: p.epilog for p in _leaf_parsers(build_parser()) if p.epilog}
    assert {"tof-mpd correct", "tof-mpd sim dataset", "tof-mpd recording export-npz"} <= set(
        examples)
    for prog, epilog in examples.items():
        line = shlex.split(epilog.removeprefix("example: "))
        assert " ".join(line[:len(prog.split())]) == prog
        assert build_parser().parse_args(line[1:]).output is not None, prog


def test_old_form_needs_a_required_output_on_a_cli_parser() -> None:
    with pytest.raises(TypeError):
        add_output(argparse.ArgumentParser(), "x", was_positional=True)
    with pytest.raises(TypeError):
        add_output(CliParser(), "x", required=False, was_positional=True)


def test_parsing_alone_raises_the_old_form() -> None:
    with pytest.raises(OldOutputForm) as old:
        build_parser().parse_args(["sim", "predict", "a.npz", "b.npz"])
    assert old.value.output == "b.npz" and old.value.prog == "tof-mpd sim predict"
