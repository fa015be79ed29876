"""Where exports may be written: inside the configured export directory, never outside (no rclpy).

The nodes write exports under their ``export_dir`` parameter, named by plan,
set or sequence ids. An id comes from a request or a message, so it is
untrusted: :func:`export_path` accepts a plain name only (letters, digits,
``.``, ``_``, ``-``; no separator, no ``..``, not absolute, not hidden, at
most 128 characters), and refuses a name whose path in the directory is a
symbolic link, or an existing export directory holding one (a link planted
there would carry the write elsewhere). The export directory itself may be a
link (the operator's configuration); what is checked is that the written
path resolves inside it. :func:`open_for_export` opens a file without
following a link at its last component (``O_NOFOLLOW``), so a link planted
between the check and the write is refused too.
"""

import os
import pathlib
import re

from .errors import EdmError, ErrorCode

#: what a name of an export (a file or directory in the export directory) may be
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}")


def check_export_name(name, what="export name"):
    """INVALID_REQUEST unless ``name`` is a plain file name that stays in its directory."""
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name) or ".." in name:
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"{what} {name!r} cannot name an export: only letters, digits, '.', '_' and '-' (not first), "
                       f"no '..', no path separators, at most 128 characters")
    return name


def _inside(real, root):
    return os.path.commonpath([real, root]) == root


def export_path(directory, name, what="export name", suffixes=("",)):
    """The path ``directory/name`` checked to stay inside ``directory``.

    Parameters
    ----------
    directory : path
        The export directory (created if missing; may itself be a symlink).
    name : str
        The export's name (checked with :func:`check_export_name`).
    suffixes : sequence of str
        The files that will be written (``name + suffix`` each, e.g. ``(".nc", ".csv")``); ``("",)`` for a
        file or directory named ``name``.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    EdmError
        INVALID_REQUEST for a name that is not plain, FILE_ERROR for a path that is (or holds) a symbolic link
        or resolves outside the directory, or a directory that cannot be created.
    """
    check_export_name(name, what)
    try:
        os.makedirs(directory, exist_ok=True)
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"export directory {directory}: {exc}") from None
    root = os.path.realpath(directory)
    base = pathlib.Path(directory) / name
    for suffix in suffixes:
        path = pathlib.Path(str(base) + suffix)
        if path.is_symlink() or not _inside(os.path.realpath(path), root):
            raise EdmError(ErrorCode.FILE_ERROR, f"export {path} is a symbolic link or leads outside the export "
                                                 f"directory {root}: not written (remove the link)")
        if path.is_dir():
            for dirpath, dirnames, filenames in os.walk(path):
                for entry in dirnames + filenames:
                    inner = pathlib.Path(dirpath) / entry
                    if inner.is_symlink():
                        raise EdmError(ErrorCode.FILE_ERROR,
                                       f"export directory {path} holds a symbolic link {inner} (to "
                                       f"{os.path.realpath(inner)}): not written there (remove the link)")
    return base


def open_for_export(path, mode="w"):
    """Open ``path`` for writing without following a symbolic link at its last component.

    Raises
    ------
    EdmError
        FILE_ERROR naming the path (a link there, or any other failure to open it).
    """
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"cannot write the export {path}: {exc.strerror or exc} (a symbolic "
                                             f"link there is never followed)") from None
    return os.fdopen(fd, mode)
