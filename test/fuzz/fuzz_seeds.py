"""Small valid seed files for the fuzz tests, made with the package's own writers."""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings import RecordingWriter, save_npz

HEIGHT, WIDTH = 4, 6
INTRINSICS = Intrinsics(5.0, 5.5, 2.5, 1.5, WIDTH, HEIGHT)
MOD_FREQ_HZ = 24e6
FIRST_STAMP_NS = 1_700_000_000_000_000_000
MAGIC = b"\x89MCAP0\r\n"
OP_CHUNK = 0x06


def seed_frames(n: int = 3) -> list[ToFFrame]:
    """n small frames with NaNs, a reference and a pose each, 50 ms apart."""
    rng = np.random.default_rng(15)
    shape = INTRINSICS.shape
    frames = []
    for i in range(n):
        range_mm = rng.uniform(150.0, 2500.0, shape).astype(np.float32)
        range_mm[0, i] = np.nan
        reference = rng.uniform(150.0, 2500.0, shape).astype(np.float32)
        pose = np.eye(4)
        pose[:3, 3] = rng.normal(size=3)
        frames.append(ToFFrame(range_mm, rng.uniform(0.0, 900.0, shape).astype(np.float32),
                               INTRINSICS, mod_freq_hz=MOD_FREQ_HZ, reference_mm=reference,
                               stamp_ns=FIRST_STAMP_NS + i * 50_000_000, pose=pose))
    return frames


def write_seed_recording(directory: Path, compression: str) -> Path:
    """A closed three-frame recording (metadata.yaml + one .mcap); returns the directory."""
    with RecordingWriter(directory, compression=compression) as writer:
        for frame in seed_frames():
            writer.write_frame(frame)
    return directory


def write_seed_npz(path: Path) -> Path:
    """A three-frame interchange .npz written by ``save_npz``."""
    save_npz(path, seed_frames())
    return path


@dataclass(frozen=True)
class ChunkFields:
    """Byte offsets, in the file, of the fields of one MCAP Chunk record that readers trust."""

    record_length: int
    uncompressed_size: int
    uncompressed_crc: int
    compression_length: int
    records_length: int


def chunk_fields(blob: bytes) -> list[ChunkFields]:
    """Field offsets of every chunk of a (well-formed) MCAP file's data section."""
    out = []
    offset = len(MAGIC)
    stream = io.BytesIO(blob)
    while offset + 9 <= len(blob):
        stream.seek(offset)
        opcode, length = struct.unpack("<BQ", stream.read(9))
        if opcode == OP_CHUNK:
            body = offset + 9
            (compression_length,) = struct.unpack_from("<I", blob, body + 28)
            out.append(ChunkFields(offset + 1, body + 16, body + 24, body + 28,
                                   body + 32 + compression_length))
        if opcode in (0x0F, 0x02):  # DataEnd, Footer: the data section is over
            break
        offset += 9 + length
    return out


def with_chunk_data(blob: bytes, chunk_at: ChunkFields, data: bytes) -> bytes:
    """``blob`` with one chunk's compressed records replaced by ``data`` (record and records
    lengths updated; later offsets shift, so the summary no longer matches and is not used)."""
    start = chunk_at.record_length - 1
    old_length = int.from_bytes(blob[chunk_at.record_length:chunk_at.record_length + 8], "little")
    head = blob[chunk_at.record_length + 8:chunk_at.records_length]
    body = head + len(data).to_bytes(8, "little") + data
    record = bytes([OP_CHUNK]) + len(body).to_bytes(8, "little") + body
    return blob[:start] + record + blob[start + 9 + old_length:]


def chunk_data(blob: bytes, chunk_at: ChunkFields) -> bytes:
    """One chunk's compressed records."""
    length = int.from_bytes(blob[chunk_at.records_length:chunk_at.records_length + 8], "little")
    return blob[chunk_at.records_length + 8:chunk_at.records_length + 8 + length]


def zstd_claiming(frame: bytes, content_size: int) -> bytes:
    """A zstd frame whose header claims ``content_size`` bytes (8-byte size field)."""
    descriptor = frame[4]
    size_bytes = (0, 2, 4, 8)[descriptor >> 6] or (1 if descriptor & 0x20 else 0)
    window = 0 if descriptor & 0x20 else 1
    rest = frame[5 + window + size_bytes:]
    return frame[:4] + bytes([(descriptor & 0x3F) | 0xC0]) + frame[5:5 + window] + \
        content_size.to_bytes(8, "little") + rest


def lz4_claiming(frame: bytes, content_size: int) -> bytes:
    """An lz4 frame whose header claims ``content_size`` bytes, with a valid header checksum."""
    flags = frame[4] | 0x08  # content size present
    had_size = bool(frame[4] & 0x08)
    rest = frame[6 + (8 if had_size else 0) + 1:]
    descriptor = bytes([flags, frame[5]]) + content_size.to_bytes(8, "little")
    return frame[:4] + descriptor + bytes([(_xxh32_short(descriptor) >> 8) & 0xFF]) + rest


def _xxh32_short(data: bytes) -> int:
    """XXH32 (seed 0) of fewer than 16 bytes: the lz4 frame header checksum."""
    p1, p2, p3, p4, p5, mask = 2654435761, 2246822519, 3266489917, 668265263, 374761393, 2**32 - 1

    def rotl(x: int, r: int) -> int:
        return ((x << r) | (x >> (32 - r))) & mask

    assert len(data) < 16
    h = (p5 + len(data)) & mask
    i = 0
    while i + 4 <= len(data):
        h = rotl((h + int.from_bytes(data[i:i + 4], "little") * p3) & mask, 17) * p4 & mask
        i += 4
    for byte in data[i:]:
        h = rotl((h + byte * p5) & mask, 11) * p1 & mask
    h ^= h >> 15
    h = h * p2 & mask
    h ^= h >> 13
    h = h * p3 & mask
    return h ^ (h >> 16)
