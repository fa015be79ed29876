"""The short soak (issue 15): mixed calls from two clients against one set of node processes.

``make soak`` runs the long one (1000 CheckInterference, 100 PlanChannel) and writes ``out/soak.json``.
"""

import pytest

from edm_planner.nodes.programs.soak import run_soak, schedule

#: private memory (RssAnon, what a leak grows; the distance field is mapped from its cache file, its pages
#: count in VmRSS as queries touch them) a node may gain over the short soak's calls after the first 25
#: [MB]: the loader nothing to speak of; the checker a step of up to about 5 MB once (most likely when a call first lands on
#: another of its executor's 8 threads, which glibc gives its own malloc arena; on a fresh clone 146.8 ->
#: 151.8 MB between calls 25 and 50, then 151.9 at call 100); the planner rises by about 10 MB with each of its
#: first few plans (three here), then levels off (``make soak``: within 625 .. 656 MB over 1000 further calls
#: and 50 plans)
RSS_GROWTH_BOUND_MB = {"geometry_loader": 5.0, "interference_checker": 12.0, "trajectory_planner": 40.0}
#: what a leak shows and a one-time step does not: growth over the second half of the calls (50 -> 100), once
#: every path of the loader and the checker has run [MB] (the planner's third new plan falls there)
LATE_GROWTH_BOUND_MB = {"geometry_loader": 1.0, "interference_checker": 2.0}


def test_the_schedule_mixes_distinct_and_repeated_plans_among_the_checks():
    calls = schedule(100, 10, 4, blade_count=60)
    plans = [a for k, a in calls if k == "plan"]
    assert len(calls) == 110 and len(plans) == 10 and sum(k == "check" for k, _ in calls) == 100
    distinct = list(dict.fromkeys(plans))
    assert distinct == [(1, 1), (2, 1), (3, 1), (4, 1)]                 # every distinct request, in order
    first_plan = min(i for i, (k, _) in enumerate(calls) if k == "plan")
    assert 0 < first_plan < 11 and calls[-1][0] == "check"               # spread among the checks
    assert schedule(100, 10, 4, 60) == calls                             # deterministic


@pytest.mark.slow
def test_a_short_soak_keeps_memory_flat_and_answers_every_call(tmp_path, field_cache):
    result = run_soak(tmp_path, n_check=100, n_plan=5, n_distinct=3, sample_every=25, cache_dir=field_cache,
                      exact_every=20, timeout=300.0)
    print({k: v for k, v in result.items() if k != "memory"})
    for m in result["memory"]:
        print(m)
    assert not result["failures"] and not result["mismatches"]
    assert result["calls_done"] == 105 and len(result["memory"]) == 1 + 105 // 25
    lat = result["latency"]
    assert (lat["check_fast"]["count"], lat["check_exact"]["count"]) == (95, 5)
    assert lat["plan_new"]["count"] == 3 and lat["plan_stored"]["count"] == 2   # each distinct request planned once
    for node, growth in result["private_growth_mb"].items():
        assert growth <= RSS_GROWTH_BOUND_MB[node], f"{node} grew by {growth} MB: {result['memory']}"
    at = {m["calls"]: m["private_mb"] for m in result["memory"]}
    for node, bound in LATE_GROWTH_BOUND_MB.items():
        late = at[100][node] - at[50][node]
        assert late <= bound, f"{node} grew by {late:.1f} MB over calls 50 to 100: {result['memory']}"
