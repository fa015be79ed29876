"""Arrays of an uncompressed ``.npz`` mapped from the file instead of read into memory.

``np.load`` ignores ``mmap_mode`` for ``.npz`` archives (numpy documents it
for ``.npy`` only) and reads every member whole: 2.6 s for the default
blisk's 226 MB field and 9 s for Rotor 37's 3.2 GB one, in every process that
loads it (checker, planner, the set designer's workers), each with its own
copy. ``np.savez`` stores members uncompressed, so each member's ``.npy``
data sits contiguous in the file; this maps it copy-on-write (``mode="c"``):
pages come from the page cache shared by every process, are read when first
touched, and a write (none is made) would stay private. Written by hand:
neither numpy nor another library maps ``.npz`` members; a directory of
``.npy`` files, which ``np.load(mmap_mode=...)`` maps, would lose the cache's
single-file atomic replace (a reader sees the old field or the new one).

Mapping skips what ``np.load`` does on a read, the zip's CRC-32 check, so
:func:`map_npz` checks it itself on every map: the CRC-32 of each member's
stored bytes, computed with zlib over the mapped file (in 16 MB blocks on a
few threads, zlib releases the GIL, joined by :func:`crc32_combine`), must
equal the one the archive stores, else ValueError and the caller rebuilds.
A flipped byte in the field that certification relies on is never used.
Measured on the 2-core machine of this repository while other jobs kept it
busy (load 4.6), the default blisk's 226 MB field warm in the page cache:
mapping its members 0.9 ms without the check, 115 ms with it (median of 7;
82 ms the fastest; zlib's CRC-32 runs at about 2.5 GB/s per core here); the
whole cached load of the field 47 ms without, 158 ms with it (median of 5).
The check reads every page once, so a cold cache costs the disk read a plain
``np.load`` would; Rotor 37's 3.2 GB field about 1.3 s of CRC on one core.
"""

import functools
import mmap
import os
import struct
import zipfile
import zlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np

_LOCAL_HEADER = struct.Struct("<4s22xHH")    # signature, ..., file name length, extra field length
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


#: bytes per CRC-32 block (a block is one zlib call; blocks of a member are joined by crc32_combine)
CRC_BLOCK = 16 << 20


def _gf2_times(matrix, vector):
    total, i = 0, 0
    while vector:
        if vector & 1:
            total ^= matrix[i]
        vector >>= 1
        i += 1
    return total


def _gf2_square(matrix):
    return [_gf2_times(matrix, matrix[n]) for n in range(32)]


@functools.lru_cache(maxsize=16)
def _zeros_operator(length):
    """The GF(2) operator (32 columns) that appends ``length`` zero bytes to a CRC-32 (zlib's crc32_combine)."""
    odd = [0xEDB88320] + [1 << n for n in range(31)]      # one zero bit
    even = _gf2_square(odd)                                # two
    odd = _gf2_square(even)                                # four
    result = None
    while length:                                          # square up to eight bits, sixteen, ...; pick length's bits
        even = _gf2_square(odd)
        if length & 1:
            result = even if result is None else [_gf2_times(even, c) for c in result]
        length >>= 1
        if not length:
            break
        odd = _gf2_square(even)
        if length & 1:
            result = odd if result is None else [_gf2_times(odd, c) for c in result]
        length >>= 1
    return result


def crc32_combine(crc1, crc2, len2):
    """CRC-32 of A + B from crc1 = CRC-32(A), crc2 = CRC-32(B) and len2 = len(B) (zlib's crc32_combine)."""
    if len2 <= 0:
        return crc1
    return _gf2_times(_zeros_operator(int(len2)), crc1) ^ crc2


def crc32_of(buffer, threads=None):
    """CRC-32 of a buffer (bytes-like), in CRC_BLOCK blocks on up to ``threads`` threads (default: the CPUs)."""
    with memoryview(buffer) as raw, raw.cast("B") as view:
        n = len(view)
        if n <= CRC_BLOCK:
            return zlib.crc32(view)
        starts = range(0, n, CRC_BLOCK)
        workers = max(1, min(int(threads or os.cpu_count() or 1), len(starts), 8))

        def block(s):
            with view[s:s + CRC_BLOCK] as b:
                return zlib.crc32(b)

        with ThreadPoolExecutor(max_workers=workers) as pool:
            parts = list(pool.map(block, starts))
    crc = parts[0]
    for s, part in zip(starts[1:], parts[1:]):
        crc = crc32_combine(crc, part, min(CRC_BLOCK, n - s))
    return crc


def map_npz(path, names, verify=True):
    """{name: array} for the members ``name + ".npy"`` of the ``.npz`` at ``path``, mapped from the file.

    With ``verify`` (the default) each member's CRC-32 is computed over the
    mapped bytes and compared with the archive's (see the module docstring).

    Raises ValueError for a compressed member, a member that is not a plain
    ``.npy`` array (object dtype), data beyond the file's end or a member
    whose CRC-32 differs from the archive's (a corrupt file); OSError,
    zipfile.BadZipFile as the file system and zipfile raise them.
    """
    out = {}
    with open(path, "rb") as f, zipfile.ZipFile(f) as archive:
        whole = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if verify else None
        try:
            for name in names:
                _map_member(f, archive, name, whole, out)
        finally:
            if whole is not None:
                whole.close()
    return out


def _map_member(f, archive, name, whole, out):
    """Map one member into ``out[name]``, its CRC-32 checked over ``whole`` (the file mapped) if given."""
    info = archive.getinfo(name + ".npy")
    if info.compress_type != zipfile.ZIP_STORED:
        raise ValueError(f"{name}: compressed in the archive")
    f.seek(info.header_offset)
    signature, name_len, extra_len = _LOCAL_HEADER.unpack(f.read(_LOCAL_HEADER.size))
    if signature != b"PK\x03\x04":
        raise ValueError(f"{name}: no local file header")
    start = info.header_offset + _LOCAL_HEADER.size + name_len + extra_len
    if whole is not None:
        if start + info.compress_size > len(whole):
            raise ValueError(f"{name}: member beyond the end of the file")
        with memoryview(whole) as view, view[start:start + info.compress_size] as member:
            got = crc32_of(member)
        if got != info.CRC:
            raise ValueError(f"{name}: CRC-32 {got:08x} of the mapped member differs from the archive's "
                             f"{info.CRC:08x}: the file is corrupt")
    f.seek(start)
    version = np.lib.format.read_magic(f)
    if version not in _HEADER_READERS:
        raise ValueError(f"{name}: .npy format {version}")
    shape, fortran, dtype = _HEADER_READERS[version](f)
    if dtype.hasobject:
        raise ValueError(f"{name}: object array")
    offset = f.tell()
    size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if offset + size > info.header_offset + _LOCAL_HEADER.size + name_len + extra_len + info.file_size:
        raise ValueError(f"{name}: data beyond the member")
    if size == 0:
        out[name] = np.empty(shape, dtype=dtype, order="F" if fortran else "C")
        return
    mapped = np.memmap(f, dtype=dtype, mode="c", offset=offset, shape=shape, order="F" if fortran else "C")
    out[name] = mapped.view(np.ndarray)       # a plain array over the mapping (numba takes no memmap)
