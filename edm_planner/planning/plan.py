"""The result of planning one channel: a certified, densely sampled axis path.

A :class:`Plan` is what the planner returns, what the trajectory_planner node
serves and publishes, what ``edm-plan plan`` exports and what the axis bridge
times. Axis values are machine axis values (X, Y, Z [mm], A, C(, B) [rad])
in feed order: the first sample is the start pose outside the blisk, the last
the final machining pose in the plan's channel (A includes channel * pitch).
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import ErrorCode
from ..interference import SURFACES
from .objective import Weights
from .search import SearchOptions

#: axis names per machine configuration (the free axes of the search, plus X, Y, Z)
AXIS_NAMES = {4: ("X", "Y", "Z", "C"), 5: ("X", "Y", "Z", "A", "C"), 6: ("X", "Y", "Z", "A", "C", "B")}


@dataclass(frozen=True)
class PlanOptions:
    """Settings of a channel plan (mm, rad, s).

    Attributes
    ----------
    search : SearchOptions
        The exit search (method, reference, axes, step, margins, weights, seed, time budget).
    sample_spacing : float
        Largest move of any electrode vertex between consecutive samples of the plan [mm].
    size_electrode : bool
        Search the smallest circumferential reduction h with a certified path (bisection).
    sizing_tolerance : float
        Bracket width at which the sizing stops [rad].
    """

    search: SearchOptions = field(default_factory=SearchOptions)
    sample_spacing: float = 0.05
    size_electrode: bool = False
    sizing_tolerance: float = 0.002

    def __post_init__(self):
        for name in ("sample_spacing", "sizing_tolerance"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive number, got {v!r}")


@dataclass
class PlanMetrics:
    """Figures of a plan (PlanMetrics.msg). Units: mm, rad, s.

    The clearances, per surface in the order of SURFACES, mean one thing each:

    * ``clearance_lower_bound``: certified lower bound over the whole continuous
      path, of the electrode as designed (its vertices' field clearance less
      the field's error bound and the electrode's chord tolerance, carried
      between samples by the certificate's Lipschitz bound); at least the
      plan's margins;
    * ``clearance_exact``: the exact minimum signed clearance of every
      electrode vertex at every sample of the plan (``verify_poses``; the
      vertices move at most ``sample_spacing`` between samples); NaN where
      not computed.
    """

    node_count: int = 0
    path_length: float = 0.0                     # mm, path of the electrode origin
    clearance_lower_bound: tuple = (float("nan"),) * 4   # mm, certified, over the continuous path
    clearance_exact: tuple = (float("nan"),) * 4         # mm, exact, every vertex at every sample
    objfun1: float = 0.0                         # Huang eq. 4, summed over nodes
    objfun2: float = 0.0                         # Huang eq. 5, summed over nodes
    axis_names: tuple = ()
    smoothness: tuple = ()                       # per axis: sum of squared second differences at the nodes
    sharp_points: tuple = ()                     # per axis: sign changes of the axis velocity
    solver_evaluations: int = 0
    planning_time: float = 0.0                   # s
    certified: bool = False
    circumferential_reduction: float = 0.0       # rad

    #: the per-surface clearance fields, stored as {surface: value} mappings
    CLEARANCES = ("clearance_lower_bound", "clearance_exact")

    def by_surface(self, name):
        """``{surface: value}`` of one of :attr:`CLEARANCES` [mm]."""
        return dict(zip(SURFACES, (float(v) for v in getattr(self, name))))

    def to_dict(self):
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        for k in self.CLEARANCES:
            d[k] = self.by_surface(k)
        for k in ("axis_names", "smoothness", "sharp_points"):
            d[k] = list(d[k])
        return d

    @classmethod
    def from_dict(cls, d):
        """The metrics of :meth:`to_dict` (a stored record); a clearance it lacks is NaN."""
        d = dict(d)
        for k in cls.CLEARANCES:
            v = d.get(k)
            d[k] = tuple(float(v[s]) if v and v.get(s) is not None else float("nan") for s in SURFACES)
        for k in ("axis_names", "smoothness", "sharp_points"):
            d[k] = tuple(d.get(k, ()))
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


@dataclass
class Plan:
    """A channel plan, or why there is none.

    Attributes
    ----------
    plan_id : str
    error_code : ErrorCode
        SUCCESS only for a certified plan.
    message : str
    geometry_id : str
    channel : int
    electrode_id : str
    electrode_mesh : trimesh.Trimesh
        The exact mesh that was checked, in the electrode frame [mm].
    final_pose : (4, 4) float
        Electrode frame -> W at the machining pose in channel 0.
    options : PlanOptions
    axis_names : tuple of str
    samples : (N, k) float
        Axis values in feed order, dense (``options.sample_spacing``).
    poses : (N, 4, 4) float
        Electrode frame -> W for each sample, in the plan's channel.
    nodes : (n, k) float
        Axis values of the search nodes, feed order.
    metrics : PlanMetrics
    furthest_node, furthest_reference, blocking_surface, blocking_clearance_lower_bound
        On failure: how far the search got [nodes, mm] and what blocked it [mm].
    cycle : MachiningCycle or None
        The whole machining cycle around the feed (approach, feed, process,
        return, retract; :mod:`edm_planner.machining.cycle`), axis values in
        the plan's channel; None for a feed-only plan.
    removal : dict or None
        The material-removal proof of the electrode set this plan belongs to
        (``RemovalReport.to_dict()``: stock and overcut per surface, accuracy); None when not proven.
    set_id : str
        The electrode set this plan belongs to ('' for none).
    """

    plan_id: str
    error_code: ErrorCode
    message: str
    geometry_id: str
    channel: int
    electrode_id: str
    electrode_mesh: object
    final_pose: np.ndarray
    options: PlanOptions
    axis_names: tuple
    samples: np.ndarray
    poses: np.ndarray
    nodes: np.ndarray
    metrics: PlanMetrics
    furthest_node: int = 0
    furthest_reference: float = 0.0
    blocking_surface: str = ""
    blocking_clearance_lower_bound: float = float("nan")
    cycle: object = None
    removal: dict = None
    set_id: str = ""

    @property
    def success(self):
        return self.error_code == ErrorCode.SUCCESS


def plan_options_from_dict(d):
    """:class:`PlanOptions` from ``dataclasses.asdict`` of one (as stored with a plan)."""
    d = dict(d)
    search = dict(d.pop("search"))
    search["weights"] = Weights(**{k: tuple(v) for k, v in search["weights"].items()})
    return PlanOptions(search=SearchOptions(**search), **d)
