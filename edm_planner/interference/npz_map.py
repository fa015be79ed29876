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
"""

import struct
import zipfile

import numpy as np

_LOCAL_HEADER = struct.Struct("<4s22xHH")    # signature, ..., file name length, extra field length
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def map_npz(path, names):
    """{name: array} for the members ``name + ".npy"`` of the ``.npz`` at ``path``, mapped from the file.

    Raises ValueError for a compressed member, a member that is not a plain
    ``.npy`` array (object dtype) or data beyond the file's end; OSError,
    zipfile.BadZipFile as the file system and zipfile raise them.
    """
    out = {}
    with open(path, "rb") as f, zipfile.ZipFile(f) as archive:
        for name in names:
            info = archive.getinfo(name + ".npy")
            if info.compress_type != zipfile.ZIP_STORED:
                raise ValueError(f"{name}: compressed in the archive")
            f.seek(info.header_offset)
            signature, name_len, extra_len = _LOCAL_HEADER.unpack(f.read(_LOCAL_HEADER.size))
            if signature != b"PK\x03\x04":
                raise ValueError(f"{name}: no local file header")
            f.seek(info.header_offset + _LOCAL_HEADER.size + name_len + extra_len)
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
                continue
            mapped = np.memmap(f, dtype=dtype, mode="c", offset=offset, shape=shape, order="F" if fortran else "C")
            out[name] = mapped.view(np.ndarray)       # a plain array over the mapping (numba takes no memmap)
    return out
