"""Results kept on disk by content: the key is a digest of everything the result depends on, code included.

What the electrode cache (:mod:`.electrode_cache`), the workpiece deviation cache
(:func:`.mesh_deviation.cached_channel_mesh_deviation`) and the electrode.stl text cache
(``records.plan_export._electrode_stl``) share: a key (sha256 of a JSON document that names the format,
the inputs and every source file of the package, :func:`~edm_planner.environment.package_sources_digest`),
files written whole or not at all (a temporary file, then a rename, so a reader never meets half a file),
and the least recently used files removed beyond a count. A cache that cannot be written costs the
computation only, never the answer: :func:`get_or_make` logs it and returns the result.
"""

import functools
import hashlib
import json
import logging
import os
import pathlib

import numpy as np

from ..environment import package_sources_digest

_log = logging.getLogger(__name__)


@functools.cache
def code_digest():
    """The package's sources digest, read once per process: the code this process runs."""
    return package_sources_digest()


def content_key(doc):
    """Hex sha256 of ``doc`` (JSON, keys sorted) with the package's sources digest added as ``"code"``."""
    doc = dict(doc, code=code_digest())
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def arrays_digest(*arrays):
    """Hex sha256 of arrays' shapes, dtypes and bytes (C order): a key of their content, a mesh's say."""
    digest = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        digest.update(f"{a.shape}{a.dtype.str}".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


def write_whole(path, write):
    """``write(file)`` into a temporary file next to ``path``, then renamed to it: whole or not at all."""
    path = pathlib.Path(path)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as out:
            write(out)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def mark_used(path):
    """Touch ``path``: the most recently used file is kept longest."""
    try:
        os.utime(path)
    except OSError:                                  # removed by another process meanwhile
        pass


def forget_oldest(folder, pattern, keep):
    """Remove the files of ``folder`` matching ``pattern`` beyond the ``keep`` most recently used."""
    def used(path):
        try:
            return path.stat().st_mtime
        except OSError:                              # removed by another process meanwhile
            return float("inf")

    for old in sorted(pathlib.Path(folder).glob(pattern), key=used, reverse=True)[keep:]:
        try:
            old.unlink()
        except OSError:                              # another process removed it first
            pass


def get_or_make(path, read, make, write, *, keep, what):
    """The result cached at ``path``, else ``make()``, written there for the next call.

    ``read(path)`` returns the result, or None where the file is missing or unusable (it logs why);
    ``write(file, result)`` writes it into a binary file. A hit marks the file used; a new file is
    written whole and its folder kept to the ``keep`` most recently used files of its suffix. A cache
    that cannot be written costs only the computation: logged as ``what``.
    """
    path = pathlib.Path(path)
    result = read(path)
    if result is not None:
        mark_used(path)
        return result
    result = make()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_whole(path, lambda out: write(out, result))
        forget_oldest(path.parent, f"*{path.suffix}", keep)
    except OSError as exc:
        _log.warning("%s cache %s: not written (%s); computed on every call", what, path.parent, exc)
    return result


def get_or_make_json(path, make, *, fmt, keep, what, encode=None, decode=None):
    """:func:`get_or_make` for a result kept as JSON: ``{"format": fmt, "value": encode(result)}``.

    ``decode(value)`` makes the result of a file's value again (it may raise KeyError, TypeError or
    ValueError for a value it cannot use); a file that is unreadable, of another format or not
    decodable is logged as ``what`` and the result computed again and written over it. JSON keeps every
    float bit for bit (``repr`` round-trips).
    """
    encode = encode or (lambda result: result)
    decode = decode or (lambda value: value)

    def read(file):
        try:
            doc = json.loads(pathlib.Path(file).read_text(encoding="utf-8"))
            if not isinstance(doc, dict) or doc.get("format") != fmt:
                raise ValueError(f"not of format {fmt}")
            return decode(doc["value"])
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            _log.warning("%s cache %s: unusable (%s); computed again", what, file, exc)
            return None

    def write(out, result):
        out.write(json.dumps({"format": fmt, "value": encode(result)}, sort_keys=True).encode())

    return get_or_make(path, read, make, write, keep=keep, what=what)
