"""Machine axis configuration (``config/machine.yaml``): joint names, directions, limits.

Every key names its unit (``_mm``, ``_rad``, ``_mm_s``, ``_rad_s2`` ...); linear
axes (X, Y, Z) take the millimetre keys, rotary axes (A, B, C) the radian keys,
so a unit mix-up is an unknown key, not a silent factor of 57.

The machine joint value is ``direction * planner value + offset``; travel limits
are given in joint coordinates, velocity/acceleration/jerk limits as magnitudes.
"""

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..errors import EdmError, ErrorCode
from ..geometry.loader import LimitedSafeLoader
from .dialect import DEFAULT_DIALECT, DIALECT_DIR, STRUCTURES, load_dialect
from .process_model import DEFAULT_PROCESS, ProcessModel, parse_process

LINEAR = ("X", "Y", "Z")
ROTARY = ("A", "B", "C")
_MACHINE_KEYS = {"name", "a_zero_rad", "c_pivot_mm"}
#: the planner's machines (SearchOptions.axes): rotary axes of each, besides X, Y, Z
ROTARY_SETS = {4: ("C",), 5: ("A", "C"), 6: ("A", "C", "B")}


def _axis_keys(unit):
    """Allowed keys of one axis and which are required (unit 'mm' or 'rad')."""
    required = {"joint", f"min_{unit}", f"max_{unit}", f"velocity_max_{unit}_s", f"acceleration_max_{unit}_s2"}
    optional = {"direction", f"offset_{unit}", f"jerk_max_{unit}_s3"}
    return required, required | optional


@dataclass(frozen=True)
class AxisLimits:
    """One machine axis.

    Attributes
    ----------
    name : str
        Planner axis name (X, Y, Z, A, B, C).
    joint : str
        Controller joint name.
    direction : float
        +1 or -1: joint = direction * planner + offset.
    offset : float
        [mm or rad].
    position_min, position_max : float
        Travel in joint coordinates [mm or rad].
    velocity_max : float
        [mm/s or rad/s].
    acceleration_max : float
        [mm/s^2 or rad/s^2].
    jerk_max : float
        [mm/s^3 or rad/s^3]; inf when not configured.
    """

    name: str
    joint: str
    direction: float
    offset: float
    position_min: float
    position_max: float
    velocity_max: float
    acceleration_max: float
    jerk_max: float = math.inf

    @property
    def unit(self):
        return "mm" if self.name in LINEAR else "rad"

    def to_joint(self, q):
        return self.direction * np.asanyarray(q, dtype=np.float64) + self.offset


@dataclass(frozen=True)
class MachineConfig:
    """The configured machine: axis limits by planner axis name, A0, C pivot."""

    name: str
    axes: dict
    a_zero: float = 0.0                  # rad
    c_pivot: tuple = (0.0, 0.0, 0.0)     # mm, electrode frame
    process: ProcessModel = DEFAULT_PROCESS   # the EDM process (regimes, wear); section ``process:``
    nc: dict = None                      # section ``nc:``: ``dialect`` (name or path), ``structure``

    @property
    def axis_names(self):
        """Planner axis names in the configured (joint) order."""
        return tuple(self.axes)

    def check_axes(self, axis_names):
        """INVALID_REQUEST unless ``axis_names`` (a plan's axes) are exactly this machine's axes, in any order.

        A 4-axis plan (no A: X, Y, Z, C in channel 0, the blisk indexed outside the path) cannot run on a
        5-axis machine as it stands, nor a 5-axis plan on a 6-axis machine (B would be left undefined).
        """
        names = list(axis_names)
        missing = [a for a in names if a not in self.axes]
        unused = [a for a in self.axes if a not in names]
        repeated = sorted({a for a in names if names.count(a) > 1})
        if missing or unused or repeated:
            what = []
            if missing:
                what.append(f"{missing} not configured")
            if unused:
                what.append(f"machine axes {unused} not in the plan")
            if repeated:
                what.append(f"{repeated} repeated")
            raise EdmError(ErrorCode.INVALID_REQUEST,
                           f"plan axes {names} do not match machine {self.name!r} (a {len(self.axes)}-axis machine: "
                           f"{list(self.axes)}): "
                           + "; ".join(what) + f". A {len(set(names))}-axis plan needs a {len(set(names))}-axis "
                           f"machine file (config/machine.yaml: 5 axes, machine_4axis.yaml, machine_6axis.yaml)")

    def limits_for(self, axis_names):
        """Axis limits in the order of ``axis_names`` (a plan's axes); INVALID_REQUEST if they are not the machine's."""
        self.check_axes(axis_names)
        return [self.axes[a] for a in axis_names]

    def joint_order(self, axis_names):
        """Indices into ``axis_names`` giving the machine's configured axis (joint) order."""
        self.check_axes(axis_names)
        names = list(axis_names)
        return [names.index(a) for a in self.axes]

    def joint_names(self, axis_names):
        return [lim.joint for lim in self.limits_for(axis_names)]


