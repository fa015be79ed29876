"""Structured progress of an electrode-set design, its time-left estimate, and its cancellation.

:class:`~.electrode_set.SetDesigner` reports every step twice: as before,
``progress(stage, fraction, message)``, and, to a ``detail`` callable, as one
:class:`SetProgress` record (which candidate, which piece, which sizing step
with the values tried, the fraction done, the elapsed time and an estimate of
the time left). The ROS action feedback (``edm_planner_msgs/action/
PlanElectrodeSet``) and ``edm-plan plan``'s progress lines are filled from it.
"""

import math
import threading
from dataclasses import dataclass, replace

#: below this fraction done the time left is not estimated (NaN): the first steps say little about the rest
MIN_FRACTION_FOR_ESTIMATE = 0.02


class SetDesignCancelled(Exception):
    """Raised inside :meth:`SetDesigner.design` after :meth:`SetDesigner.cancel`; nothing was delivered."""


@dataclass(frozen=True)
class SetProgress:
    """One step of a set design (units mm, rad, s).

    Attributes
    ----------
    candidate : str
        Candidate being tried ('' before the first).
    candidate_index, candidate_count : int
        Its 0-based index and the number of candidates.
    piece : str
        Label of the electrode being sized ('' when the step is not one piece's).
    piece_index, piece_count : int
        Its 0-based index in the candidate and the candidate's piece count.
    sizing_parameter : str
        "start" (a start design), "radial" or "circumferential" (the bisection of that reduction); ''.
    sizing_step : int
        1-based number of the certified-plan attempt of this piece (0 outside the sizing).
    circumferential_reduction : float
        h tried [rad] (NaN outside the sizing).
    radial_reduction : float
        Radial reduction tried [mm] (NaN outside the sizing).
    fraction : float
        Work done, 0..1 (candidates, pieces and plan attempts; not seconds).
    elapsed : float
        Since the design started [s].
    estimated_time_left : float
        An estimate [s], see :func:`estimate_time_left`; NaN when unknown.
    message : str
    """

    candidate: str = ""
    candidate_index: int = 0
    candidate_count: int = 0
    piece: str = ""
    piece_index: int = 0
    piece_count: int = 0
    sizing_parameter: str = ""
    sizing_step: int = 0
    circumferential_reduction: float = math.nan
    radial_reduction: float = math.nan
    fraction: float = 0.0
    elapsed: float = 0.0
    estimated_time_left: float = math.nan
    message: str = ""

    def timed(self, fraction, elapsed, budget_left=math.inf):
        """The record with its fraction, elapsed time and time-left estimate set."""
        return replace(self, fraction=float(fraction), elapsed=float(elapsed),
                       estimated_time_left=estimate_time_left(fraction, elapsed, budget_left))

    def where(self):
        """One line: candidate, piece, sizing step (what a progress line shows before the message)."""
        parts = []
        if self.candidate:
            parts.append(f"candidate {self.candidate_index + 1}/{self.candidate_count} {self.candidate}")
        if self.piece:
            parts.append(f"piece {self.piece_index + 1}/{self.piece_count} {self.piece}")
        if self.sizing_parameter:
            parts.append(f"step {self.sizing_step} {self.sizing_parameter} (h {self.circumferential_reduction:.4f} "
                         f"rad, radial {self.radial_reduction:.3f} mm)")
        return ", ".join(parts)


def estimate_time_left(fraction, elapsed, budget_left=math.inf):
    """Time left [s] by linear extrapolation: ``elapsed * (1 - fraction) / fraction``, at most ``budget_left``.

    The fraction counts steps (candidates, pieces, plan attempts), whose durations differ, so this is an
    estimate that firms up as the design goes on; NaN below :data:`MIN_FRACTION_FOR_ESTIMATE` (and for a
    non-finite input). A design never runs much past its time budget, hence the cap.
    """
    fraction, elapsed = float(fraction), float(elapsed)
    if not (math.isfinite(fraction) and math.isfinite(elapsed)) or fraction < MIN_FRACTION_FOR_ESTIMATE:
        return math.nan
    if fraction >= 1.0:
        return 0.0
    return max(0.0, min(elapsed * (1.0 - fraction) / fraction, float(budget_left)))


def terminate_pool(pool, timeout=5.0):
    """Stop a ProcessPoolExecutor at once: its worker processes terminated (SIGTERM, then SIGKILL), jobs dropped.

    ``shutdown(wait=True)`` would wait for the running jobs (a piece's whole sizing); a cancelled design
    must not. Futures still waited on fail with BrokenProcessPool. Safe to call twice and from any thread.

    A ``submit`` in another thread may be spawning a worker meanwhile (it does so holding the pool's shutdown
    lock, and a spawned worker holds it until it has read its start-up data). So the pool's own table of
    processes is kept, not a copy of it: ``shutdown`` takes that lock, so when it returns every worker ever
    spawned is in the table, and no later ``submit`` spawns one (it raises RuntimeError).

    The pool's manager thread reaps the workers too (it joins them once it sees one die). A worker it has
    reaped but whose exit it has not yet recorded looks alive to every other thread (``waitpid`` answers
    ECHILD), so that thread is waited for as well: on return every worker's ``exitcode`` is set.
    """
    table = getattr(pool, "_processes", None)       # shutdown drops the pool's reference, not the table
    pool.shutdown(wait=False, cancel_futures=True)
    managers = _manager_threads(pool)               # found after shutdown: a submit may have started it
    processes = list((table or {}).values())
    for process in processes:
        if process.is_alive():
            process.terminate()
    for manager in managers:
        manager.join(timeout)       # it ends once it has joined the terminated workers
    for process in processes:
        process.join(timeout)
        if process.is_alive():      # SIGTERM ignored (or the manager thread still joining it)
            process.kill()
            process.join(timeout)
    for manager in managers:
        manager.join(timeout)


def _manager_threads(pool):
    """The threads managing ``pool`` (a ProcessPoolExecutor's internal thread holds a weak reference to it)."""
    return [thread for thread in threading.enumerate()
            if callable(getattr(thread, "executor_reference", None)) and thread.executor_reference() is pool]
