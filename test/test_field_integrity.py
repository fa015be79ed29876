"""The cached distance field is verified when it is mapped (issue 23): a flipped byte is detected and rebuilt.

``npz_map.map_npz`` maps the cache's members instead of reading them, which skips the zip's CRC-32 check
``np.load`` does; it computes each member's CRC-32 over the mapped bytes itself. Units: mm.
"""

import logging
import os
import zipfile
import zlib

import numpy as np
import pytest

from edm_planner.interference.fast import FastChannelField
from edm_planner.interference.npz_map import CRC_BLOCK, crc32_combine, crc32_of, map_npz

ARRAYS = [name.lstrip("_") for name in FastChannelField._ARRAYS]


def coarse_field(blisk, cache_dir, key):
    """A quick field (0.6 mm, few error samples), cached under ``key``."""
    return FastChannelField(blisk, spacing=0.6, cache_dir=cache_dir, cache_key=key, error_samples=300)


def member_data(path, name):
    """(offset of the member's stored bytes in the file, their length) of ``name.npy``."""
    with open(path, "rb") as f, zipfile.ZipFile(f) as archive:
        info = archive.getinfo(name + ".npy")
        f.seek(info.header_offset + 26)
        name_len, extra_len = np.frombuffer(f.read(4), dtype="<u2")
        return info.header_offset + 30 + int(name_len) + int(extra_len), info.compress_size


def flip(path, offset, bit=0x10):
    with open(path, "r+b") as f:
        f.seek(offset)
        byte = f.read(1)[0]
        f.seek(offset)
        f.write(bytes([byte ^ bit]))


def test_blockwise_crc_is_zlibs_crc():
    """The CRC-32 computed in blocks on threads and joined equals zlib's over the whole buffer, at every
    block boundary case (empty, one block, one byte past a block, several blocks and a remainder)."""
    rng = np.random.default_rng(23)
    for n in (0, 1, 4095, CRC_BLOCK, CRC_BLOCK + 1, 2 * CRC_BLOCK + 12345):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        for threads in (1, 2, 3):
            assert crc32_of(data, threads=threads) == zlib.crc32(data), \
                f"blockwise CRC-32 of {n} bytes on {threads} thread(s) differs from zlib's"
    a, b = b"electrode", b"discharge gap 0.1 mm"
    assert crc32_combine(zlib.crc32(a), zlib.crc32(b), len(b)) == zlib.crc32(a + b), "crc32_combine is not zlib's"


@pytest.mark.parametrize("member, where", [("grid", 0.5), ("kind", 0.999), ("line_uv", 0.0)])
def test_a_flipped_byte_in_the_cached_field_is_detected_and_the_field_rebuilt(default_geometry, tmp_path, caplog,
                                                                             member, where):
    b = default_geometry.blisk
    built = coarse_field(b, tmp_path, "geom-crc")
    (path,) = tmp_path.glob("*.npz")
    original = path.read_bytes()
    pts = built.error_sample_points(300, seed=23)
    want = built.clearances(pts)
    assert coarse_field(b, tmp_path, "geom-crc").build_seconds == 0, "a sound cache must be loaded, not rebuilt"

    start, length = member_data(path, member)
    offset = start + min(int(where * length), length - 1)      # where=0: the .npy header's first byte
    flip(path, offset)
    assert path.read_bytes() != original, "the test must really have damaged the file"
    if where > 0:
        # without the check the damaged bytes would be mapped and used as they are
        unchecked = map_npz(path, ARRAYS, verify=False)[member]
        with np.load(_clean(tmp_path, original)) as data:        # np.load itself checks the CRC
            clean = data[member]
        assert not np.array_equal(unchecked.view(np.uint8), clean.view(np.uint8)), \
            "a mapping without the CRC check returns the flipped byte (this is what the check catches)"
        with pytest.raises(ValueError, match=f"{member}: CRC-32 .* differs from the archive's .* corrupt"):
            map_npz(path, ARRAYS)

    with caplog.at_level(logging.WARNING, logger="edm_planner.interference.fast"):
        again = coarse_field(b, tmp_path, "geom-crc")
    assert again.build_seconds > 0, "a corrupt cache must be rebuilt, never used"
    assert "unusable" in caplog.text and "rebuilding" in caplog.text and member in caplog.text, \
        f"the corrupt cache must be reported, naming the member: {caplog.text}"
    np.testing.assert_array_equal(again.clearances(pts), want,
                                  err_msg="the rebuilt field answers as the original did")
    # the rebuild rewrote the cache: it now loads (verified) without another build, with the same answers
    reloaded = coarse_field(b, tmp_path, "geom-crc")
    assert reloaded.build_seconds == 0 and "loaded_from" in reloaded.stats, "the rewritten cache must load"
    np.testing.assert_array_equal(reloaded.clearances(pts), want, err_msg="the reloaded field answers as before")


def _clean(tmp_path, original):
    clean = tmp_path / "clean" / "field.npz"
    os.makedirs(clean.parent, exist_ok=True)
    clean.write_bytes(original)
    return clean
