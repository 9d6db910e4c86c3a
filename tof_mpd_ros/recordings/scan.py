"""Summary-less, crash-tolerant reading of an MCAP file's data section.

A writer killed with SIGKILL leaves no summary, no footer and usually a half-written last
record. This module walks the records from the start with the ``mcap`` library's record parsers
(``mcap.records``, ``mcap.stream_reader.breakup_chunk``), yields every schema, channel, message
and metadata record of each complete chunk, and stops cleanly at the end of the written data.

Corruption is told apart from truncation by the file's end: a file that ends with the MCAP
magic was closed properly, so a record running past the end of it is corruption; a file without
it was interrupted, so its last incomplete record is the expected torn write.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from ..errors import RecordingError

_log = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_MAX_HEADER = 1 << 20  # a Header holds two short strings (profile, library)
# Chunks are decompressed this many bytes at a time (see _records_section).
_BLOCK = 1 << 20
# Footer record: opcode, length 20, summary_start, summary_offset_start, summary_crc.
_FOOTER = struct.Struct("<BQQQI")

Record = Schema | Channel | Message | Metadata


@dataclass
class ScanReport:
    """What a scan found besides records.

    Attributes:
        closed: the file ends with the MCAP magic (the writer finished it).
        truncated_bytes: bytes of the torn last record ignored (interrupted writer).
        corrupt_chunks: chunks skipped because they failed their CRC or decompression.
        chunks: chunks read successfully.
        warn: log recoveries and skips as warnings (else debug: a repeated scan of one file).
        skip_corrupt: skip (and count) chunks failing CRC/decompression instead of raising.
    """

    warn: bool = True
    skip_corrupt: bool = False
    closed: bool = False
    truncated_bytes: int = 0
    corrupt_chunks: int = 0
    chunks: int = 0

    @property
    def level(self) -> int:
        return logging.WARNING if self.warn else logging.DEBUG


def file_is_closed(stream: BinaryIO, size: int) -> bool:
    """True when the file ends with the MCAP magic, i.e. its writer finished it."""
    if size < 2 * len(MAGIC):
        return False
    stream.seek(size - len(MAGIC))
    return stream.read(len(MAGIC)) == MAGIC


def summary_intact(stream: BinaryIO, size: int) -> bool:
    """True when a closed file's summary section matches the CRC its footer stores (or the
    footer stores none). The summary is outside every chunk CRC, so a flipped byte there would
    otherwise rename a topic or miscount messages unnoticed."""
    footer_at = size - len(MAGIC) - _FOOTER.size
    if footer_at < len(MAGIC):
        return False
    stream.seek(footer_at)
    opcode, length, summary_start, _, crc = _FOOTER.unpack(stream.read(_FOOTER.size))
    if opcode != Opcode.FOOTER or length != _FOOTER.size - 9:
        return False
    if crc == 0:
        return True  # the writer did not compute one
    if not len(MAGIC) <= summary_start <= footer_at:
        return False
    stream.seek(summary_start)
    covered = stream.read(footer_at + _FOOTER.size - 4 - summary_start)
    return zlib.crc32(covered) == crc


def check_magic(stream: BinaryIO, path: Path) -> int:
    """Check the leading magic; return the file size."""
    size = stream.seek(0, io.SEEK_END)
    stream.seek(0)
    head = stream.read(len(MAGIC))
    if size == 0:
        raise RecordingError(f"{path}: file is empty")
    if head != MAGIC:
        raise RecordingError(f"{path}: not an MCAP file (bad magic {head[:8]!r})")
    return size


def iter_records(path: Path, report: ScanReport) -> Iterator[Record]:
    """Yield the schema, channel, message and metadata records of ``path`` in file order.

    Args:
        path: the ``.mcap`` file.
        report: options (``warn``, ``skip_corrupt``); filled in while scanning.

    Raises:
        RecordingError: not an MCAP file, broken record framing in a closed file, or a corrupt
            chunk unless ``report.skip_corrupt``.
    """
    try:
        stream = open(path, "rb")  # closed in the finally below
    except OSError as err:
        raise RecordingError(f"{path}: cannot open: {err}") from err
    try:
        size = check_magic(stream, path)
        report.closed = file_is_closed(stream, size)
        stream.seek(len(MAGIC))
        yield from _walk(stream, path, size, report)
    finally:
        stream.close()


def _walk(stream: BinaryIO, path: Path, size: int, report: ScanReport) -> Iterator[Record]:
    offset = len(MAGIC)
    while True:
        head = stream.read(_RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size or offset + _RECORD_HEAD.size > size:
            _end_without_footer(path, size, offset, report)
            return
        opcode, length = _RECORD_HEAD.unpack(head)
        if offset == len(MAGIC) and (opcode != Opcode.HEADER or length > _MAX_HEADER):
            # Every MCAP starts with a small Header record; anything else is not one.
            raise RecordingError(f"{path}: corrupt MCAP: no Header record after the magic "
                                 f"(opcode {opcode:#x}, length {length})")
        end = offset + _RECORD_HEAD.size + length
        if end > size:
            _end_without_footer(path, size, offset, report, length=length)
            return
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            if not report.closed:
                _log.log(report.level, "%s: file was not closed (incomplete summary section); "
                         "all %d chunks of its data section are intact", path, report.chunks)
            return  # what follows is the summary section: indexes and repeated records
        body = stream.read(length)
        if opcode == Opcode.CHUNK:
            yield from _chunk_records(body, path, offset, report)
        else:
            record = _top_level_record(opcode, body, path, offset)
            if record is not None:
                yield record
        offset = end


def _end_without_footer(path: Path, size: int, offset: int, report: ScanReport,
                        length: int | None = None) -> None:
    """The data ends before a DataEnd/Footer record: torn write, or corruption if closed."""
    if report.closed:
        what = "" if length is None else f" claims {length} bytes"
        raise RecordingError(f"{path}: corrupt MCAP: record at byte {offset}{what} and runs past "
                             f"the end of the {size}-byte file")
    report.truncated_bytes = size - offset
    _log.log(report.level, "%s: file was not closed (writer interrupted?): recovered %d complete "
                 "chunks, ignored the last %d bytes", path, report.chunks, size - offset)


def _chunk_records(body: bytes, path: Path, offset: int,
                   report: ScanReport) -> Iterator[Record]:
    try:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
        plain = dataclasses.replace(chunk, compression="", data=_records_section(chunk))
        records = breakup_chunk(plain, validate_crc=True)
    except Exception as err:  # zstd/lz4/crc/struct all signal a corrupt chunk
        problem = f"corrupt chunk at byte {offset} ({type(err).__name__}: {err})"
        if not report.skip_corrupt:
            raise RecordingError(f"{path}: {problem}") from err
        report.corrupt_chunks += 1
        _log.log(report.level, "%s: skipped %s", path, problem)
        return
    report.chunks += 1
    for record in records:
        if isinstance(record, Schema | Channel | Message):
            yield record


_DECOMPRESSORS: dict[str, Callable[[bytes], BinaryIO]] = {
    "zstd": lambda data: zstandard.ZstdDecompressor().stream_reader(data),
    "lz4": lambda data: lz4.frame.LZ4FrameFile(io.BytesIO(data)),
}


def _records_section(chunk: Chunk) -> bytes:
    """The chunk's records, decompressed block by block up to its declared size.

    zstd and lz4 allocate the content size their frame header claims before decompressing, so a
    corrupt header could claim gigabytes; reading in blocks keeps memory to the data really
    there (and never past ``uncompressed_size``, which may lie too).
    """
    if chunk.compression == "":
        return chunk.data
    if chunk.compression not in _DECOMPRESSORS:
        raise ValueError(f"unsupported chunk compression {chunk.compression!r}")
    stream = _DECOMPRESSORS[chunk.compression](chunk.data)
    limit = chunk.uncompressed_size
    out = bytearray()
    while len(out) <= limit:
        block = stream.read(min(_BLOCK, limit + 1 - len(out)))
        if not block:
            break
        out += block
    if len(out) != limit:
        what = f"more than {limit}" if len(out) > limit else str(len(out))
        raise ValueError(f"decompresses to {what} bytes but declares {limit}")
    return bytes(out)


def _top_level_record(opcode: int, body: bytes, path: Path, offset: int) -> Record | None:
    """Parse a record outside chunks (unchunked files, metadata); others are skipped."""
    readers = {Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read,
               Opcode.METADATA: Metadata.read}
    try:
        if opcode == Opcode.MESSAGE:
            return Message.read(ReadDataStream(io.BytesIO(body)), len(body))
        if opcode in readers:
            return readers[opcode](ReadDataStream(io.BytesIO(body)))
    except Exception as err:  # struct, unicode and mcap's EndOfFile alike
        raise RecordingError(f"{path}: corrupt MCAP record (opcode {opcode:#x}) at byte "
                             f"{offset}: {type(err).__name__}: {err}") from err
    return None