def _number(value, where):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}: expected a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}: must be finite, got {value!r}")
    return value


def _axis(name, entry, source):
    where = f"{source}: axes.{name}"
    if name not in LINEAR + ROTARY:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}: unknown axis (known: {list(LINEAR + ROTARY)})")
    if not isinstance(entry, dict):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}: expected a mapping, got {entry!r}")
    unit = "mm" if name in LINEAR else "rad"
    required, allowed = _axis_keys(unit)
    unknown = sorted(set(entry) - allowed)
    if unknown:
        other = "rad" if unit == "mm" else "mm"
        hint = f" ({'linear' if unit == 'mm' else 'rotary'} axis: use the _{unit} keys, not _{other})" \
            if any(other in k for k in unknown) else ""
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}: unknown keys {unknown}{hint}; allowed {sorted(allowed)}")
    missing = sorted(required - set(entry))
    if missing:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}: missing keys {missing}")
    joint = entry["joint"]
    if not isinstance(joint, str) or not joint.strip():
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}.joint: expected a non-empty joint name, got {joint!r}")
    direction = _number(entry.get("direction", 1), f"{where}.direction")
    if direction not in (1.0, -1.0):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}.direction: must be +1 or -1, got {direction:g}")
    lo, hi = (_number(entry[f"{k}_{unit}"], f"{where}.{k}_{unit}") for k in ("min", "max"))
    if lo >= hi:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}: min_{unit} ({lo:g}) must be below max_{unit} ({hi:g})")
    limits = {}
    for key in (f"velocity_max_{unit}_s", f"acceleration_max_{unit}_s2", f"jerk_max_{unit}_s3"):
        if key not in entry:
            continue
        v = _number(entry[key], f"{where}.{key}")
        if v <= 0:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"{where}.{key}: must be positive, got {v:g}")
        limits[key.split("_max")[0]] = v
    return AxisLimits(name=name, joint=joint.strip(), direction=direction,
                      offset=_number(entry.get(f"offset_{unit}", 0.0), f"{where}.offset_{unit}"),
                      position_min=lo, position_max=hi, velocity_max=limits["velocity"],
                      acceleration_max=limits["acceleration"], jerk_max=limits.get("jerk", math.inf))


