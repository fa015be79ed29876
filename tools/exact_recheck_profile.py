"""Where the exact re-check of a plan spends its time: per surface, per solve, and in the footprint test.

    .venv/bin/python tools/exact_recheck_profile.py

Plans the speed suite's case (default blisk, channel 0, rear electrode of a
front/rear split, exit downstream), then runs the branch and bound of
``pose_check.verify_poses`` per surface on one thread and prints, as JSON
lines: its time and exact solves per surface; for the suction wall's
evaluated points, the cost of an exact solve and of its footprint test
(``_wall_angle``); and, from a copy of ``spline_kernels.uv_at``'s two loops
with counters added, how many of those points make plain Newton cycle, how
many surface evaluations the descending Newton then takes, whether any lands,
and how many lie outside every knot span's (x, r) box (the convex hull of its
16 control points: a point outside all of them cannot land). A diagnostic, not
a benchmark of record (docs/performance.md, issue 29). Run with
``NUMBA_NUM_THREADS=1`` for one core.
"""

import json
import math
import time

import numba
import numpy as np

from edm_planner.bench.common import CONFIG, rear_design
from edm_planner.cli import DEFAULT_CACHE
from edm_planner.geometry.loader import load_geometry
from edm_planner.geometry.spline_kernels import _meridional_step, new_work, surface_eval
from edm_planner.interference.exact_solvers import _behind_at, _channel_coordinates, _exact_at, _nearest_start
from edm_planner.interference.fast import FastChannelField
from edm_planner.interference.field_params import named_exact
from edm_planner.interference.pose_check import search_trees, surface_minimum
from edm_planner.planning.plan import PlanOptions
from edm_planner.planning.planner import plan_channel
from edm_planner.planning.search import SearchOptions


@numba.njit
def _solve_all(surface, pts, channel_angle, params, shape, tables, footprint_only):
    params, shape, tables = named_exact(params, shape, tables)
    work, acc = new_work(), 0.0
    for k in range(pts.shape[0]):
        x, y, z = pts[k, 0], pts[k, 1], pts[k, 2]
        if footprint_only:
            acc += _behind_at(surface, x, y, z, channel_angle, params, shape, tables, work)
        else:
            acc += _exact_at(surface, x, y, z, channel_angle, params, shape, tables, work)
    return acc


@numba.njit
def _footprint_counts(face, pts, channel_angle, params, shape, tables):
    """Per point: plain Newton's evaluations, whether it cycled off the position, the descending Newton's
    evaluations and final squared residual (``uv_at``'s loops, counted), and the point's (x, rho)."""
    params, shape, tables = named_exact(params, shape, tables)
    cp, tu, tv = (tables.cp_s, tables.tu_s, tables.tv_s) if face == 0 else (tables.cp_p, tables.tu_p, tables.tv_p)
    work = new_work()
    ev = work[2]
    out = np.zeros((pts.shape[0], 6))
    for k in range(pts.shape[0]):
        x0 = pts[k, 0]
        r0, _ = _channel_coordinates(pts[k, 0], pts[k, 1], pts[k, 2], channel_angle, params)
        j = _nearest_start(face, x0, r0, tables.start_samples, tables.start_scale, tables.start_box,
                           tables.start_first, tables.start_items)
        u0, v0 = tables.start_uv[face, j, 0], tables.start_uv[face, j, 1]
        u, v, plain, cycled = u0, v0, 0, True
        for _ in range(30):
            surface_eval(cp, tu, tv, u, v, work)
            plain += 1
            du, dv, _ = _meridional_step(ev, x0, r0)
            un, vn = min(max(u - du, 0.0), 1.0), min(max(v - dv, 0.0), 1.0)
            stalled = un == u and vn == v
            u, v = un, vn
            if max(abs(du), abs(dv)) < 1e-11 or stalled:
                cycled = False
                break
        surface_eval(cp, tu, tv, u, v, work)
        resid = math.hypot(ev[0, 0] - x0, math.hypot(ev[0, 1], ev[0, 2]) - r0)
        cycled = cycled and resid >= 1e-7
        descending, f = 0, np.nan
        if cycled:
            u, v = u0, v0
            surface_eval(cp, tu, tv, u, v, work)
            descending = 1
            du, dv, f = _meridional_step(ev, x0, r0)
            for _ in range(60):
                t, moved = 1.0, False
                for _ in range(20):
                    un, vn = min(max(u - t * du, 0.0), 1.0), min(max(v - t * dv, 0.0), 1.0)
                    if un == u and vn == v:
                        break
                    surface_eval(cp, tu, tv, un, vn, work)
                    descending += 1
                    dun, dvn, fn = _meridional_step(ev, x0, r0)
                    if fn < f:
                        moved = True
                        break
                    t *= 0.5
                if not moved:
                    break
                step = max(abs(un - u), abs(vn - v))
                u, v, du, dv, f = un, vn, dun, dvn, fn
                if step < 1e-11 or f < 1e-12:
                    break
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4], out[k, 5] = plain, cycled, descending, f, x0, r0
    return out


