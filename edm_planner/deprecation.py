"""Names that moved, kept importable from their old modules for one release with a DeprecationWarning.

A module whose names moved keeps a PEP 562 ``__getattr__`` that imports the new home when an old name is
asked for and hands it out through :func:`moved_name`, which warns. The old modules import nothing at load
time, so they add no import cycle; the upward imports inside their ``__getattr__`` are listed, one by one, as
allowed in the layer contract (``.importlinter``) until :data:`REMOVED_IN`. CHANGELOG.md lists every moved name.
"""

import warnings

#: the release in which the old names are removed
REMOVED_IN = "0.3.0"


def moved_name(old_module, name, *new_modules):
    """The attribute ``name`` of the first of ``new_modules`` that has it, with a DeprecationWarning.

    Raises
    ------
    AttributeError
        No new home has ``name`` (or it is a dunder: ``__path__``, ``__all__``, ... are not forwarded).
    """
    if not name.startswith("__"):
        for module in new_modules:
            if hasattr(module, name):
                warnings.warn(f"{old_module}.{name} is deprecated: it moved to {module.__name__}.{name} (issue 27); "
                              f"the old name is removed in {REMOVED_IN}", DeprecationWarning, stacklevel=3)
                return getattr(module, name)
    raise AttributeError(f"module {old_module!r} has no attribute {name!r}")
