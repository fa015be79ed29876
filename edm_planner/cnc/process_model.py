"""The EDM process model: discharge regimes and wear limits (the ``process:`` section of the machine YAML).

A die-sinking EDM's gap servo advances the electrode only as fast as the discharges erode the workpiece,
so a cutting leg takes (removed volume) / (the regime's volumetric removal rate), however fast the axes
could move. Each regime (a generator setting, the control's *condition*) has a spark gap per side, a
removal rate, a volumetric electrode wear ratio and a surface roughness. The defaults are for copper
electrodes on a nickel superalloy (Inconel 718 class); they are model inputs to calibrate on the shop's own
generator table (see ``config/machine.yaml`` for the sources and what each value stands for).

Every figure computed from this model is a **model estimate** with these inputs, not a measurement.
It lives in ``machine``, below the ``process`` layer that computes with it, because the machine
configuration (:mod:`.config`) reads it; :mod:`edm_planner.process.model` re-exports its names.
Units: mm, mm^3/min, %, um (Ra), as every key says. No rclpy.
"""

import math
from dataclasses import dataclass

from ..errors import EdmError, ErrorCode

#: the regimes every process model has: roughing, then finishing to size
REQUIRED_REGIMES = ("rough", "finish")

_REGIME_KEYS = {"spark_gap_mm", "removal_rate_mm3_min", "wear_ratio_percent", "roughness_ra_um",
                "condition_code"}
_PROCESS_KEYS = {"regimes", "finish_allowance_mm", "allowance_band_mm", "wear_tolerance_mm",
                 "wear_compensation", "max_compensated_wear_mm", "rough_and_finish"}


@dataclass(frozen=True)
class Regime:
    """One discharge regime (generator setting).

    Attributes
    ----------
    name : str
    spark_gap : float
        Spark gap per side [mm]: the electrode erodes what lies within it.
    removal_rate : float
        Volumetric material removal rate [mm^3/min].
    wear_ratio : float
        Volumetric electrode wear ratio [%]: electrode volume lost per workpiece volume removed.
    roughness_ra : float
        Surface roughness Ra it leaves [um].
    condition_code : str
        The control's code that selects the regime (e.g. ``C120``, ``E190``).
    """

    name: str
    spark_gap: float
    removal_rate: float
    wear_ratio: float
    roughness_ra: float
    condition_code: str

    def erosion_seconds(self, volume):
        """Time to erode ``volume`` [mm^3] at this regime's removal rate [s] (a model estimate)."""
        return 60.0 * float(volume) / self.removal_rate

    def to_dict(self):
        return {"name": self.name, "spark_gap_mm": self.spark_gap, "removal_rate_mm3_min": self.removal_rate,
                "wear_ratio_percent": self.wear_ratio, "roughness_ra_um": self.roughness_ra,
                "condition_code": self.condition_code}


@dataclass(frozen=True)
class ProcessModel:
    """The configured EDM process.

    Attributes
    ----------
    regimes : dict of str -> Regime
        At least ``rough`` and ``finish``.
    finish_allowance : float
        Stock the roughing electrode leaves for the finishing one on every wall [mm].
    allowance_band : float
        The roughing proof's allowance must lie within finish_allowance +- this [mm].
    wear_tolerance : float
        Largest face wear of a finishing electrode without compensation [mm]: beyond it a new
        electrode (or a redressing) is needed (a roughing electrode may take ``allowance_band``).
    wear_compensation : bool
        The control feeds deeper by the estimated frontal wear (the machine allows it).
    max_compensated_wear : float
        With compensation: the largest frontal wear an electrode may accumulate before the corner
        rounding it brings spoils the form [mm].
    rough_and_finish : bool
        Design a roughing electrode for every piece (False: today's single-regime set, the finishing
        electrode removes everything at the finish regime).
    """

    regimes: dict
    finish_allowance: float = 0.1
    allowance_band: float = 0.03
    wear_tolerance: float = 0.02
    wear_compensation: bool = False
    max_compensated_wear: float = 0.5
    rough_and_finish: bool = True

    @property
    def rough(self):
        return self.regimes["rough"]

    @property
    def finish(self):
        return self.regimes["finish"]

    @property
    def rough_electrode_gap(self):
        """Offset of the roughing electrode from the walls [mm]: the rough spark gap plus the allowance."""
        return self.rough.spark_gap + self.finish_allowance

    def wear_limit(self, regime="finish"):
        """The face wear one electrode may take before it is replaced or redressed [mm], uncompensated.

        A finishing electrode's wear shows in the part, so ``wear_tolerance``; a roughing electrode's only
        adds to the allowance it leaves, so ``allowance_band``. With wear compensation the front may wear
        further, as far as the compensation's certified reach (at most ``max_compensated_wear``;
        :func:`~.report.compensation_schedule`); the other faces keep this limit.
        """
        return self.allowance_band if regime == "rough" else self.wear_tolerance

    def to_dict(self):
        return {"regimes": {k: r.to_dict() for k, r in self.regimes.items()},
                "finish_allowance_mm": self.finish_allowance, "allowance_band_mm": self.allowance_band,
                "wear_tolerance_mm": self.wear_tolerance, "wear_compensation": self.wear_compensation,
                "max_compensated_wear_mm": self.max_compensated_wear, "rough_and_finish": self.rough_and_finish}


