"""Read every array of an ``.npz`` file that may be corrupt or hostile, without pickle.

``np.load`` trusts each member's ``.npy`` header: it allocates the array the header declares
before reading a byte of it (a header claiming 10^12 pixels asks for terabytes), and the zip
layer raises whatever its damage calls for (``NotImplementedError``, ``RuntimeError``,
``zlib.error``, ...). Here each header is checked against the size of its member first, the data
is read exactly (so the zip's CRC is checked), and every failure becomes the caller's typed error
naming the file and the problem. Every ``.npz`` a user hands the package (weights,
calibrations, forest arrays, the NPZ interchange) goes through :func:`read_npz`, the one reader
of untrusted files; the golden frames committed with the tests are read with ``np.load``.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import IO

import numpy as np

from .errors import TofMpdError

_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0,
                   (2, 0): np.lib.format.read_array_header_2_0}


# Deflate cannot expand data more than about 1032:1, so a member claiming more is lying.
_MAX_DEFLATE_RATIO = 1032
_BLOCK = 1 << 20  # bytes read at a time into the array


def read_npz(path: Path, error: type[TofMpdError], what: str = ".npz") -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` at ``path``, keyed like ``np.load`` (``.npy`` stripped).

    Memory follows the file: an array is allocated only once its header agrees with the
    member's size, and a member's size only counts once it fits the file (stored members) or
    deflate's largest expansion of its compressed bytes.

    Args:
        path: the file.
        error: the caller's error type.
        what: what the file should be, for the message of an unreadable file.

    Raises:
        error: not a zip, a damaged member, a header that does not match its data, an object
            (pickled) array, or a read failure; the message starts with ``path``.
    """
    try:
        size = path.stat().st_size
        with zipfile.ZipFile(path) as archive:
            return {_key(info.filename): _read_member(archive, info, size)
                    for info in archive.infolist()}
    except _Refused as err:
        raise error(f"{path}: {err}") from None
    except Exception as err:  # zipfile, zlib and numpy raise many types on damaged data
        raise error(f"{path}: is not a readable {what} ({type(err).__name__}: {err})") from err


class _Refused(Exception):
    """A member this reader will not load; the message says why."""


def _key(filename: str) -> str:
    return filename[:-4] if filename.endswith(".npy") else filename


def _check_sizes(info: zipfile.ZipInfo, archive_size: int) -> None:
    """Refuse member sizes the file cannot back (before they size any allocation)."""
    name, packed, unpacked = info.filename, info.compress_size, info.file_size
    if packed > archive_size:
        raise _Refused(f"{name} claims {packed} compressed bytes in a {archive_size}-byte file")
    if info.compress_type == zipfile.ZIP_STORED and unpacked != packed:
        raise _Refused(f"{name} is stored uncompressed but claims {unpacked} bytes in {packed}")
    if info.compress_type == zipfile.ZIP_DEFLATED and unpacked > _MAX_DEFLATE_RATIO * packed:
        raise _Refused(f"{name} claims {unpacked} bytes from {packed} deflated bytes")
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise _Refused(f"{name} uses zip compression method {info.compress_type}; numpy "
                       "writes stored or deflated members only")


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo,
                 archive_size: int) -> np.ndarray:
    _check_sizes(info, archive_size)
    with archive.open(info) as member:
        shape, fortran_order, dtype = _header(member, info.filename)
        count = int(np.prod(shape, dtype=object))
        declared = count * dtype.itemsize
        stored = info.file_size - member.tell()
        if declared != stored:
            raise _Refused(f"{info.filename} declares {shape} {dtype} ({declared} bytes) but "
                           f"holds {stored} bytes")
        array = np.empty(count, dtype)
        if declared:
            _read_into(member, array.view(np.uint8), info.filename)
        if member.read(1):  # also makes zipfile check the member's CRC
            raise _Refused(f"{info.filename} holds more than its {declared} bytes")
    return array.reshape(shape, order="F" if fortran_order else "C")


def _read_into(member: IO[bytes], out: np.ndarray, name: str) -> None:
    """Fill ``out`` (uint8) from ``member`` a block at a time (no second full-size copy)."""
    done = 0
    while done < out.size:
        block = member.read(min(_BLOCK, out.size - done))
        if not block:
            raise _Refused(f"{name} ends after {done} of its {out.size} bytes")
        out[done:done + len(block)] = np.frombuffer(block, np.uint8)
        done += len(block)


def _header(member: IO[bytes], name: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    version = np.lib.format.read_magic(member)
    if version not in _HEADER_READERS:
        raise _Refused(f"{name}: unsupported .npy format version {version}")
    shape, fortran_order, dtype = _HEADER_READERS[version](member)
    if dtype.hasobject:
        raise _Refused(f"holds object arrays ({name}), which would need pickle (refused)")
    return shape, fortran_order, dtype
