"""Make an HDF5 file left behind by a killed writer (kill -9, power cut) openable again.

Why: HDF5 ≥ 1.10 files in the 1.10 format or later (superblock version 3: the run files,
written with library-version bounds ("v110", "v110"), as SWMR needs) carry "file is open for
write" flags in the superblock; a writer that dies never clears them, and a plain open then
refuses the file ("file is already open for write ... h5clear"), in h5py as in Octave or MATLAB.
The recorder writes in SWMR mode, so everything up to its last flush is consistent on disk:
only the flags are stale. ``recover`` clears them in place, as ``h5clear -s`` does, without the
HDF5 tools; it rewrites nothing else, so the file keeps the format it was written in (readable
by HDF5 1.10 readers: tests/test_old_readers.py).

Superblock versions 2 and 3 (the only ones with these flags):
    signature (8) | version (1) | size of offsets O (1) | size of lengths (1) | flags (1) |
    base address (O) | extension address (O) | end-of-file address (O) | root object header (O) |
    checksum (4, Jenkins lookup3 of everything before it)

Decision records: docs/decisions/0004-swmr-hdf5-periodic-flush.md, docs/decisions/0018-hdf5-for-old-readers.md.
"""

from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass
from pathlib import Path

from daq.errors import InputError

SIGNATURE = b"\x89HDF\r\n\x1a\n"
FLAGS_OFFSET = 11
WRITE_ACCESS = 0x01  # H5F_SUPER_WRITE_ACCESS
SWMR_WRITE_ACCESS = 0x04  # H5F_SUPER_SWMR_WRITE_ACCESS
_MASK = 0xFFFFFFFF


