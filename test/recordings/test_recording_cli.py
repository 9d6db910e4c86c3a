"""``tof-mpd recording info | import-npz | export-npz``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rec_helpers import make_frames

from tof_mpd_ros.cli.main import main
from tof_mpd_ros.recordings import save_npz


@pytest.fixture
def npz(tmp_path):
    frames = make_frames(4)
    frames[2].range_mm[:] = np.nan  # a fully invalid frame survives too
    path = tmp_path / "in.npz"
    save_npz(path, frames)
    return path


def test_import_info_export_round_trips_exactly(tmp_path, npz, capsys):
    rec, out = tmp_path / "rec", tmp_path / "out.npz"
    assert main(["recording", "import-npz", str(npz), "-o", str(rec), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 4

    assert main(["recording", "info", str(rec), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    counts = {t["name"]: t["count"] for t in info["topics"]}
    assert counts["/tof/range/image_raw"] == 4 and counts["/sl/range/image_raw"] == 4
    assert info["range_convention"] == "radial" and info["closed"] is True
    assert info["duration_s"] == pytest.approx(0.15) and info["message_count"] == 20

    assert main(["recording", "info", str(rec)]) == 0
    table = capsys.readouterr().out
    assert "Range convention:  radial" in table and "/tof/camera_info" in table

    assert main(["recording", "export-npz", str(rec), "-o", str(out)]) == 0
    assert "wrote 4 frames" in capsys.readouterr().out
    a, b = np.load(npz), np.load(out)
    assert sorted(a.files) == sorted(b.files)
    for key in a.files:
        assert a[key].dtype == b[key].dtype and a[key].tobytes() == b[key].tobytes(), key


def test_16uc1_import_and_refusal_to_overwrite(tmp_path, npz, capsys):
    rec = tmp_path / "rec"
    assert main(["recording", "import-npz", str(npz), "-o", str(rec), "--encoding", "16UC1",
                 "--compression", "none"]) == 0
    capsys.readouterr()
    assert main(["recording", "import-npz", str(npz), "-o", str(rec)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refusing to overwrite" in err


def test_corrupt_file_gives_exit_2_and_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\x07" * 40)
    assert main(["recording", "info", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("tof-mpd recording: error: ") and "bad.mcap: corrupt MCAP" in err
    assert main(["recording", "export-npz", str(tmp_path / "missing"), "-o",
                 str(tmp_path / "o.npz")]) == 2
    assert "no such recording" in capsys.readouterr().err
    (tmp_path / "junk.npz").write_bytes(b"junk")
    assert main(["recording", "import-npz", str(tmp_path / "junk.npz"), "-o",
                 str(tmp_path / "r2")]) == 2
    assert "junk.npz: is not an .npz (zip) file" in capsys.readouterr().err
    assert not (tmp_path / "r2").exists()


def test_corrupt_chunk_fails_export_unless_skipped(tmp_path, npz, capsys):
    rec = tmp_path / "rec"
    assert main(["recording", "import-npz", str(npz), "-o", str(rec), "--compression", "none"]) == 0
    mcap = rec / "rec_0.mcap"
    data = bytearray(mcap.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 64] = bytes(range(64))
    mcap.write_bytes(bytes(data))
    capsys.readouterr()
    assert main(["recording", "export-npz", str(rec), "-o", str(tmp_path / "o.npz")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rec_0.mcap: corrupt chunk at byte" in err
    assert main(["recording", "export-npz", str(rec), "-o", str(tmp_path / "o.npz"), "--skip-bad",
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 3


@pytest.mark.parametrize("sub", ["info", "import-npz", "export-npz"])
def test_help_says_what_it_reads_writes_and_how_long(sub, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["recording", sub, "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "Reads" in text and ("Writes" in text or "writes" in text) and "Takes" in text
