"""Read rosbag2 MCAP recordings: info, decoded messages and streamed ToF frames.

Accepts the recording directory (metadata.yaml + .mcap), a directory holding only ``.mcap``
files, or one ``.mcap`` file. Files that were never closed (writer killed) are read up to their
last complete chunk; see :mod:`tof_mpd_ros.recordings.scan`.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

from mcap.reader import SeekingReader
from mcap.records import Channel, Message, Metadata, Schema
from mcap_ros2.decoder import DecoderFactory

from ..errors import RecordingError
from ..frame import DEFAULT_MOD_FREQ_HZ, ToFFrame
from . import metadata, scan
from .frames import (
    REQUIRED_ROLES,
    ROLE_TYPES,
    FrameAssembler,
    Plan,
    normalise_type,
    topic_roles,
)
from .topics import (
    CONVENTIONS,
    KEY_MOD_FREQ,
    KEY_RANGE_CONVENTION,
    MCAP_METADATA_NAME,
    RADIAL,
    TopicNames,
)

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordedMessage:
    """One decoded message.

    Attributes:
        topic: topic name.
        msgtype: ``pkg/msg/Type``.
        log_time_ns: MCAP log time, integer ns.
        message: the decoded message (attributes named like the ROS fields).
    """

    topic: str
    msgtype: str
    log_time_ns: int
    message: Any


@dataclass(frozen=True)
class RecordingInfo:
    """What ``tof-mpd recording info`` shows.

    Attributes:
        path: the path given to the reader.
        files: the ``.mcap`` files read.
        topics: per topic: name, type, message count (as found in the files).
        start_ns, end_ns: first and last message log time (ns); 0 when empty.
        size_bytes: total size of the ``.mcap`` files.
        custom_data: metadata.yaml ``custom_data`` over the MCAP ``tof_mpd_ros`` metadata.
        closed: every file was closed by its writer (False after a crash).
        range_convention: ``"radial"`` or ``"z"``.
    """

    path: Path
    files: tuple[Path, ...]
    topics: tuple[metadata.TopicStats, ...]
    start_ns: int
    end_ns: int
    size_bytes: int
    custom_data: dict[str, str]
    closed: bool
    range_convention: str

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics)

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns)

    def count(self, topic: str) -> int:
        return sum(t.count for t in self.topics if t.name == topic)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"path": str(self.path), "files": [str(f) for f in self.files],
                "closed": self.closed, "size_bytes": self.size_bytes,
                "start_ns": self.start_ns, "end_ns": self.end_ns,
                "duration_s": self.duration_ns / 1e9, "message_count": self.message_count,
                "range_convention": self.range_convention,
                "topics": [{"name": t.name, "type": t.msgtype, "count": t.count}
                           for t in self.topics],
                "custom_data": dict(self.custom_data)}


@dataclass
class _FileIndex:
    """Per-file facts gathered from the summary section or by a scan."""

    closed: bool
    topics: dict[str, metadata.TopicStats] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0
    custom: dict[str, str] = field(default_factory=dict)


class RecordingReader:
    """Context manager reading one recording.

    Args:
        path: recording directory, or a ``.mcap`` file.
        topics: topic names; default: those recorded in ``custom_data``, else the defaults.
        range_convention: override ``custom_data``'s ``"radial"``/``"z"`` (default radial when
            the recording does not say).
        on_error: ``"raise"`` (default) raises :class:`RecordingError` on a corrupt chunk, an
            undecodable message or a frame that cannot be built; ``"skip"`` drops it, logs it
            and counts it in :attr:`dropped`.

    Raises:
        RecordingError: the path does not exist, or is a directory with neither metadata.yaml
            nor ``.mcap`` files, or metadata.yaml is unreadable or lists missing files.
    """

    def __init__(self, path: str | Path, *, topics: TopicNames | None = None,
                 range_convention: str | None = None, on_error: str = "raise") -> None:
        if on_error not in ("raise", "skip"):
            raise RecordingError(f"on_error must be 'raise' or 'skip', got {on_error!r}")
        if range_convention is not None and range_convention not in CONVENTIONS:
            raise RecordingError(f"range_convention must be one of {CONVENTIONS}, "
                                 f"got {range_convention!r}")
        self.path = Path(path)
        self.skip_bad = on_error == "skip"
        self.dropped: Counter[str] = Counter()
        self._files, self._bag = _resolve(self.path)
        self._topics_override = topics
        self._convention_override = range_convention
        self._indexes: list[_FileIndex] | None = None
        self._scanned: set[Path] = set()  # files already scanned (their warnings were logged)

    def __enter__(self) -> RecordingReader:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Nothing stays open between calls; kept for the context-manager protocol."""

    # ------------------------------------------------------------------------ info

    def info(self) -> RecordingInfo:
        """Topics, counts, times, size and custom data (reads the summary, or scans if none)."""
        indexes = self._file_indexes()
        topics: dict[str, metadata.TopicStats] = {}
        for index in indexes:
            for t in index.topics.values():
                old = topics.get(t.name)
                topics[t.name] = metadata.TopicStats(t.name, t.msgtype,
                                                     t.count + (old.count if old else 0))
        used = [i for i in indexes if any(t.count for t in i.topics.values())]
        return RecordingInfo(
            path=self.path, files=tuple(self._files), topics=tuple(topics.values()),
            start_ns=min((i.start_ns for i in used), default=0),
            end_ns=max((i.end_ns for i in used), default=0),
            size_bytes=sum(f.stat().st_size for f in self._files),
            custom_data=self.custom_data, closed=all(i.closed for i in indexes),
            range_convention=self.range_convention)

    @property
    def custom_data(self) -> dict[str, str]:
        """metadata.yaml ``custom_data`` over the MCAP ``tof_mpd_ros`` metadata records."""
        merged: dict[str, str] = {}
        for index in self._file_indexes():
            merged.update(index.custom)
        if self._bag is not None:
            merged.update(self._bag.custom_data)
        return merged

    @property
    def range_convention(self) -> str:
        if self._convention_override is not None:
            return self._convention_override
        value = self.custom_data.get(KEY_RANGE_CONVENTION)
        if value is None:
            return RADIAL
        if value not in CONVENTIONS:
            raise RecordingError(f"{self.path}: custom_data {KEY_RANGE_CONVENTION}={value!r} "
                                 f"is not one of {CONVENTIONS}")
        return value

    @property
    def topic_names(self) -> TopicNames:
        if self._topics_override is not None:
            return self._topics_override
        return TopicNames.from_custom_data(self.custom_data)

    def __len__(self) -> int:
        """Number of range images (frames, unless some cannot be assembled)."""
        return self.info().count(self.topic_names.range)

    # ------------------------------------------------------------------------ messages

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RecordedMessage]:
        """Stream decoded messages in file order.

        Args:
            topics: only these topics (default: all).

        Messages whose schema cannot be decoded (not ``ros2msg``/``cdr``) are skipped and
        counted in :attr:`dropped`.
        """
        wanted = None if topics is None else set(topics)
        for path in self._files:
            yield from self._file_messages(path, wanted)

    def _file_messages(self, path: Path, wanted: set[str] | None) -> Iterator[RecordedMessage]:
        # A closed file repeats its schemas and channels in the summary: start from those, so a
        # skipped corrupt chunk that declared a channel does not orphan the channel's messages.
        schemas, channels = _summary_records(path)
        decoders: dict[int, Any] = {}
        factory = DecoderFactory()
        report = self._report(path)
        for record in scan.iter_records(path, report):
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    self._bad(f"{path}: message on unknown channel {record.channel_id}",
                              "message without channel")
                    continue
                if wanted is not None and channel.topic not in wanted:
                    continue
                schema = schemas.get(channel.schema_id)
                decoded = self._decode(path, record, channel, schema, factory, decoders)
                if decoded is not None:
                    msgtype = normalise_type(schema.name) if schema else ""
                    yield RecordedMessage(channel.topic, msgtype, record.log_time, decoded)
        if report.corrupt_chunks:
            self.dropped["corrupt chunk"] += report.corrupt_chunks

    def _decode(self, path: Path, record: Message, channel: Channel, schema: Schema | None,
                factory: DecoderFactory, decoders: dict[int, Any]) -> Any:
        decoder = decoders.get(channel.id)
        if decoder is None:
            try:
                decoder = factory.decoder_for(channel.message_encoding, schema)
            except Exception as err:  # the msg parser raises anything on a bad schema
                _log.debug("schema of %s does not parse: %s", channel.topic, err)
                decoder = None
            if decoder is None:
                what = schema.name if schema else "no schema"
                key = f"undecodable {channel.topic} ({what}, {channel.message_encoding})"
                if not self.dropped[key]:
                    _log.warning("%s: skipping messages on %s: cannot decode %s/%s", path,
                                 channel.topic, what, channel.message_encoding)
                self.dropped[key] += 1
                return None
            decoders[channel.id] = decoder
        try:
            return decoder(record.data)
        except Exception as err:  # CDR decoding of corrupt bytes raises anything
            self._bad(f"{path}: message on {channel.topic} at {record.log_time} ns does not "
                      f"decode as {schema.name if schema else '?'}: {type(err).__name__}: "
                      f"{err}", "undecodable message")
            return None

    def _bad(self, problem: str, reason: str) -> None:
        if not self.skip_bad:
            raise RecordingError(problem)
        self.dropped[reason] += 1
        _log.warning("skipped: %s", problem)

    # ------------------------------------------------------------------------ frames

    def frames(self) -> Iterator[ToFFrame]:
        """Stream :class:`ToFFrame` objects, paired by header stamp (bounded memory).

        Each frame has radial ``range_mm`` and ``reference_mm`` (converted from z-depth when the
        recording says ``z``), intrinsics from CameraInfo, ``pose`` = camera-to-base (exact
        matrix topic, else ``tcp_pose @ hand_eye``) and the recording's modulation frequency.

        Raises:
            RecordingError: no range topic, a frame topic holding the wrong message type, or
                (``on_error="raise"``) a frame that cannot be built.
        """
        info = self.info()
        names = self.topic_names
        roles = topic_roles(names)
        counts = self._check_frame_topics(info, roles)
        assembler = FrameAssembler(
            source=str(self.path), plan=Plan.from_counts(counts),
            convention=info.range_convention, mod_freq_hz=self._mod_freq(info),
            skip_bad=self.skip_bad, dropped=self.dropped)
        wanted = {t for t, role in roles.items() if counts.get(role, 0) > 0}
        for m in self.messages(wanted):
            yield from assembler.add(roles[m.topic], m.message, m.log_time_ns)
        yield from assembler.finish()

    def _check_frame_topics(self, info: RecordingInfo, roles: dict[str, str]) -> dict[str, int]:
        """Messages per role; wrong types on required topics raise, on optional ones skip."""
        counts: dict[str, int] = {}
        for t in info.topics:
            role = roles.get(t.name)
            if role is None or t.count == 0:
                continue
            if normalise_type(t.msgtype) != ROLE_TYPES[role]:
                held = t.msgtype or "no schema"
                problem = (f"{self.path}: topic {t.name} holds {held}, expected "
                           f"{ROLE_TYPES[role]}")
                if role in REQUIRED_ROLES:
                    raise RecordingError(problem)
                _log.warning("%s; ignoring its %d messages", problem, t.count)
                self.dropped[f"wrong type on {t.name}"] += t.count
                continue
            counts[role] = t.count
        names = self.topic_names
        for role in REQUIRED_ROLES:
            if counts.get(role, 0) == 0:
                present = ", ".join(t.name for t in info.topics) or "none"
                raise RecordingError(f"{self.path}: no {ROLE_TYPES[role]} messages on "
                                     f"{getattr(names, role)} (topics: {present})")
        return counts

    def _mod_freq(self, info: RecordingInfo) -> float:
        value = info.custom_data.get(KEY_MOD_FREQ)
        if value is None:
            _log.warning("%s: recording does not state the modulation frequency; assuming "
                         "%g Hz", self.path, DEFAULT_MOD_FREQ_HZ)
            return DEFAULT_MOD_FREQ_HZ
        try:
            freq = float(value)
        except ValueError as err:
            raise RecordingError(f"{self.path}: custom_data {KEY_MOD_FREQ}={value!r} is not "
                                 "a number") from err
        if not (math.isfinite(freq) and freq > 0):
            raise RecordingError(f"{self.path}: custom_data {KEY_MOD_FREQ}={value!r} must "
                                 "be a finite number > 0")
        return freq

    # ------------------------------------------------------------------------ indexing

    def _file_indexes(self) -> list[_FileIndex]:
        if self._indexes is None:
            self._indexes = [_index_from_summary(p) or _index_by_scan(p, self._report(p))
                             for p in self._files]
        return self._indexes

    def _report(self, path: Path) -> scan.ScanReport:
        """A scan report that warns only on the first scan of ``path``."""
        report = scan.ScanReport(warn=path not in self._scanned, skip_corrupt=self.skip_bad)
        self._scanned.add(path)
        return report


