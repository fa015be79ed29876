"""Options of the plunge-roughing planner (units: mm and rad)."""

import math
from dataclasses import asdict, dataclass

from ..errors import EdmError, ErrorCode


class RoughingOptionsError(EdmError, ValueError):
    """Bad roughing options: an EdmError with code INVALID_REQUEST that is also a ValueError."""

    def __init__(self, message):
        super().__init__(ErrorCode.INVALID_REQUEST, message)


@dataclass(frozen=True)
class RoughingOptions:
    """Settings of :func:`edm_planner.roughing.plan_roughing`.

    Attributes
    ----------
    tool_radius : float or None
        Flat-bottomed tool radius r [mm]; None: the largest allowed, r_max of eq. 11.
    mu : float
        Safeguard factor of eq. 11 (the paper: 1.2 < mu < 1.5); >= 1.
    allowance : float
        delta [mm], > 0: the allowance left on the shroud (the target surface is the shroud's inner
        surface offset by it towards the axis) and on the blade walls (eq. 11, the machining area).
    residual_height : float
        h of eq. 13 [mm], > 0: the permissible residual thickness between neighbouring lines; the
        lines are 2 sqrt(2 r h) apart.
    step_tolerance : float
        epsilon of eq. 12 [mm], > 0: permissible chord error of the grooving step.
    max_step : float or None
        Largest grooving step [mm]; None: the tool radius (neighbouring plunges overlap).
    lateral_step : float or None
        Largest spacing of the plunges along an expansion line [mm]; None: the line spacing of eq. 13.
    root_points : int
        n of eq. 10, stations along the blade root (>= 3).
    bottom_rings, bottom_points : int
        Discretisation of the flat tool bottom: the centre and ``bottom_rings`` rings, the rim with
        ``bottom_points`` points (a multiple of 4).
    rotation_range : float
        The tool's rotations about its own x and y axes stay within +-this [rad] of the initial
        pose (the paper's first round: 0.1 pi).
    translation_range : (float, float)
        Range of the translation t along the initial tool axis [mm], positive away from the
        shroud (the paper: [0, 2] mm; here both ways by default, as the initial bottom centre lies
        on the target surface and the optimum may be beyond it).
    secondary_rotation_range : float
        Tightened rotation range of the secondary optimisation (paper 3.2: 0.05 pi) [rad].
    eta : float
        Step factor of eq. 9, in (0, 1].
    increment_tolerance : float
        Eq. 9 stops when the increment (rotations times the tool radius) is below this [mm].
    objective_tolerance : float
        ... or when the Hausdorff distance changes by less than this [mm].
    max_iterations : int
        N_max of eq. 9.
    polish : bool
        Run the trust-region minimax polish after the paper's iteration (reaches the optimum; see
        ``hausdorff``). Off: the paper's iteration alone.
    retract_height : float or None
        Retract distance along the tool axis from the optimised pose [mm]; None: until the bottom
        centre is ``retract_clearance`` below the hub radius (clear of the blades).
    retract_clearance : float
        [mm], >= 0.
    path_spacing : float
        Largest move of any point of the tool bottom between consecutive path samples [mm].
    """

    tool_radius: float = None
    mu: float = 1.3
    allowance: float = 0.3
    residual_height: float = 0.2
    step_tolerance: float = 0.02
    max_step: float = None
    lateral_step: float = None
    root_points: int = 101
    bottom_rings: int = 3
    bottom_points: int = 24
    rotation_range: float = 0.1 * math.pi
    translation_range: tuple = (-2.0, 2.0)
    secondary_rotation_range: float = 0.05 * math.pi
    eta: float = 0.5
    increment_tolerance: float = 1e-6
    objective_tolerance: float = 1e-7
    max_iterations: int = 50
    polish: bool = True
    retract_height: float = None
    retract_clearance: float = 2.0
    path_spacing: float = 0.5

    def __post_init__(self):
        def number(name, value, low=None, low_open=True, high=None, optional=False):
            if value is None and optional:
                return
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise RoughingOptionsError(f"{name} must be a finite number, got {value!r}")
            if low is not None and (value <= low if low_open else value < low):
                raise RoughingOptionsError(f"{name} must be {'>' if low_open else '>='} {low:g}, got {value!r}")
            if high is not None and value > high:
                raise RoughingOptionsError(f"{name} must be <= {high:g}, got {value!r}")

        def integer(name, value, low):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise RoughingOptionsError(f"{name} must be an integer >= {low}, got {value!r}")

        number("tool_radius [mm]", self.tool_radius, 0.0, optional=True)
        number("mu", self.mu, 1.0, low_open=False)
        number("allowance [mm]", self.allowance, 0.0)
        number("residual_height [mm]", self.residual_height, 0.0)
        number("step_tolerance [mm]", self.step_tolerance, 0.0)
        number("max_step [mm]", self.max_step, 0.0, optional=True)
        number("lateral_step [mm]", self.lateral_step, 0.0, optional=True)
        integer("root_points", self.root_points, 3)
        integer("bottom_rings", self.bottom_rings, 1)
        integer("bottom_points", self.bottom_points, 4)
        if self.bottom_points % 4:
            raise RoughingOptionsError(f"bottom_points must be a multiple of 4, got {self.bottom_points}")
        number("rotation_range [rad]", self.rotation_range, 0.0, high=0.5 * math.pi)
        number("secondary_rotation_range [rad]", self.secondary_rotation_range, 0.0, high=self.rotation_range)
        tr = self.translation_range
        if not isinstance(tr, (tuple, list)) or len(tr) != 2:
            raise RoughingOptionsError(f"translation_range must be (min, max) in mm, got {tr!r}")
        for v in tr:
            number("translation_range [mm]", v)
        if not tr[0] < tr[1]:
            raise RoughingOptionsError(f"translation_range: min must be below max, got {tr!r}")
        object.__setattr__(self, "translation_range", (float(tr[0]), float(tr[1])))
        number("eta", self.eta, 0.0, high=1.0)
        number("increment_tolerance [mm]", self.increment_tolerance, 0.0)
        number("objective_tolerance [mm]", self.objective_tolerance, 0.0)
        integer("max_iterations", self.max_iterations, 1)
        if not isinstance(self.polish, bool):
            raise RoughingOptionsError(f"polish must be true or false, got {self.polish!r}")
        number("retract_height [mm]", self.retract_height, 0.0, optional=True)
        number("retract_clearance [mm]", self.retract_clearance, 0.0, low_open=False)
        number("path_spacing [mm]", self.path_spacing, 0.0)

    def to_dict(self):
        d = asdict(self)
        d["translation_range"] = list(self.translation_range)
        return d