#: copper on a nickel superalloy; the sources and what the values stand for are in config/machine.yaml
DEFAULT_PROCESS = ProcessModel(regimes={
    "rough": Regime("rough", spark_gap=0.25, removal_rate=40.0, wear_ratio=3.0, roughness_ra=8.0,
                    condition_code="C180"),
    "finish": Regime("finish", spark_gap=0.10, removal_rate=4.0, wear_ratio=15.0, roughness_ra=1.6,
                     condition_code="C120"),
})

# (lowest, highest) accepted, per key: beyond them a value is a unit slip, not a regime
_RANGES = {"spark_gap_mm": (0.005, 1.0), "removal_rate_mm3_min": (1e-3, 1e5), "wear_ratio_percent": (0.0, 200.0),
           "roughness_ra_um": (0.01, 100.0)}


def _bad(source, where, message):
    raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: process.{where}: {message}")


def _value(entry, key, source, where, low, high, default=None):
    if key not in entry:
        if default is None:
            _bad(source, where, f"missing key {key!r}")
        return default
    v = entry[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        _bad(source, f"{where}.{key}", f"expected a finite number, got {v!r}")
    v = float(v)
    if v < 0:
        _bad(source, f"{where}.{key}", f"must not be negative, got {v:g}")
    if not low <= v <= high:
        _bad(source, f"{where}.{key}", f"{v:g} is out of range [{low:g}, {high:g}] (check the unit in the key)")
    return v


def _regime(name, entry, source):
    where = f"regimes.{name}"
    if not isinstance(entry, dict):
        _bad(source, where, f"expected a mapping, got {entry!r}")
    unknown = sorted(set(entry) - _REGIME_KEYS)
    if unknown:
        _bad(source, where, f"unknown keys {unknown}; allowed {sorted(_REGIME_KEYS)}")
    values = {k: _value(entry, k, source, where, *_RANGES[k]) for k in _RANGES}
    code = entry.get("condition_code")
    if not isinstance(code, str) or not code.strip():
        _bad(source, f"{where}.condition_code", f"expected the control's regime code as text, got {code!r}")
    return Regime(name, values["spark_gap_mm"], values["removal_rate_mm3_min"], values["wear_ratio_percent"],
                  values["roughness_ra_um"], code.strip())


def parse_process(doc, source="<machine>"):
    """The ``process:`` mapping of a machine YAML -> ProcessModel; None or absent -> the defaults.

    A given section overrides the defaults key by key (a regime given whole replaces its default).
    INVALID_REQUEST names the key of a missing, negative or out-of-range value.
    """
    if doc is None:
        return DEFAULT_PROCESS
    if not isinstance(doc, dict):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{source}: process: expected a mapping, got {doc!r}")
    unknown = sorted(set(doc) - _PROCESS_KEYS)
    if unknown:
        _bad(source, "", f"unknown keys {unknown}; allowed {sorted(_PROCESS_KEYS)}")
    regimes = dict(DEFAULT_PROCESS.regimes)
    given = doc.get("regimes", {})
    if not isinstance(given, dict):
        _bad(source, "regimes", f"expected a mapping of regime name -> settings, got {given!r}")
    for name, entry in given.items():
        regimes[str(name)] = _regime(str(name), entry, source)
    d = DEFAULT_PROCESS
    model = ProcessModel(
        regimes=regimes,
        finish_allowance=_value(doc, "finish_allowance_mm", source, "", 0.005, 2.0, d.finish_allowance),
        allowance_band=_value(doc, "allowance_band_mm", source, "", 0.001, 1.0, d.allowance_band),
        wear_tolerance=_value(doc, "wear_tolerance_mm", source, "", 0.001, 1.0, d.wear_tolerance),
        wear_compensation=_flag(doc, "wear_compensation", source, d.wear_compensation),
        max_compensated_wear=_value(doc, "max_compensated_wear_mm", source, "", 0.001, 10.0, d.max_compensated_wear),
        rough_and_finish=_flag(doc, "rough_and_finish", source, d.rough_and_finish))
    if model.rough.spark_gap < model.finish.spark_gap:
        _bad(source, "regimes.rough.spark_gap_mm", f"the rough gap {model.rough.spark_gap:g} mm is smaller than "
                                                   f"the finish gap {model.finish.spark_gap:g} mm")
    if model.rough_electrode_gap > 0.5:     # ElectrodeDesign's discharge-gap range
        _bad(source, "finish_allowance_mm", f"rough spark gap + finish allowance = {model.rough_electrode_gap:g} mm "
                                            f"exceeds the 0.5 mm an electrode offset may have")
    return model


def _flag(doc, key, source, default):
    v = doc.get(key, default)
    if not isinstance(v, bool):
        _bad(source, key, f"expected true or false, got {v!r}")
    return v
