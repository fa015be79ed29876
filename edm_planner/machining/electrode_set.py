"""Automatic electrode set: the fewest electrodes that machine a channel to its tolerance, with proof.

When neither the request nor the geometry file names an electrode design,
the set is designed here (Huang II: reduction and division; Liu 2024 4.1:
left/right split). Candidates, in order of electrode count:

1. one electrode (no split);
2. front/rear (Huang) and left/right (Liu), each with an overlap;
3. three axial pieces (front, middle, rear) where two are not enough;
4. front/rear x left/right (four electrodes), four and five axial pieces,
   before the set is declared infeasible.

For every piece of a candidate the radial reduction and then the
circumferential reduction are sized by bisection, each step a certified
plan with the machining margin (discharge gap less the tolerance): the
smallest radial reduction (least shroud stock) first, then the smallest h
(the thickest electrode). Each piece's full cycle (approach, feed, copy
processing, return, retract; :mod:`.cycle`) is built and certified, and the
candidate's swept electrodes go through the material-removal simulation
(:mod:`.removal`). A candidate is accepted (:func:`acceptance`) when on
every wall the area whose stock exceeds the EDM corner rounding by more than
the tolerance (``area_fraction_beyond_inherent``) is at most
``max_area_above`` of its area, and nothing is overcut beyond the tolerance.
The corner rounding (what an ideal electrode leaves in the concave corners,
radius = gap) is computed from the walls' own geometry
(:func:`.corner_rounding.corner_rounding_stock`), not by this module's design code,
so a fault of the design is never written off as inherent. The strict
share against sharp corners (``area_fraction_above_tolerance``) is reported
beside it, not accepted on. Among the accepted candidates with the fewest
electrodes the thickest set (largest electrode volume) wins, then the
shortest cycle. Every candidate tried is reported with why it was rejected.
"""

import hashlib
import json
import logging
import os
import pickle
import threading
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import asdict, dataclass, field, replace

import numba
import numpy as np