def span_boxes(cp, tu, tv, margin=1e-6):
    """(n, 4) x and r bounds of the face over each knot span: from its 16 control points (convex hull)."""
    boxes = []
    for sv in range(3, cp.shape[1]):
        for su in range(3, cp.shape[2]):
            if tu[su + 1] <= tu[su] or tv[sv + 1] <= tv[sv]:
                continue
            x, y, z = cp[:, sv - 3:sv + 1, su - 3:su + 1].reshape(3, -1)
            d = np.array([y.mean(), z.mean()]) / math.hypot(y.mean(), z.mean())
            boxes.append((x.min() - margin, x.max() + margin, max(0.0, (y * d[0] + z * d[1]).min()) - margin,
                          np.hypot(y, z).max() + margin))
    return np.array(boxes)


def main():
    g = load_geometry(CONFIG / "default_blisk.yaml")
    field = FastChannelField(g.blisk, spacing=0.1, cache_dir=DEFAULT_CACHE, cache_key=g.geometry_id)
    opts = PlanOptions(search=SearchOptions(method="default", step=0.1, exit_side="downstream"))
    plan = plan_channel(g, 0, "rear", opts, field=field, design=rear_design(), exact_clearance=False)
    P, V = np.ascontiguousarray(plan.poses), np.ascontiguousarray(plan.electrode_mesh.vertices)
    full = field._plain_args(0)
    args = (full.channel_angle, full.params, full.shape, full.tables)
    trees = search_trees(P, V)
    print(json.dumps({"samples": len(P), "vertices": len(V), "numba_threads": numba.get_num_threads()}))
    suction_points = None
    for s, name in enumerate(("suction", "pressure", "hub", "shroud")):
        def search():
            return surface_minimum(s, P, V, trees, args)                       # every vertex
        search()                                        # compiled or loaded outside the clock
        t = time.perf_counter()
        best, _, _, evaluations, keys = search()
        spent = time.perf_counter() - t
        print(json.dumps({"surface": name, "search_s": round(spent, 3), "exact_solves": int(evaluations),
                          "us_per_solve": round(spent / evaluations * 1e6, 2), "minimum_mm": round(best, 4)}))
        if s == 0:
            ts, ks = keys // len(V), keys % len(V)
            suction_points = np.einsum("nij,nj->ni", P[ts, :3, :3], V[ks]) + P[ts, :3, 3]
    out = {}
    for label, footprint_only in (("exact_solve_us", False), ("footprint_test_us", True)):
        _solve_all(0, suction_points[:10], *args, footprint_only)
        t = time.perf_counter()
        _solve_all(0, suction_points, *args, footprint_only)
        out[label] = round((time.perf_counter() - t) / len(suction_points) * 1e6, 2)
    counts = _footprint_counts(0, suction_points, *args)
    cycled = counts[:, 1] > 0
    x, r = counts[cycled, 4], counts[cycled, 5]
    tables = named_exact(full.params, full.shape, full.tables)[2]
    boxes = span_boxes(tables.cp_s, tables.tu_s, tables.tv_s)
    in_a_box = np.zeros(len(x), dtype=bool)
    for x0, x1, r0, r1 in boxes:
        in_a_box |= (x >= x0) & (x <= x1) & (r >= r0) & (r <= r1)
    out.update(points=len(suction_points), plain_newton_cycled=int(cycled.sum()),
               descending_evaluations_mean=round(float(counts[cycled, 2].mean()), 1) if cycled.any() else 0.0,
               descending_landed=int((counts[cycled, 3] < 1e-14).sum()),
               descending_final_residual_mm=[round(float(q), 4) for q in
                                             np.sqrt(np.quantile(counts[cycled, 3], [0, 0.5, 1]))] if cycled.any() else [],
               knot_spans=len(boxes), cycled_outside_every_span_box=int((~in_a_box).sum()))
    print(json.dumps({"surface": "suction", **out}))


if __name__ == "__main__":
    main()