def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & _MASK


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' hashlittle (lookup3), as HDF5's H5_checksum_lookup3, for superblock checksums."""
    length = len(data)
    a = b = c = (0xDEADBEEF + length + initval) & _MASK
    i = 0
    while length > 12:
        a = (a + int.from_bytes(data[i:i + 4], "little")) & _MASK
        b = (b + int.from_bytes(data[i + 4:i + 8], "little")) & _MASK
        c = (c + int.from_bytes(data[i + 8:i + 12], "little")) & _MASK
        a = (a - c) & _MASK; a ^= _rot(c, 4); c = (c + b) & _MASK  # noqa: E702
        b = (b - a) & _MASK; b ^= _rot(a, 6); a = (a + c) & _MASK  # noqa: E702
        c = (c - b) & _MASK; c ^= _rot(b, 8); b = (b + a) & _MASK  # noqa: E702
        a = (a - c) & _MASK; a ^= _rot(c, 16); c = (c + b) & _MASK  # noqa: E702
        b = (b - a) & _MASK; b ^= _rot(a, 19); a = (a + c) & _MASK  # noqa: E702
        c = (c - b) & _MASK; c ^= _rot(b, 4); b = (b + a) & _MASK  # noqa: E702
        length -= 12
        i += 12
    if length == 0:
        return c
    tail = bytes(data[i:]) + bytes(12)
    a = (a + int.from_bytes(tail[0:4], "little")) & _MASK
    b = (b + int.from_bytes(tail[4:8], "little")) & _MASK
    c = (c + int.from_bytes(tail[8:12], "little")) & _MASK
    c ^= b; c = (c - _rot(b, 14)) & _MASK  # noqa: E702
    a ^= c; a = (a - _rot(c, 11)) & _MASK  # noqa: E702
    b ^= a; b = (b - _rot(a, 25)) & _MASK  # noqa: E702
    c ^= b; c = (c - _rot(b, 16)) & _MASK  # noqa: E702
    a ^= c; a = (a - _rot(c, 4)) & _MASK  # noqa: E702
    b ^= a; b = (b - _rot(a, 14)) & _MASK  # noqa: E702
    c ^= b; c = (c - _rot(b, 24)) & _MASK  # noqa: E702
    return c


@dataclass(frozen=True)
class Superblock:
    """Where the superblock sits and what its first bytes say; enough to clear the flags safely."""

    base: int  # file offset of the signature (0 unless there is a user block)
    version: int
    raw: bytes  # from the signature up to and including the checksum (versions 2/3)

    @property
    def flags(self) -> int:
        return self.raw[FLAGS_OFFSET]

    @property
    def checksum_offset(self) -> int:
        return len(self.raw) - 4


def _find_signature(fh: io.BufferedIOBase, size: int) -> int | None:
    """HDF5 looks for the signature at 0, 512, 1024, 2048, ... (a user block may precede it)."""
    offset = 0
    while offset + len(SIGNATURE) <= size:
        fh.seek(offset)
        if fh.read(len(SIGNATURE)) == SIGNATURE:
            return offset
        offset = 512 if offset == 0 else offset * 2
    return None


def read_superblock(path: str | Path) -> Superblock | None:
    """The superblock of ``path``, or None if it is not an HDF5 file (no signature)."""
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            base = _find_signature(fh, size)
            if base is None:
                return None
            fh.seek(base)
            head = fh.read(12)
            if len(head) < 12:
                return None
            version, size_of_offsets = head[8], head[9]
            if version not in (2, 3):
                return Superblock(base, version, head)
            fh.seek(base)
            raw = fh.read(12 + 4 * size_of_offsets + 4)
    except OSError as exc:
        raise InputError(str(path), "(file)", exc.strerror or str(exc)) from None
    return Superblock(base, version, raw)


def is_unclean(path: str | Path) -> bool:
    """True if a writer left the file marked open for write (it died, or it is still writing)."""
    sb = read_superblock(path)
    if sb is None or sb.version not in (2, 3) or len(sb.raw) <= FLAGS_OFFSET:
        return False
    return bool(sb.flags & (WRITE_ACCESS | SWMR_WRITE_ACCESS))


def _checked(path: str | Path) -> Superblock:
    """The superblock, refusing anything we do not understand rather than guessing."""
    src = str(path)
    sb = read_superblock(path)
    if sb is None:
        raise InputError(src, "superblock", "no HDF5 signature: not an HDF5 file")
    if sb.version not in (2, 3):
        raise InputError(src, "superblock", f"version {sb.version} has no status flags to clear "
                                            "(only versions 2 and 3 are supported)")
    so = sb.raw[9]
    if so not in (2, 4, 8, 16, 32) or len(sb.raw) != 12 + 4 * so + 4:
        raise InputError(src, "superblock", f"truncated or invalid superblock (size of offsets {so})")
    stored = struct.unpack("<I", sb.raw[-4:])[0]
    computed = lookup3(sb.raw[:-4])
    if stored != computed:
        raise InputError(src, "superblock", f"checksum mismatch (stored {stored:#010x}, computed {computed:#010x}); "
                                            "refusing to modify a damaged file")
    return sb


def cleaned_superblock(sb: Superblock) -> bytes:
    """The superblock bytes with the status flags cleared and the checksum recomputed."""
    raw = bytearray(sb.raw)
    raw[FLAGS_OFFSET] = 0
    raw[-4:] = struct.pack("<I", lookup3(bytes(raw[:-4])))
    return bytes(raw)


def recover(path: str | Path) -> None:
    """Clear the open-for-write flags of a file whose writer died, in place, durably (like ``h5clear -s``).

    Do not call it on a file that a live writer still has open.
    """
    sb = _checked(path)
    if not sb.flags:
        return
    new = cleaned_superblock(sb)
    with open(path, "r+b") as fh:
        fh.seek(sb.base + FLAGS_OFFSET)
        fh.write(new[FLAGS_OFFSET:FLAGS_OFFSET + 1])
        fh.seek(sb.base + sb.checksum_offset)
        fh.write(new[-4:])
        fh.flush()
        os.fsync(fh.fileno())


class CleanView(io.RawIOBase):
    """A read-only view of an unclean HDF5 file whose superblock flags read as cleared.

    Why: lets a reader open a crashed recording that SWMR read mode refuses, without
    modifying the file (h5py accepts file-like objects).
    """

    def __init__(self, path: str | Path) -> None:
        super().__init__()
        sb = _checked(path)
        self._patch_at = sb.base
        self._patch = cleaned_superblock(sb)
        self._fh = open(path, "rb")
        self._pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        self._pos = self._fh.seek(offset, whence)
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, buf) -> int:
        self._fh.seek(self._pos)
        n = self._fh.readinto(buf)
        lo, hi = self._patch_at, self._patch_at + len(self._patch)
        start, end = max(lo, self._pos), min(hi, self._pos + n)
        if start < end:
            mv = memoryview(buf).cast("B")
            mv[start - self._pos:end - self._pos] = self._patch[start - lo:end - lo]
        self._pos += n
        return n

    def close(self) -> None:
        if not self.closed:
            self._fh.close()
        super().close()