def _resolve(path: Path) -> tuple[list[Path], metadata.BagMetadata | None]:
    """The ``.mcap`` files of a recording path and its metadata.yaml (if any)."""
    if not path.exists():
        raise RecordingError(f"{path}: no such recording")
    if path.is_file():
        sibling = path.parent / metadata.METADATA_FILE
        bag = None
        if sibling.exists():
            candidate = metadata.read(sibling)
            bag = candidate if path.name in {Path(f).name for f in candidate.files} else None
        return [path], bag
    meta_path = path / metadata.METADATA_FILE
    if meta_path.exists():
        bag = metadata.read(meta_path)
        files = [path / Path(f).name for f in bag.files]
        missing = [str(f) for f in files if not f.exists()]
        if missing or not files:
            raise RecordingError(f"{meta_path}: lists storage files that are missing: "
                                 f"{', '.join(missing) or 'none listed'}")
        return files, bag
    files = sorted(path.glob("*.mcap"))
    if not files:
        what = "empty directory" if not any(path.iterdir()) else "directory"
        raise RecordingError(f"{path}: {what} with neither {metadata.METADATA_FILE} nor "
                             ".mcap files; not a recording")
    _log.info("%s: no %s; reading %s alone", path, metadata.METADATA_FILE,
              ", ".join(f.name for f in files))
    return files, None


