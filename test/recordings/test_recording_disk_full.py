"""A recording whose disk fills up: the writer stops with one clear error, and what it wrote
before stays a readable recording. "Full" is a file size limit (RLIMIT_FSIZE) in a child
process: writes past it fail with EFBIG like they fail with ENOSPC on a full disk."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from rec_helpers import assert_frames_equal, make_frames

from tof_mpd_ros.recordings import RecordingReader

resource = pytest.importorskip("resource")  # POSIX only

LIMIT = 40_000  # bytes: room for several of make_frames' 12x16 frames, not for 30
FRAMES = 30

CHILD = """
import json, resource, signal, sys
sys.path.insert(0, sys.argv[3])
from rec_helpers import make_frames
from tof_mpd_ros.errors import RecordingError
from tof_mpd_ros.recordings import RecordingWriter

signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a failed write, not a killed process
limit = int(sys.argv[2])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
writer = RecordingWriter(sys.argv[1], compression="none").open()
written, error = 0, ""
for frame in make_frames(int(sys.argv[4])):
    try:
        writer.write_frame(frame)
    except RecordingError as err:
        error = str(err)
        break
    written += 1
writer.close()  # a writer that failed is closed already: no second error
print(json.dumps({"written": written, "error": error}))
"""


def test_a_full_disk_stops_the_writer_with_one_error_and_keeps_every_complete_frame(
        tmp_path: Path) -> None:
    path = tmp_path / "rec"
    run = subprocess.run([sys.executable, "-c", CHILD, str(path), str(LIMIT),
                          str(Path(__file__).parent), str(FRAMES)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout.splitlines()[-1])
    written, error = result["written"], result["error"]
    assert 2 <= written < FRAMES, result
    assert "rec_0.mcap" in error and "File too large" in error, error
    assert f"the {written} complete frames written before are kept" in error
    mcap = path / "rec_0.mcap"
    assert mcap.stat().st_size <= LIMIT
    with RecordingReader(path) as reader:
        frames = list(reader.frames())
    assert len(frames) == written
    for got, want in zip(frames, make_frames(FRAMES)[:written], strict=True):
        assert_frames_equal(got, want, exact_range=False)  # 32FC1 metres
    # metadata.yaml counts what the file holds, not the messages of the frame that failed
    info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"]
              for t in info["topics_with_message_count"]}
    assert counts and set(counts.values()) == {written}, counts
    assert info["message_count"] == sum(counts.values())