from .. import deprecation
from ..budget import budget_clock
from ..errors import EdmError, ErrorCode
from ..geometry.electrode import ElectrodeDesign, design_electrodes
from ..geometry.frames import rotation_about_x
from ..interference import SURFACES
from ..interference.fast import FastChannelField
from ..cnc.kinematics import axis_poses
from ..planning.certify import AGREEMENT_ACCURACY
from ..planning.plan import PlanOptions
from ..planning.planner import add_exact_clearance, plan_channel, plan_id_for
from . import proof_path
from .corner_rounding import corner_rounding_stock
from .cycle import CycleBuilder, CycleOptions, shift_channel
from .proof_path import proof_samples
from .removal import simulate_removal
from .executors import LOCAL, drain, kind_for, make_executor
from .set_progress import SetDesignCancelled, SetProgress
from .swept_stock import Sweep
from .wall_samples import wall_samples

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SetOptions:
    """Settings of the automatic electrode set (mm, rad, s).

    Attributes
    ----------
    tolerance : float
        Stock and overcut tolerance [mm]; also the machining margin's allowance below the gap.
    max_area_above : float
        Largest share of a wall's area allowed to keep stock above the tolerance.
    overlap : float
        Overlap of split electrodes [mm].
    radial_start : float
        First radial reduction tried, as a share of the smallest channel height.
    radial_resolution, circumferential_resolution : float
        Bisection resolutions [mm], [rad].
    removal_spacing : float
        Wall sample spacing of the removal simulation [mm].
    time_budget : float
        For the whole set [s], numba's one-time compilation not counted (:mod:`edm_planner.budget`).
    max_electrodes : int
        Candidates with more electrodes are not tried.
    """

    tolerance: float = 0.02
    max_area_above: float = 0.01
    overlap: float = 1.0
    radial_start: float = 0.15
    radial_resolution: float = 0.25
    circumferential_resolution: float = 0.004
    removal_spacing: float = 0.25
    time_budget: float = 900.0
    max_electrodes: int = 5

    def __post_init__(self):
        for name in ("tolerance", "overlap", "radial_start", "radial_resolution", "circumferential_resolution",
                     "removal_spacing", "time_budget"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not 0 <= self.max_area_above < 1:
            raise ValueError(f"max_area_above must lie in [0, 1), got {self.max_area_above!r}")
        if int(self.max_electrodes) < 1:
            raise ValueError(f"max_electrodes must be >= 1, got {self.max_electrodes!r}")


@dataclass
class Piece:
    """One electrode of a candidate set and how it was sized and planned."""

    label: str                       # front, rear, left, right, middle, main
    electrode_id: str                # the id within its design
    design: ElectrodeDesign
    plan: object = None              # Plan (channel 0 while designing)
    cycle: object = None             # MachiningCycle (channel-0 axis values)
    tried: list = field(default_factory=list)   # [(h, radial, result)]
    volume: float = 0.0              # electrode volume [mm^3]
    regime: str = "finish"           # the process regime it erodes in: rough (a roughing twin) or finish

    def to_dict(self):
        d = {"label": self.label, "electrode_id": self.electrode_id, "regime": self.regime,
             "design": self.design.to_dict(), "volume_mm3": round(self.volume, 1),
             "sizing": [{"circumferential_reduction_rad": round(h, 5), "radial_reduction_mm": round(r, 4),
                         "result": res} for h, r, res in self.tried]}
        if self.plan is not None:
            d["plan_id"] = self.plan.plan_id
        if self.cycle is not None:
            d["cycle"] = {"certified": self.cycle.certified, "message": self.cycle.message,
                          "reach": self.cycle.reach.to_dict(), "samples": int(len(self.cycle.samples))}
        return d


@dataclass
class Candidate:
    """A candidate set: its pieces, and whether and why it was accepted or rejected."""

    name: str
    pieces: list
    status: str = "not tried"        # accepted, chosen, infeasible, stock left, overcut, disagreement, not tried,
    reason: str = ""                 # time budget
    removal: object = None           # RemovalReport
    truth: dict = None               # certificate_against_proof: per surface, the bound and the proof side by side
    cycle_travel: float = 0.0        # mm of vertex travel over all pieces' cycles
    process: object = None           # ProcessReport of the delivered candidate (process.set_process)
    rough_removal: object = None     # RemovalReport of its roughing twins (rough spark gap)
    allowance: dict = None           # how uniform the allowance the twins leave is (rough_finish.allowance_figures)
    single_regime_reason: str = ""   # why the delivered set has no roughing twins ('' : it has them)
    roughing_notes: list = field(default_factory=list)   # pieces without a twin, and why

    @property
    def electrode_count(self):
        return len(self.pieces)

    @property
    def volume(self):
        return float(sum(p.volume for p in self.pieces))

    def to_dict(self):
        d = {"name": self.name, "electrodes": self.electrode_count, "status": self.status, "reason": self.reason,
             "electrode_volume_mm3": round(self.volume, 1), "cycle_travel_mm": round(self.cycle_travel, 1),
             "pieces": [p.to_dict() for p in self.pieces]}
        if self.removal is not None:
            d["removal"] = self.removal.to_dict()
        if self.truth is not None:
            d["certificate_vs_proof"] = self.truth
        if self.process is not None:
            d["process"] = self.process.to_dict()
            d["single_regime_reason"] = self.single_regime_reason
            d["roughing_notes"] = list(self.roughing_notes)
        if self.rough_removal is not None:
            d["roughing_removal"] = self.rough_removal.to_dict()
            d["roughing_allowance"] = self.allowance
        return d


@dataclass
class ElectrodeSet:
    """The designed set of a channel, every candidate tried, and the proof of the chosen one."""

    geometry_id: str
    channel: int
    candidates: list
    chosen: Candidate = None
    planning_time: float = 0.0
    message: str = ""
    set_id: str = ""
    program_id: str = ""
    closest: Candidate = None

    @property
    def delivered(self):
        """The chosen candidate, or (when none machines to the tolerance) the closest certified one."""
        return self.chosen if self.chosen is not None else self.closest

    @property
    def plans(self):
        """The delivered set's plans in machining order (each with its cycle and the set's proof)."""
        return [] if self.delivered is None else [p.plan for p in self.delivered.pieces]

    @property
    def success(self):
        return self.chosen is not None

    def to_dict(self):
        return {"set_id": self.set_id, "program_id": self.program_id,
                "geometry_id": self.geometry_id, "channel": self.channel, "success": self.success,
                "message": self.message, "planning_time_s": round(self.planning_time, 2),
                "chosen": None if self.chosen is None else self.chosen.name,
                "delivered": None if self.delivered is None else self.delivered.name,
                "meets_tolerance": self.chosen is not None,
                "candidates": [c.to_dict() for c in self.candidates]}


#: insets of the electrodes' axial range from the closed channel's ends tried, as shares of its length
EDGE_INSETS = (0.0005, 0.001, 0.002, 0.005)
#: how finely the inset is bisected between a share of EDGE_INSETS that fails and the next that designs
EDGE_INSET_RESOLUTION = 0.0002


def set_id_for(geometry_id, channel, plan_options, options, cycle_options, process=None, process_resolution=0.5,
               stock_sha256=""):
    """Deterministic id of a set request (equal requests give equal sets): (set id, whole-blisk program id)."""
    parts = ["electrode_set", geometry_id, int(channel), asdict(plan_options), asdict(options), asdict(cycle_options)]
    if process is not None:                      # the process model changes the set (twins, leg regimes)
        parts += [process.to_dict(), float(process_resolution)]
    if stock_sha256:                             # and so does the stock it starts from
        parts.append(stock_sha256)
    key = json.dumps(parts, sort_keys=True, default=str)
    set_id = hashlib.sha256(key.encode()).hexdigest()[:16]
    return set_id, hashlib.sha256(f"blisk_program/{set_id}".encode()).hexdigest()[:16]


#: the share of a design's progress its EDM process step takes (roughing twins and their proof, removed volume):
#: about a fifth of a first design of the default blisk (6.4 of 32 s on an AMD EPYC Zen 4, 2026-11-29)
PROCESS_SHARE = 0.2

#: piece labels of the axial splits (front to rear); each is an export directory's name
AXIAL_LABELS = {3: ("front", "middle", "rear"), 4: ("front", "middle1", "middle2", "rear"),
                5: ("front", "middle1", "middle2", "middle3", "rear")}


def axial_ranges(x0, x1, count, overlap):
    """``count`` equal axial ranges over [x0, x1], neighbours overlapping by ``overlap`` [mm]."""
    cuts = np.linspace(x0, x1, count + 1)
    return [(float(x0) if i == 0 else float(cuts[i] - overlap / 2),
             float(x1) if i == count - 1 else float(cuts[i + 1] + overlap / 2)) for i in range(count)]


def candidate_sets(blisk, base, options):
    """The candidates in order of electrode count: (name, [(label, electrode_id, design)]).

    One electrode; front/rear (Huang) and left/right (Liu); three axial
    pieces; then, where those fail, front/rear x left/right (four
    electrodes: each axial half split left and right), four and five axial
    pieces. Up to ``options.max_electrodes`` electrodes.
    """
    ov = options.overlap
    out = [("one electrode", [("main", "main", replace(base, split="none"))]),
           ("front/rear", [(lab, lab, replace(base, split="front_rear", split_overlap=ov))
                           for lab in ("front", "rear")]),
           ("left/right", [(lab, lab, replace(base, split="left_right", split_overlap=ov))
                           for lab in ("left", "right")])]
    if base.axial_range is not None:
        x0, x1 = base.axial_range
    else:
        fx0, fx1 = blisk.full_span_axial_range
        inset = 0.005 * (fx1 - fx0)
        x0, x1 = fx0 + inset, fx1 - inset

    def axial(count):
        return [(lab, "main", replace(base, split="none", axial_range=r))
                for lab, r in zip(AXIAL_LABELS[count], axial_ranges(x0, x1, count, ov))]

    out.append(("three axial pieces", axial(3)))
    halves = axial_ranges(x0, x1, 2, ov)
    out.append(("front/rear x left/right",
                [(f"{half}-{side}", side, replace(base, split="left_right", split_overlap=ov, axial_range=r))
                 for half, r in zip(("front", "rear"), halves) for side in ("left", "right")]))
    out.append(("four axial pieces", axial(4)))
    out.append(("five axial pieces", axial(5)))
    return [c for c in out if len(c[1]) <= options.max_electrodes]


class SetDesigner:
    """Designs the electrode set of one channel.

    Parameters
    ----------
    geometry : LoadedGeometry
    field : FastChannelField
    plan_options : PlanOptions
        Search settings; the margins are raised to the machining margin.
    options : SetOptions
    cycle_options : CycleOptions
    progress : callable, optional
        ``progress(stage, fraction, message)``.
    detail : callable, optional
        ``detail(SetProgress)``: the same reports, structured (candidate, piece, sizing step and
        values, fraction, elapsed and estimated time left; :mod:`.set_progress`), also from the workers.
    field_cache : (str, str), optional
        (cache directory, cache key) of ``field``: with it the pieces of a
        candidate are sized in parallel worker processes (``workers``, default
        the CPU count), each loading the field from that cache.
    workers : int, optional
    ray_address : str
        A Ray cluster's address ("host:port", "auto"): the tasks (pieces, proof shares) run there as Ray tasks
        (:mod:`.executors`); "" : none.
    executor : str, optional
        "local" (spawn worker processes) or "ray" (a local Ray started on demand, or the cluster at
        ``ray_address``); default: Ray with an address, else :data:`.executors.DEFAULT_KIND`.
    process : ProcessModel, optional
        The EDM process (roughing twins, removed volume, erosion time, wear); part of the set id. None: none.
    process_resolution : float
        Voxel size of the removed-volume field [mm].
    stock_mesh : (MeshBlank, str), optional
        A pre-machined stock and its SHA-256 (:func:`edm_planner.process.volume.load_stock_mesh`).
    process_step : callable, optional
        ``process_step(designer, candidate, process_resolution)``, required with ``process``: the process of
        the delivered candidate, run at the end of :meth:`design` (before the plans are moved to their
        channel); it reports its steps with :meth:`process_progress`, which spans the last
        :data:`PROCESS_SHARE` of the design's progress. The process layer's
        :func:`edm_planner.process.set_process.add_process`; passed in by whoever builds the designer with a
        process model, since this module (a layer below) imports nothing of ``edm_planner.process``.
    """

    def __init__(self, geometry, field, plan_options=None, options=None, cycle_options=None, progress=None,
                 field_cache=None, workers=None, detail=None, process=None, process_resolution=0.5,
                 stock_mesh=None, process_step=None, ray_address="", executor=None):
        if process is not None and process_step is None:
            raise ValueError("a SetDesigner with a process model needs its process_step "
                             "(edm_planner.process.set_process.add_process)")
        self.geometry = geometry
        self.process = process           # ProcessModel: roughing twins, removed volume, erosion time (None: none)
        self.process_step = process_step
        self.process_resolution = float(process_resolution)
        self.stock_mesh, self.stock_sha256 = stock_mesh if stock_mesh is not None else (None, "")
        self.blisk = geometry.blisk
        self.field = field
        self.options = options or SetOptions()
        self.cycle_options = cycle_options or CycleOptions(tolerance=self.options.tolerance)
        base = geometry.design
        self.base = replace(base, circumferential_reduction=0.0, radial_reduction=0.0, reduction_side="both",
                            axial_range=None)
        self._designs = {}
        self._walls = {}                 # the offset walls, shared by designs that differ in h only
        margin = base.discharge_gap - self.options.tolerance
        if margin <= 0:
            raise EdmError(ErrorCode.INVALID_REQUEST,
                           f"the tolerance {self.options.tolerance:g} mm is not below the discharge gap "
                           f"{base.discharge_gap:g} mm")
        self.plan_options = self.machining_plan_options(plan_options, base, self.options)
        self.progress = progress
        self.detail = detail
        self.field_cache = field_cache
        self.workers = int(workers or os.cpu_count() or 1)
        self.ray_address = str(ray_address or "")
        self.executor_kind = kind_for(self.ray_address, executor)
        self._pool = None
        self._wall_samples = None
        self._inherent = None            # the corner rounding at the wall samples (prove)
        self._walls_future = None        # the same, being made in a worker (_start_workers)
        self._starter = None             # the thread that starts the workers (_start_workers)
        self.t0 = None
        self._where, self._name = (0, 1, 0, 1), ""
        self._sizing = ""                # what the sizing step tries: start, radial, circumferential
        self._fraction = 0.0             # the last fraction reported (reports never go back)
        self._cancel = threading.Event()
        self._reports = None             # the workers' SetProgress records (a multiprocessing or a Ray queue)
        self._cands = []                 # the candidates of the design under way
        self._ahead = {}                 # (candidate, piece) -> future: pieces sized ahead of their candidate
        self._stashed = []               # their workers' records, reported when their candidate's turn comes
        b = self.blisk
        self.h_max = 0.9 * float(np.min(b.pitch - (b.blade.theta_plus - b.blade.theta_minus)))
        self.r_start = self.options.radial_start * b.channel_height_range[0]

    @staticmethod
    def machining_plan_options(plan_options, design, options):
        """The search settings with the margins raised to the machining margin (gap less the tolerance)."""
        margin = design.discharge_gap - options.tolerance
        po = plan_options or PlanOptions()
        search = replace(po.search, margin_blade=max(po.search.margin_blade, margin),
                         margin_hub_shroud=max(po.search.margin_hub_shroud, margin))
        return replace(po, search=search, size_electrode=False)

    def closed_channel_range(self, insets=EDGE_INSETS, resolution=EDGE_INSET_RESOLUTION):
        """The longest axial range an electrode can fill: the closed channel less the smallest inset that designs.

        The electrode stops where both blade walls still span hub to shroud; the
        default design keeps 0.5 % inside that range (the spline footprints' corners),
        which leaves end strips of stock, so the set tries thinner insets first
        (``insets``, shares of the channel length), and between one that fails and
        the next that designs bisects for the thinnest that designs, to ``resolution``.
        """
        fx0, fx1 = self.blisk.full_span_axial_range
        length = fx1 - fx0

        def designs(share):
            try:
                self._designed(replace(self.base, axial_range=(fx0 + share * length, fx1 - share * length)), "main")
                return True
            except EdmError:
                return False

        failed = None
        for share in insets:
            if designs(share):
                # between a share that fails and one that designs, the thinnest that designs (a faceted or measured
                # blade's walls may stop covering the span a little inside its sections' extent)
                while failed is not None and share - failed > resolution:
                    mid = 0.5 * (failed + share)
                    failed, share = (failed, mid) if designs(mid) else (mid, share)
                return (fx0 + share * length, fx1 - share * length)
            failed = share
        return None

    # -- helpers -----------------------------------------------------------------------------
    def _report(self, fraction, message, absolute=False, **step):
        """Report a step to ``progress`` and, structured (``step``: :class:`SetProgress` fields), to ``detail``.

        ``fraction`` is the candidates' share of the design (scaled to leave the process step its part), or
        with ``absolute`` the design's. Raises SetDesignCancelled after :meth:`cancel`: every step is a point
        where the design stops.
        """
        self._check_cancel()
        if not absolute:
            fraction = float(fraction) * self._search_share
        fraction = self._fraction = max(float(min(fraction, 0.99)), self._fraction)
        _log.info("electrode set: %s", message)
        if self.progress is not None:
            self.progress("electrode set", fraction, message)
        if self.detail is not None:
            ci, nc, pj, npc = self._where
            where = dict(candidate=self._name, candidate_index=ci, candidate_count=nc, piece_index=pj,
                         piece_count=npc, message=message)
            elapsed = self._elapsed() if self.t0 is not None else 0.0
            self.detail(SetProgress(**{**where, **step}).timed(fraction, elapsed,
                                                                self.options.time_budget - elapsed))

    @property
    def _search_share(self):
        """The candidates' steps fill the progress up to here, the process step (with a process model) the rest."""
        return 1.0 - PROCESS_SHARE if self.process is not None else 1.0

    def process_progress(self, share, message):
        """The process step's report: ``share`` (0 to 1) of its part of the progress done, and what it does now."""
        start = self._search_share
        self._report(start + min(max(float(share), 0.0), 1.0) * (0.99 - start), message, absolute=True)

    def cancel(self):
        """Stop the design from another thread: :meth:`design` raises SetDesignCancelled at its next step.

        The sizing worker processes are terminated at once (a running job is not waited for), so the
        design stops within about a second (at most one search step of a plan sized in this process).
        """
        self._cancel.set()
        if self._pool is not None:
            self._pool.terminate()

    def _check_cancel(self):
        if self._cancel.is_set():
            raise SetDesignCancelled("the electrode-set design was cancelled")

    def _search_progress(self, stage, fraction, nodes, reference, message=""):
        """plan_channel's progress while sizing: only a point where a cancelled design stops."""
        self._check_cancel()

    def _elapsed(self):
        return budget_clock() - self.t0

    def _out_of_time(self):
        return self._elapsed() > self.options.time_budget

    def _plan(self, piece, h, radial):
        ci, nc, pj, npc = self._where
        share = min(len(piece.tried) / 12.0, 0.95)            # about a dozen certified plans size a piece
        self._report((ci + (pj + share) / npc) / nc, f"{self._name}: {piece.label} electrode, h {h:.4f} rad, "
                                                       f"radial reduction {radial:.3f} mm",
                     piece=piece.label, sizing_parameter=self._sizing, sizing_step=len(piece.tried) + 1,
                     circumferential_reduction=float(h), radial_reduction=float(radial))
        design = replace(piece.design, circumferential_reduction=float(h), radial_reduction=float(radial))
        try:
            plan = plan_channel(self.geometry, 0, piece.electrode_id, self.plan_options, field=self.field,
                                design=design, electrodes=self._designed(design, piece.electrode_id),
                                exact_clearance=False,             # the chosen plan's only, in size_piece
                                progress=self._search_progress)    # a cancelled design stops mid-search
        except EdmError as e:                     # a reduction that leaves no electrode
            piece.tried.append((h, radial, f"{e.code.name}: {e.message[:120]}"))
            return None, design
        piece.tried.append((h, radial, "certified" if plan.success else f"{plan.error_code.name}: {plan.message[:120]}"))
        return (plan if plan.success else None), design

    # -- sizing one piece ------------------------------------------------------------------------
    def size_piece(self, piece):
        """Smallest radial, then smallest circumferential reduction with a certified plan; False if none.

        Then the piece's cycle; where it does not certify, the smallest larger radial reduction with which it
        does (:meth:`_radial_for_the_cycle`); else the piece keeps the failing cycle, which rejects its candidate.
        """
        o = self.options
        # start designs, most promising first; a reduction that leaves no electrode (a narrow half of a
        # left/right split) is skipped at the cost of a design, not of a plan
        plan = None
        self._sizing = "start"
        for fh, fr in ((0.5, 1.0), (0.25, 1.0), (1.0, 2.0), (0.5, 2.0)):
            h_hi, r_hi = fh * self.h_max, fr * self.r_start
            plan, design = self._plan(piece, h_hi, r_hi)
            if plan is not None or self._out_of_time():
                break
        if plan is None:
            return False
        best, r_start = (plan, design), r_hi
        self._sizing = "radial"
        lo = 0.0                                   # radial first: the least shroud stock
        if r_hi > 0:                               # none at all leaves none (and needs no plunges)
            p, d = self._plan(piece, h_hi, 0.0)
            if p is not None:
                r_hi, best = 0.0, (p, d)
        r_hi, best = self._bisect(lo, r_hi, o.radial_resolution, lambda r: self._plan(piece, h_hi, r), best)
        # then the thickest electrode
        self._sizing = "circumferential"
        h_hi, best = self._bisect(0.0, h_hi, o.circumferential_resolution, lambda h: self._plan(piece, h, r_hi), best)
        piece.plan, piece.design = best
        piece.cycle = self._cycle(piece, *best)
        if not piece.cycle.certified and r_start > r_hi:
            self._radial_for_the_cycle(piece, h_hi, r_hi, r_start)
        add_exact_clearance(piece.plan, self.blisk, self.field)
        piece.volume = float(self._electrode(piece).mesh.volume)
        return True

    def _cycle(self, piece, plan, design):
        """The certified cycle (approach, feed, copy processing, return, retract, clear) of a piece's plan."""
        electrode = _pick_electrode(self._designed(design, piece.electrode_id), piece.electrode_id)
        builder = CycleBuilder(self.field, electrode, design, plan.axis_names, self.cycle_options)
        margin = min(self.plan_options.search.margin_blade, self.plan_options.search.margin_hub_shroud)
        return builder.build(plan.samples, margin, np.asarray(plan.metrics.clearance_lower_bound))

    def _radial_for_the_cycle(self, piece, h, r_lo, r_hi):
        """A piece whose feed plans but whose cycle does not certify: the smallest radial reduction in
        (r_lo, r_hi] whose plan and cycle both do, if any (the piece keeps its failing cycle otherwise).

        The cycle can fail where the feed does not: after the retract the clear leg moves X alone out of the
        part, through an annulus that may narrow beyond the blades (a front piece of three axial pieces on the
        default blisk: the hub rises and the shroud falls ahead of the leading edge); a shorter electrode
        (more radial reduction, which copy processing's plunge takes) passes it.
        """
        self._sizing = "radial (the cycle)"
        failing = piece.cycle.message

        def attempt(r):
            """(found or None, None) in :meth:`_bisect`'s form: found = (plan, design, cycle) when both certify."""
            plan, design = self._plan(piece, h, r)
            if plan is None:
                return None, None
            cycle = self._cycle(piece, plan, design)
            hh, rr, _ = piece.tried[-1]
            piece.tried[-1] = (hh, rr, "certified; cycle " + ("certified" if cycle.certified
                                                                 else f"not certified: {cycle.message[:120]}"))
            return ((plan, design, cycle) if cycle.certified else None), None

        best = attempt(r_hi)
        if best[0] is None:
            return
        r_hi, best = self._bisect(r_lo, r_hi, self.options.radial_resolution, attempt, best)
        piece.plan, piece.design, piece.cycle = best[0]
        _log.info("%s electrode: radial reduction %.3f mm for a certified cycle (with less: %s)", piece.label,
                  r_hi, failing)

    def _designed(self, design, electrode_id):
        """The piece's electrode of a design (in a list, as plan_channel takes it), designed once."""
        key = (design, electrode_id)
        if key not in self._designs:
            self._designs[key] = design_electrodes(self.blisk, design, only=electrode_id, walls_cache=self._walls)
        return self._designs[key]

    def _bisect(self, lo, hi, resolution, attempt, best):
        """Smallest value in (lo, hi] with a certified plan (``attempt(v) -> (plan or None, design)``);
        ``hi`` is known to have one (``best``). Returns (value, (plan, design))."""
        while hi - lo > resolution and not self._out_of_time():
            mid = 0.5 * (lo + hi)
            plan, design = attempt(mid)
            if plan is None:
                lo = mid
            else:
                hi, best = mid, (plan, design)
        return hi, best

    def _electrode(self, piece):
        return _pick_electrode(self._designed(piece.design, piece.electrode_id), piece.electrode_id)

    # -- the removal proof of a candidate ------------------------------------------------------
    def sweeps(self, candidate):
        """A :class:`.swept_stock.Sweep` per piece: the channel-0 poses of its cycle's moves that retrace none.

        The return runs the feed backwards, the retract the approach, and every "back" move of copy
        processing its straight moves out: the same electrode positions, which the proof need not visit twice
        (:func:`.proof_path.proof_legs`; about half the poses).
        """
        out = []
        for p in candidate.pieces:
            mesh = p.plan.electrode_mesh
            samples, breaks = proof_samples(p.cycle)
            poses = axis_poses(p.plan.final_pose, p.plan.axis_names, samples)
            out.append(Sweep(np.asarray(mesh.vertices), np.asarray(mesh.faces), poses, breaks))
        return out

    def prove(self, candidate):
        """The candidate's removal proof; the inherent stock is the corner rounding of the walls themselves.

        The reference is computed from the blisk's wall geometry
        (:func:`.corner_rounding.corner_rounding_stock`), independent of the design
        code that made the candidates' electrodes.
        """
        if self._wall_samples is None:                # the same walls for every candidate
            future, self._walls_future = self._walls_future, None
            if future is not None:
                self._wall_samples, self._inherent = future.result()
            else:
                self._wall_samples, self._inherent = _wall_reference(self.blisk, self.options.removal_spacing,
                                                                     self.base.discharge_gap)
        pool = self._workers_pool()               # the sizing workers share out the wall samples
        report = simulate_removal(self.blisk, self.sweeps(candidate), self.base.discharge_gap,
                                  tolerance=self.options.tolerance, samples=self._wall_samples,
                                  inherent=self._inherent,
                                  executor=pool, parts=self.workers if pool is not None else 1)
        candidate.removal = report
        return report

    # -- the whole design ----------------------------------------------------------------------------
    def design(self, channel=0):
        """Design, prove and choose; the chosen pieces' plans and cycles moved to ``channel``."""
        try:
            return self._design(channel)
        except Exception:
            if self._cancel.is_set():      # a worker terminated by cancel() breaks whatever waited on it
                raise SetDesignCancelled("the electrode-set design was cancelled") from None
            raise
        finally:
            self.close()

    def _design(self, channel):
        if self.geometry.measured is not None:
            # the pieces are planned in channel 0 and turned to ``channel``: right only on the channel's walls
            raise EdmError(ErrorCode.INVALID_REQUEST,
                           f"a blisk as measured: design the set of channel {channel} on its own geometry, "
                           f"geometry.for_channel({channel}), with that geometry's field")
        self.t0 = budget_clock()
        self._report(0.0, "the axial range the electrodes can fill")
        self.base = replace(self.base, axial_range=self.closed_channel_range())
        self._start_workers()
        cands = [Candidate(name, [Piece(lab, eid, d) for lab, eid, d in pieces])
                 for name, pieces in candidate_sets(self.blisk, self.base, self.options)]
        self._cands, self._ahead, self._stashed = cands, {}, []
        accepted_count = None
        for i, cand in enumerate(cands):
            if accepted_count is not None and cand.electrode_count > accepted_count:
                cand.status, cand.reason = "not tried", f"a set of {accepted_count} electrode(s) machines the channel"
                continue
            if self._out_of_time():
                cand.status, cand.reason = "time budget", f"the time budget of {self.options.time_budget:g} s was used up"
                continue
            self._where, self._name = (i, len(cands), 0, cand.electrode_count), cand.name
            self._report(i / len(cands), f"candidate {cand.name}: sizing {cand.electrode_count} electrode(s)")
            self._evaluate(cand, i, len(cands))
            if cand.status == "accepted":
                accepted_count = cand.electrode_count
        accepted = [c for c in cands if c.status == "accepted"]
        result = ElectrodeSet(self.geometry.geometry_id, int(channel), cands)
        result.set_id, result.program_id = set_id_for(self.geometry.geometry_id, channel, self.plan_options,
                                                      self.options, self.cycle_options, self.process,
                                                      self.process_resolution, self.stock_sha256)
        if accepted:
            best = min(accepted, key=lambda c: (c.electrode_count, -c.volume, c.cycle_travel))
            best.status = "chosen"
            for c in accepted:
                if c is not best:
                    c.reason = (f"also machines the channel, but {best.name} has thicker electrodes "
                                f"({best.volume:.0f} against {c.volume:.0f} mm^3) or a shorter cycle")
            result.chosen = best
            result.message = (f"{best.name}: {best.electrode_count} electrode(s), {best.reason}")
        else:
            # nothing machines to the tolerance: the certified candidate that leaves the least stock (and
            # overcuts nowhere) is still delivered, flagged, so the engineer sees what another operation must take
            near = [c for c in cands if c.status == "stock left"]
            if near:
                result.closest = min(near, key=lambda c: (max(w.area_fraction_beyond_inherent
                                                              for w in c.removal.surfaces.values()),
                                                          c.electrode_count))
            result.message = "no candidate machines the channel to the tolerance: " + "; ".join(
                f"{c.name}: {c.status} ({c.reason})" for c in cands)
            if result.closest is not None:
                result.message = (f"{result.closest.name} leaves the least stock (not to the tolerance; its plans are "
                                  f"certified and delivered, flagged); " + result.message)
        delivered = result.delivered
        # no candidate's step from here on: the reports name the delivered set in their message
        self._name, self._where = "", (0, 0, 0, 0)
        if delivered is not None and self.process is not None:
            self.process_progress(0.0, f"{delivered.name}: the EDM process (roughing twins, removed volume, "
                                       f"erosion time)")
            self.process_step(self, delivered, self.process_resolution)
        if delivered is not None:
            proof = dict(delivered.removal.to_dict(), certificate_vs_proof=delivered.truth)
            rough_proof = None if delivered.rough_removal is None else dict(
                delivered.rough_removal.to_dict(), roughing_allowance=delivered.allowance)
            for p in delivered.pieces:
                _move_plan(p.plan, p.cycle, p.design, channel, self.blisk.pitch)
                p.plan.removal = rough_proof if p.regime == "rough" else proof
                p.plan.set_id = result.set_id
        result.planning_time = self._elapsed()
        self._report(1.0, result.message, absolute=True)
        return result

    def _size_all(self, cand, index, count):
        """Size every piece of a candidate: in the worker processes when there are several, else here.

        A worker this candidate no longer needs (its piece sized while others still run) sizes a piece of a
        later candidate that is certain to be tried (:meth:`_certain_after`) instead of waiting: the same
        sizing, in a core that would idle. The pieces, and so the set, are the same as one at a time.
        """
        pool = self._workers_pool() if len(cand.pieces) > 1 else None
        if pool is None:
            done = []
            for j, piece in enumerate(cand.pieces):
                self._where = (index, count, j, len(cand.pieces))
                done.append(self.size_piece(piece))
            return done
        self._report(index / count, f"{cand.name}: sizing {len(cand.pieces)} electrodes in "
                                     f"{pool.describe()}")
        n = len(cand.pieces)
        pending = {j: self._ahead.pop((index, j), None) or self._submit_piece(pool, cand, index, count, j)
                   for j in range(n)}
        ahead = self._certain_after(cand, index)
        records, self._stashed = ([r for r in self._stashed if r.candidate_index == index],
                                  [r for r in self._stashed if r.candidate_index != index])
        done, shares = [None] * n, [0.0] * n          # per piece: sized?, share of its sizing done
        while pending:
            finished, _ = wait(list(pending.values()), timeout=0.25, return_when=FIRST_COMPLETED)
            self._check_cancel()
            for record in records + drain(self._reports):       # the workers' steps, each reported here
                if record.candidate_index != index:             # a piece sized ahead: at its candidate's turn
                    self._stashed.append(record)
                    continue
                shares[record.piece_index] = max(shares[record.piece_index], min(record.sizing_step / 12.0, 0.95))
                self._report((index + 0.9 * sum(shares) / n) / count, record.message, piece=record.piece,
                             piece_index=record.piece_index, sizing_parameter=record.sizing_parameter,
                             sizing_step=record.sizing_step, radial_reduction=record.radial_reduction,
                             circumferential_reduction=record.circumferential_reduction)
            records = []
            for j in [j for j, f in pending.items() if f in finished]:
                future = pending.pop(j)
                ok, sized = future.result()
                cand.pieces[j], done[j], shares[j] = sized, ok, 1.0
                node = getattr(future, "node_id", "")          # a Ray task's node
                self._report((index + 0.9 * sum(shares) / n) / count,
                             f"{cand.name}: {sized.label} electrode {'sized' if ok else 'has no certified path'}"
                             + (f" (on node {node[:8]})" if node else ""), piece=sized.label, piece_index=j)
            busy = len(pending) + sum(not f.done() for f in self._ahead.values())
            while pending and ahead and busy < self.workers:
                i, j = ahead.pop(0)
                self._ahead[(i, j)] = self._submit_piece(pool, self._cands[i], i, count, j)
                busy += 1
        return done

    def _submit_piece(self, pool, cand, index, count, j):
        return pool.submit(_size_in_worker, cand.pieces[j], self.options.time_budget - self._elapsed(),
                           (index, count, j, len(cand.pieces)), cand.name)

    def _certain_after(self, cand, index):
        """(candidate, piece) of the later candidates sized in the workers that are certain to be tried once
        candidate ``index`` is: those with as many electrodes (a candidate is passed over only for an accepted
        one with fewer), not yet submitted."""
        if index >= len(self._cands) or self._cands[index] is not cand:      # a candidate evaluated on its own
            return []
        count = cand.electrode_count
        return [(i, j) for i in range(index + 1, len(self._cands))
                if self._cands[i].electrode_count == count and len(self._cands[i].pieces) > 1
                for j in range(len(self._cands[i].pieces)) if (i, j) not in self._ahead]

    def _workers_pool(self):
        """The executor of the tasks (:mod:`.executors`), made on first use; None: everything runs here.

        Local worker processes need the field cache and two workers or more; Ray needs the field cache (its
        workers load the field from it) and runs on a local Ray of ``workers`` CPUs or on the cluster at
        ``ray_address``, whose CPUs set ``workers`` (the proof's shares).
        """
        if self.field_cache is None or (self.executor_kind != "ray" and self.workers < 2):
            return None
        self._join_starter()
        if self._pool is None:
            self._pool = self.make_executor(self.workers)
            self._reports = self._pool.reports
            self.workers = self._pool.workers
        return self._pool

    def _start_workers(self):
        """Start the worker processes in the background, one of them sampling the walls for the proofs (with
        their corner rounding): both overlap the first candidate's sizing, which runs in this process when it
        is one electrode, instead of waiting in front of its proof (Rotor 37: about 4 s to start the workers,
        3.7 s for the walls). A thread starts them: a spawned worker holds up its starter until it has read
        its start-up data. Local workers only: Ray is started or joined where it is first needed, in the
        designer's own thread, as before."""
        if (self.field_cache is None or self.executor_kind != LOCAL or self._starter is not None
                or self._wall_samples is not None):
            return

        def start():
            try:
                pool = self._workers_pool()
            except Exception as exc:            # made again where it is needed, which raises there
                _log.warning("electrode set: the workers could not be started ahead: %s", exc)
                return
            if pool is None or self._cancel.is_set():
                return
            try:
                self._walls_future = pool.submit(_walls_in_worker, self.options.removal_spacing,
                                                 self.base.discharge_gap)
                for _ in range(self.workers - 1):
                    pool.submit(_ready_in_worker)  # a process pool starts a worker per task it has no idle one for
            except RuntimeError:
                if not self._cancel.is_set():   # cancel() shut the pool meanwhile: nothing left to start
                    raise

        self._starter = threading.Thread(target=start, name="electrode-set workers", daemon=True)
        self._starter.start()

    def _join_starter(self):
        """Wait for :meth:`_start_workers`' thread (from any other thread): the pool is then made or not."""
        starter = self._starter
        if starter is not None and starter is not threading.current_thread():
            starter.join()

    def make_executor(self, workers, kind=None):
        """A new executor (:func:`.executors.make_executor`) of ``workers`` whose workers hold this designer's
        geometry, field (from ``field_cache``), options and base design; its tasks are this module's
        ``_size_in_worker`` and ``_plan_in_worker`` and the removal proof's shares."""
        return make_executor(
            workers, _start_worker,
            (pickle.dumps(self.geometry), self.field.spacing, self.field_cache, self.plan_options,
             self.options, self.cycle_options, self.base),
            address=self.ray_address, kind=kind or self.executor_kind, reports=self.detail is not None)

    def close(self):
        """Stop the worker processes (if any): after their running jobs, or at once after :meth:`cancel`."""
        self._join_starter()
        self._starter = None
        pool, self._pool = self._pool, None
        self._walls_future = None
        if pool is not None:
            if self._cancel.is_set():
                pool.terminate()
                pool.shutdown(wait=False, cancel_futures=True)
            else:
                pool.shutdown(wait=True, cancel_futures=True)
        self._reports = None

    def _evaluate(self, cand, index=0, count=1):
        self._name = cand.name
        sized = self._size_all(cand, index, count)
        for piece, ok in zip(cand.pieces, sized):
            if not ok:
                last = piece.tried[-1][2] if piece.tried else "not planned"
                cand.status, cand.reason = "infeasible", f"the {piece.label} electrode has no certified path ({last})"
                return
            if not piece.cycle.certified:
                cand.status, cand.reason = "infeasible", f"the {piece.label} electrode's cycle: {piece.cycle.message}"
                return
        cand.cycle_travel = float(sum((len(p.cycle.samples) - 1) * self.cycle_options.sample_spacing
                                      for p in cand.pieces))
        self._report((index + 0.95) / count, f"{cand.name}: material-removal proof")
        judge(cand, self.prove(cand), self.options)


def _pick_electrode(electrodes, electrode_id):
    for e in electrodes:
        if e.electrode_id == electrode_id:
            return e
    raise EdmError(ErrorCode.INTERNAL, f"no electrode {electrode_id!r} in its own design")


_WORKER = None


def _start_worker(geometry_blob, spacing, field_cache, plan_options, options, cycle_options, base, reports=None):
    """Worker process: the geometry, its field from the cache and a designer of its own."""
    global _WORKER
    numba.set_num_threads(1)             # the pool is the parallelism: one thread per worker process
    geometry = pickle.loads(geometry_blob)
    field = FastChannelField(geometry.blisk, spacing=spacing, cache_dir=field_cache[0], cache_key=field_cache[1])
    _WORKER = SetDesigner(geometry, field, plan_options, options, cycle_options,
                          detail=None if reports is None else reports.put)     # the steps, to the parent
    _WORKER.base = base


def _size_in_worker(piece, remaining, where=(0, 1, 0, 1), name=""):
    """Size one piece in a worker; (ok, the piece with its plan and cycle)."""
    _WORKER.t0 = budget_clock() - (_WORKER.options.time_budget - remaining)
    _WORKER._where, _WORKER._name, _WORKER._fraction = where, name, 0.0
    ok = _WORKER.size_piece(piece)
    return ok, piece


def _wall_reference(blisk, spacing, gap):
    """The proofs' wall samples and their corner rounding (the inherent stock): (samples, inherent)."""
    samples = wall_samples(blisk, spacing)
    return samples, corner_rounding_stock(blisk, samples, gap)


def _walls_in_worker(spacing, gap):
    """:func:`_wall_reference` of the worker's blisk."""
    return _wall_reference(_WORKER.blisk, spacing, gap)


def _ready_in_worker():
    """Nothing: a task that makes the pool start a worker process."""
    return True


def _plan_in_worker(piece, h, radial):
    """One sizing step in a worker: a certified-plan attempt of ``piece`` at (h, radial); (piece, plan or None).

    The unit the bench (``scaleout``) and the scale-out tests hand out; :meth:`SetDesigner.size_piece` is a
    sequence of these.
    """
    _WORKER.t0 = budget_clock()
    plan, _ = _WORKER._plan(piece, h, radial)
    return piece, plan




def certificate_against_proof(candidate, report):
    """Per surface, side by side: the certificate's lower bound and the smallest distance the proof found.

    The certificate bounds the clearance of every point of every electrode
    over its whole continuous cycle from below (every leg's
    ``clearance_lower_bound``); the removal proof measures, exactly, the
    distance from wall samples to the electrode meshes at the cycle's poses
    (stock + gap). A sample's distance at a pose of the cycle can never lie
    below a sound bound, so ``proof >= certificate - AGREEMENT_ACCURACY``
    must hold on every surface; where it does not, one of them is wrong and
    the candidate is refused.

    Returns
    -------
    dict
        surface -> {"certificate_lower_bound_mm", "proof_min_distance_mm", "agree", "message"}.
    """
    bounds = np.vstack([np.asarray(p.cycle.clearance_lower_bound(), dtype=np.float64) for p in candidate.pieces])
    cert = np.nanmin(bounds, axis=0) if np.isfinite(bounds).any() else np.full(bounds.shape[1], np.nan)
    gap = float(min(report.gap))
    out = {}
    for name, surf in report.surfaces.items():
        j = SURFACES.index(name)
        proof = float(np.nanmin(surf.stock)) + gap
        agree = bool(np.isfinite(cert[j]) and proof >= cert[j] - AGREEMENT_ACCURACY)
        out[name] = {"certificate_lower_bound_mm": round(float(cert[j]), 6), "proof_min_distance_mm": round(proof, 6),
                     "agree": agree,
                     "message": "" if agree else (f"{name}: the proof finds an electrode {proof:.4f} mm from the "
                                                  f"wall where the certificate promises at least {cert[j]:.4f} mm")}
    return out


def judge(candidate, report, options):
    """Set a proven candidate's ``truth``, ``status`` and ``reason``.

    A candidate whose certificate and removal proof disagree on any surface
    (:func:`certificate_against_proof`) is refused ("disagreement", naming
    each surface and both figures), whatever its stock: one of the two is
    wrong, and no set is delivered on a false certificate. Otherwise
    :func:`acceptance` decides.
    """
    candidate.removal = report
    candidate.truth = certificate_against_proof(candidate, report)
    disagree = [t["message"] for t in candidate.truth.values() if not t["agree"]]
    if disagree:
        candidate.status = "disagreement"
        candidate.reason = "the certificate and the removal proof disagree: " + "; ".join(disagree)
        _log.error("%s: %s", candidate.name, candidate.reason)
    else:
        candidate.status, candidate.reason = acceptance(report, options)
    return candidate.status


def acceptance(report, options):
    """(status, reason) of a proven candidate: "overcut", "stock left" or "accepted".

    Accepted when nothing is overcut beyond the tolerance and on every wall
    the area whose stock exceeds the inherent corner rounding by more than
    the tolerance (``area_fraction_beyond_inherent``) is at most
    ``options.max_area_above``. A report without an inherent stock (NaN) is
    never accepted.
    """
    figures = removal_figures(report)
    shares = {name: w.area_fraction_beyond_inherent for name, w in report.surfaces.items()}
    if report.overcut_max > options.tolerance:
        return "overcut", f"overcut {report.overcut_max:.4f} mm, beyond the tolerance; {figures}"
    unknown = [name for name, v in shares.items() if not np.isfinite(v)]
    if unknown:
        return "stock left", f"no inherent stock to compare with on the {', '.join(unknown)}; {figures}"
    worst = max(shares, key=shares.get)
    if shares[worst] > options.max_area_above:
        return "stock left", (f"{100 * shares[worst]:.2f} % of the {worst} keeps stock more than "
                              f"{options.tolerance:g} mm beyond the EDM corner rounding (at most "
                              f"{100 * options.max_area_above:g} % allowed); {figures}")
    return "accepted", f"machines the channel to {options.tolerance:g} mm; {figures}"


def removal_figures(report):
    """One line of the proof's figures: per surface largest / mean stock, share above tolerance, overcut."""
    return "; ".join(f"{name} stock max {s.stock_max:.3f} mean {s.stock_mean:.4f} mm, "
                     f"{100 * s.area_fraction_above_tolerance:.2f} % above the tolerance "
                     f"({100 * s.area_fraction_beyond_inherent:.2f} % beyond the corner rounding of "
                     f"{s.inherent_max:.3f} mm), overcut {s.overcut_max:.4f} mm"
                     for name, s in report.surfaces.items())


def _move_plan(plan, cycle, design, channel, pitch):
    """A channel-0 plan and its cycle moved to channel k (the blisk is periodic), with the plan id of channel k."""
    plan.cycle = cycle
    if not channel:
        return plan
    plan.samples = shift_channel(plan.samples, plan.axis_names, channel, pitch)
    plan.poses = rotation_about_x(channel * pitch)[None] @ plan.poses
    for leg in cycle.legs:
        leg.samples = shift_channel(leg.samples, plan.axis_names, channel, pitch)
    plan.channel = int(channel)
    plan.plan_id = plan_id_for(plan.geometry_id, channel, plan.electrode_id, plan.options, design)
    return plan


#: the set's file writers, moved up to the records layer (:mod:`edm_planner.records.set_files`)
_MOVED_TO_RECORDS = ("write_set", "write_stored_set", "write_stock_glb", "_write_set_json")
#: what the proof visits of a cycle, moved to :mod:`.proof_path`
_MOVED_TO_PROOF_PATH = ("proof_legs", "retraces")


def __getattr__(name):
    # PEP 562, deprecated aliases only: these imports run when an old name is asked for (machining imports no
    # records module at load time)
    if name in _MOVED_TO_RECORDS:
        from ..records import set_files
        return deprecation.moved_name(__name__, name, set_files)
    if name in _MOVED_TO_PROOF_PATH:
        return deprecation.moved_name(__name__, name, proof_path)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