def _summary_records(path: Path) -> tuple[dict[int, Schema], dict[int, Channel]]:
    """Schemas and channels of a closed file's summary section ({} and {} otherwise)."""
    try:
        with open(path, "rb") as stream:
            size = scan.check_magic(stream, path)
            if not scan.file_is_closed(stream, size) or not scan.summary_intact(stream, size):
                return {}, {}
            stream.seek(0)
            summary = SeekingReader(stream).get_summary()
    except Exception:  # a damaged summary: the scan finds the records in the data section
        return {}, {}
    if summary is None:
        return {}, {}
    return dict(summary.schemas), dict(summary.channels)


def _index_from_summary(path: Path) -> _FileIndex | None:
    """Counts, times and custom data of a closed file from its summary section."""
    try:
        with open(path, "rb") as stream:
            size = scan.check_magic(stream, path)
            if not scan.file_is_closed(stream, size):
                return None
            if not scan.summary_intact(stream, size):
                _log.warning("%s: summary section fails its CRC; scanning the file", path)
                return None
            stream.seek(0)
            reader = SeekingReader(stream)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return None
            custom = _custom_from_metadata(reader.iter_metadata())
    except RecordingError:
        raise
    except Exception as err:  # a damaged summary: fall back to scanning the data section
        _log.warning("%s: unreadable summary section (%s); scanning the file", path, err)
        return None
    stats = summary.statistics
    index = _FileIndex(closed=True, start_ns=stats.message_start_time,
                       end_ns=stats.message_end_time, custom=custom)
    for channel_id, count in stats.channel_message_counts.items():
        channel = summary.channels.get(channel_id)
        if channel is None:
            continue
        schema = summary.schemas.get(channel.schema_id)
        _add_count(index, channel.topic, schema.name if schema else "", count)
    return index