def parse_machine(doc, source="<machine>"):
    """A parsed machine YAML document -> MachineConfig (INVALID_REQUEST naming the key on any fault)."""
    if not isinstance(doc, dict):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: expected a mapping with 'machine' and 'axes'")
    unknown = sorted(set(doc) - {"machine", "axes", "process", "nc"})
    if unknown:
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"{source}: unknown top-level keys {unknown} (allowed: machine, axes, process, nc)")
    machine = doc.get("machine") or {}
    if not isinstance(machine, dict):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: machine: expected a mapping")
    unknown = sorted(set(machine) - _MACHINE_KEYS)
    if unknown:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: machine: unknown keys {unknown}; "
                                                  f"allowed {sorted(_MACHINE_KEYS)}")
    pivot = machine.get("c_pivot_mm", [0.0, 0.0, 0.0])
    if not isinstance(pivot, (list, tuple)) or len(pivot) != 3:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: machine.c_pivot_mm: expected 3 numbers, got {pivot!r}")
    pivot = tuple(_number(v, f"{source}: machine.c_pivot_mm[{i}]") for i, v in enumerate(pivot))
    axes = doc.get("axes")
    if not isinstance(axes, dict) or not axes:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: axes: expected a mapping of axis name -> limits")
    parsed = {str(name): _axis(str(name), entry, source) for name, entry in axes.items()}
    for need in LINEAR:
        if need not in parsed:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: axes: {need} missing (X, Y, Z are required)")
    rotary = {a for a in parsed if a in ROTARY}
    if rotary not in [set(v) for v in ROTARY_SETS.values()]:
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"{source}: axes: rotary axes {sorted(rotary)} are none of the planner's machines "
                       f"(4 axes: C; 5 axes: A, C; 6 axes: A, C, B)")
    if "B" in parsed and any(pivot):
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"{source}: machine.c_pivot_mm: a C pivot with a B axis is not modelled (B and C must "
                       f"intersect at the electrode origin): got {list(pivot)}")
    joints = [a.joint for a in parsed.values()]
    if len(set(joints)) != len(joints):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: axes: joint names must be unique, got {joints}")
    return MachineConfig(name=str(machine.get("name", "")), axes=parsed,
                         a_zero=_number(machine.get("a_zero_rad", 0.0), f"{source}: machine.a_zero_rad"),
                         c_pivot=pivot, process=parse_process(doc.get("process"), source),
                         nc=_parse_nc(doc.get("nc"), source))


def _parse_nc(section, source):
    """The ``nc:`` section: the control's dialect and the program structure (the dialect loaded to check it)."""
    section = {} if section is None else section
    if not isinstance(section, dict) or set(section) - {"dialect", "structure"}:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: nc: expected a mapping with dialect and structure, "
                                                  f"got {section!r}")
    dialect = str(section.get("dialect", DEFAULT_DIALECT))
    if dialect.endswith((".yaml", ".yml")) and not Path(dialect).is_absolute():
        here = Path(source).parent if source and not source.startswith("<") else DIALECT_DIR
        dialect = str((here / dialect).resolve())         # relative to the machine file
    load_dialect(dialect)
    structure = str(section.get("structure", "subprograms"))
    if structure not in STRUCTURES:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: nc.structure must be one of {STRUCTURES}, got "
                                                  f"{structure!r}")
    return {"dialect": dialect, "structure": structure}


#: largest machine YAML read [bytes] (a machine file is a few kB)
MAX_MACHINE_BYTES = 1_000_000


def load_machine(path):
    """Read a machine YAML file. FILE_ERROR: unreadable, too large or not YAML; INVALID_REQUEST: bad content.

    Read as geometry YAML is (:class:`~edm_planner.geometry.loader.LimitedSafeLoader`: plain data, limits on
    depth, aliases and expanded nodes), at most :data:`MAX_MACHINE_BYTES`.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:                      # at most the limit and a byte: /dev/zero ends too
            data = f.read(MAX_MACHINE_BYTES + 1)
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"machine file {path}: {exc.strerror or exc}") from None
    if len(data) > MAX_MACHINE_BYTES:
        raise EdmError(ErrorCode.FILE_ERROR, f"machine file {path}: larger than {MAX_MACHINE_BYTES} bytes")
    try:
        doc = yaml.load(data.decode("utf-8"), Loader=LimitedSafeLoader)
    except UnicodeDecodeError:
        raise EdmError(ErrorCode.FILE_ERROR, f"machine file {path}: not UTF-8 text") from None
    except yaml.YAMLError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"machine file {path}: not valid YAML: {exc}") from None
    except RecursionError:
        raise EdmError(ErrorCode.FILE_ERROR, f"machine file {path}: YAML nested too deeply to read") from None
    return parse_machine(doc, str(path))


def default_machine_path():
    """config/machine.yaml of the source tree (editable install) or of share/edm_planner."""
    here = Path(__file__).resolve().parents[2] / "config" / "machine.yaml"
    if here.exists():
        return here
    return Path(sys.prefix) / "share" / "edm_planner" / "config" / "machine.yaml"
