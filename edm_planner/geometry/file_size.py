"""File size limits, checked on a file before anything reads it.

The geometry loader (:class:`~.loader.FileAccess`), the blade mesh reader
(:func:`~.mesh_read.load_blade_mesh`) and the table readers (:mod:`.readers`)
refuse a file larger than the limit of its kind of file with the same message.
"""

import os

from ..errors import GeometryFileError


def too_large_message(where, path, size, limit, kind):
    """The message of a file larger than the limit for its ``kind`` of files ('yaml', 'mesh', 'table')."""
    return (f"{where}: {path} is {size} bytes, larger than the limit for {kind} files of {limit} bytes "
            f"({limit / 2 ** 20:.4g} MiB; geometry_loader parameter max_{kind}_bytes): not read")


def check_file_size(path, limit, where, kind):
    """GeometryFileError when the file at ``path`` is larger than ``limit`` bytes (checked without reading it)."""
    try:
        size = os.stat(path).st_size
    except OSError as exc:
        raise GeometryFileError(f"{where}: cannot read {path} ({exc.strerror or exc})") from None
    if size > limit:
        raise GeometryFileError(too_large_message(where, path, size, limit, kind))