def _index_by_scan(path: Path, report: scan.ScanReport) -> _FileIndex:
    """Counts, times and custom data of a file without a usable summary, by a scan."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata_records: list[Metadata] = []
    index = _FileIndex(closed=False)
    start, end = None, 0
    for record in scan.iter_records(path, report):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
            schema = schemas.get(record.schema_id)
            _add_count(index, record.topic, schema.name if schema else "", 0)
        elif isinstance(record, Metadata):
            metadata_records.append(record)
        elif isinstance(record, Message) and record.channel_id in channels:
            channel = channels[record.channel_id]
            schema = schemas.get(channel.schema_id)
            _add_count(index, channel.topic, schema.name if schema else "", 1)
            start = record.log_time if start is None else min(start, record.log_time)
            end = max(end, record.log_time)
    index.closed = report.closed
    index.custom = _custom_from_metadata(metadata_records)
    index.start_ns, index.end_ns = (start, end) if start is not None else (0, 0)
    return index


def _add_count(index: _FileIndex, topic: str, msgtype: str, count: int) -> None:
    old = index.topics.get(topic)
    index.topics[topic] = metadata.TopicStats(topic, normalise_type(msgtype) if msgtype else "",
                                              count + (old.count if old else 0))


def _custom_from_metadata(records: Iterable[Metadata]) -> dict[str, str]:
    merged: dict[str, str] = {}
    for record in records:
        if record.name == MCAP_METADATA_NAME:
            merged.update(record.metadata)
    return merged
