"""``edm-plan plan``: a real plan written and re-checked exactly, failures with their error code."""

import io
import re

import numpy as np
import pytest

from edm_planner.cli import main
from edm_planner.errors import ErrorCode
from edm_planner.geometry.loader import load_geometry
from edm_planner.records.plan_export import read_plan

from conftest import CONFIG

REAR = ["--electrode", "rear", "--method", "max_min_distance", "--exit-side", "downstream", "--step", "0.2"]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """The default blisk with a reduced front/rear split electrode design, and a shared field cache."""
    d = tmp_path_factory.mktemp("cli")
    text = (CONFIG / "default_blisk.yaml").read_text()
    assert "\nelectrode:" not in text
    yaml = d / "rear_blisk.yaml"
    yaml.write_text(text + "\nelectrode:\n  circumferential_reduction: 0.045\n  radial_reduction: 1.5\n"
                           "  split: front_rear\n  split_overlap: 1.0\n")
    return yaml, str(d / "cache"), d


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    return main(argv, out, err), out.getvalue(), err.getvalue()


@pytest.mark.slow
def test_plan_writes_a_certified_export_that_passes_the_exact_recheck(setup):
    yaml, cache, d = setup
    rc, out, err = _run(["plan", "--geometry", str(yaml), "--channel", "3", "--out", str(d / "plan"),
                         "--cache-dir", cache] + REAR)
    assert rc == 0, err
    assert "channel 3, electrode rear" in out
    lower = out.split("certified lower bound over the path [mm]:")[1].split("\n")[0]
    exact = out.split("exact minimum over every vertex at every sample [mm]:")[1].split("\n")[0]
    lower = [float(v) for v in lower.replace(",", " ").split()[1::2]]
    exact = [float(v) for v in exact.replace(",", " ").split()[1::2]]
    assert len(lower) == len(exact) == 4 and all(0.02 <= lo <= ex for lo, ex in zip(lower, exact)), out
    assert "search" in err and "certified" in err          # progress lines on stderr
    g = load_geometry(yaml)
    plan = read_plan(d / "plan")
    assert plan.success and plan.channel == 3 and plan.doc["method"] == "max_min_distance"
    assert plan.doc["settings"]["search"]["step"] == 0.2 and plan.doc["geometry_id"] == g.geometry_id
    # the last sample is the machining pose in channel 3: A = 3 * pitch, the rest zero
    np.testing.assert_allclose(plan.axes[-1], [0, 0, 0, 3 * g.blisk.pitch, 0], atol=1e-9)
    # edm-plan check: the planner's margins (0.02 mm) hold by the exact clearance of every vertex at
    # every sample; at the machining pose the hub is the 0.1 mm discharge gap away
    rc, out, err = _run(["check", str(d / "plan"), "--geometry", str(yaml), "--threshold", "0.019"])
    assert rc == 0, err
    assert "passed" in out
    clear = dict(part.split() for part in
                 out.split("exact minimum over every vertex at every sample [mm]: ")[1].split("\n")[0].split(", "))
    assert min(float(v) for v in clear.values()) >= 0.019 and float(clear["hub"]) == pytest.approx(0.1, abs=2e-3)
    # the re-check of the export finds the exact minimum the plan reported
    assert [float(clear[s]) for s in ("suction", "pressure", "hub", "shroud")] == exact
    step = float(out.split("largest vertex step ")[1].split()[0])
    assert step <= 0.05
    # edm-plan plot: pictures of the export
    rc, out, err = _run(["plot", str(d / "plan"), "--out", str(d / "pictures")])
    assert rc == 0, err
    for name in ("axes_vs_index.png", "channel.png", "channel.glb"):
        assert (d / "pictures" / name).stat().st_size > 10_000
    # a plan checked against another geometry is refused before any work
    rc, out, err = _run(["check", str(d / "plan"), "--geometry", str(CONFIG / "default_blisk.yaml")])
    assert rc == ErrorCode.INVALID_REQUEST and "was made for geometry" in err


def test_geometry_validate_and_info(tmp_path):
    rc, out, err = _run(["geometry", "validate", str(CONFIG / "rotor37.yaml")])
    assert rc == 0 and "valid" in out and "36 blades" in out
    rc, out, err = _run(["geometry", "info", str(CONFIG / "rotor37.yaml")])
    assert rc == 0 and "blade_count: 36" in out and "min_channel_width: 20" in out
    bad = tmp_path / "bad.yaml"
    bad.write_text("blade_count: [unclosed\n")
    rc, out, err = _run(["geometry", "validate", str(bad)])
    assert rc == ErrorCode.FILE_ERROR and "error: FILE_ERROR" in err


def test_geometry_info_says_what_was_sliced_of_a_blade_mesh():
    """The mesh blisk's STL reaches about 0.6 mm past hub and shroud: sliced to 3 % of the smallest height."""
    rc, out, err = _run(["geometry", "info", str(CONFIG / "mesh_blisk.yaml")])
    assert rc == 0 and "blade_source: mesh" in out
    info = dict(line.split(": ", 1) for line in out.splitlines())
    assert info["input_mesh_wall_overlap_mm"] == "0.558"               # 3 % of the 18.6 mm smallest height
    # the STL ends 0.57-0.65 mm past the walls: where its own end (less the slicing inset) lies inside 0.558 mm,
    # that station is sliced there, elsewhere at the 3 %
    for wall in ("hub", "shroud"):
        assert re.fullmatch(r"all|\d+ of 81 stations", info[f"input_mesh_clipped_to_{wall}"]), wall
    for key in ("axial_extent_mm", "radial_extent_mm", "sliced_axial_extent_mm", "sliced_hub_side_radius_mm",
                "sliced_tip_side_radius_mm", "beyond_hub_mm", "beyond_shroud_mm"):
        lo, hi = (float(v) for v in info[f"input_mesh_{key}"].strip("[]").split(", "))
        assert lo <= hi, key
    beyond = [float(v) for key in ("beyond_hub_mm", "beyond_shroud_mm")
              for v in info[f"input_mesh_{key}"].strip("[]").split(", ")]
    assert 0.5 < min(beyond) <= max(beyond) < 0.7
    rc, out, err = _run(["geometry", "info", str(CONFIG / "rotor37.yaml")])
    assert rc == 0 and "input_mesh_" not in out                         # blade sections: nothing sliced


def test_failures_exit_with_their_error_code(setup, tmp_path):
    yaml, cache, _ = setup
    # margins above the 0.1 mm discharge gap: the electrode violates them at its machining pose
    rc, out, err = _run(["plan", "--geometry", str(yaml), "--channel", "0", "--out", str(tmp_path / "f"),
                         "--cache-dir", cache, "--margin-hub-shroud", "0.2"] + REAR)
    assert rc == ErrorCode.ELECTRODE_IN_COLLISION and out == ""
    assert err.strip().splitlines()[-1].startswith("error: ELECTRODE_IN_COLLISION: ")
    assert read_plan(tmp_path / "f", require_success=False).error_code == ErrorCode.ELECTRODE_IN_COLLISION
    rc, _, err = _run(["plan", "--geometry", str(yaml), "--channel", "60", "--out", str(tmp_path / "g"),
                       "--cache-dir", cache])
    assert rc == ErrorCode.INVALID_REQUEST and "--channel must be in 0 .. 59" in err
    rc, _, err = _run(["plan", "--geometry", str(tmp_path / "missing.yaml"), "--channel", "0",
                       "--out", str(tmp_path / "h")])
    assert rc == ErrorCode.FILE_ERROR and "error: FILE_ERROR" in err
    rc, _, err = _run(["plan", "--geometry", str(yaml), "--channel", "0", "--out", str(tmp_path / "i"),
                       "--step", "-1"])
    assert rc == ErrorCode.INVALID_REQUEST and "step must be a positive number" in err


@pytest.mark.slow
def test_plan_is_kept_in_the_store_and_exported_to_nc_and_csv(setup, tmp_path):
    """plan -> store -> the same request from the store; export by id and by directory agree; NC reads back."""
    from edm_planner.cnc.post import parse_nc

    yaml, cache, _ = setup
    store = str(tmp_path / "store")
    argv = ["plan", "--geometry", str(yaml), "--channel", "5", "--cache-dir", cache, "--store", store] + REAR
    rc, out, err = _run(argv + ["--out", str(tmp_path / "a")])
    assert rc == 0, err
    assert "kept in the plan store" in out
    plan_id = out.split("plan ")[1].split(":")[0]
    rc, out, err = _run(argv + ["--out", str(tmp_path / "b")])
    assert rc == 0 and "from the plan store" in out and "stored" in err and "search" not in err
    a, b = read_plan(tmp_path / "a"), read_plan(tmp_path / "b")
    np.testing.assert_array_equal(a.axes, b.axes)
    rc, out, err = _run(["store", "list", "--store", store])
    assert rc == 0 and "1 plan(s)" in out and plan_id in out and "channel   5" in out
    # export by id from the store and from the export directory: the same program
    rc, out, err = _run(["export", plan_id, "--store", store, "--out", str(tmp_path / "nc")])
    assert rc == 0, err
    assert "peak velocity" in out
    rc, out, err = _run(["export", str(tmp_path / "a")])
    assert rc == 0, err
    by_id = (tmp_path / "nc" / f"{plan_id}.nc").read_text()
    assert by_id == (tmp_path / "a" / f"{plan_id}.nc").read_text()
    nc = parse_nc(by_id)
    assert nc["plan_id"] == plan_id and nc["axis_names"] == ("X", "Y", "Z", "A", "C")
    csv = np.loadtxt(tmp_path / "nc" / f"{plan_id}.csv", delimiter=",", skiprows=1)
    assert nc["times"][-1] == pytest.approx(csv[-1, 0], rel=1e-5) and len(nc["times"]) <= len(csv)
    # the program ends at the machining pose of channel 5: joint A = 5 pitches (degrees in the NC text)
    g = load_geometry(yaml)
    assert csv[-1, 1 + 3 * 3] == pytest.approx(5 * g.blisk.pitch, abs=1e-9)
    np.testing.assert_allclose(nc["positions"][-1, 3], 5 * g.blisk.pitch, atol=1e-6)
    assert "(X JOINT EDM_X MM)" in by_id and "G93" in by_id and "T1 M06" in by_id
    # --replan plans anew (progress of the search) and finds the same plan
    rc, out, err = _run(argv + ["--out", str(tmp_path / "c"), "--replan", "--progress", "bar"])
    assert rc == 0 and f"plan {plan_id}" in out and "search" in err and "%|" in err   # a tqdm bar


def test_export_and_store_errors(setup, tmp_path):
    rc, _, err = _run(["export", "0123456789abcdef", "--store", str(tmp_path / "empty")])
    assert rc == ErrorCode.UNKNOWN_ID and "neither a plan export directory nor a plan id" in err
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "plans.sqlite").write_bytes(b"not a database" * 100)
    rc, _, err = _run(["store", "list", "--store", str(tmp_path / "foreign")])
    assert rc == ErrorCode.FILE_ERROR and "not a usable SQLite database" in err and "left untouched" in err
    assert (tmp_path / "foreign" / "plans.sqlite").read_bytes() == b"not a database" * 100
    rc, _, err = _run(["export", str(tmp_path), "--store", "none"])       # a directory without plan.json
    assert rc == ErrorCode.FILE_ERROR, err
    rc, _, err = _run(["store", "list", "--store", "none"])
    assert rc == ErrorCode.INVALID_REQUEST


@pytest.mark.slow
def test_rough_plans_keeps_and_exports_a_roughing_plan(tmp_path):
    import json

    from edm_planner.cnc.post import parse_nc

    store = str(tmp_path / "store")
    argv = ["rough", "--geometry", str(CONFIG / "default_blisk.yaml"), "--channel", "4", "--store", store]
    rc, out, err = _run(argv + ["--out", str(tmp_path / "r")])
    assert rc == 0, err
    assert "kept in the plan store" in out and "the paper: 57.79 %" in out and "optimise" in err
    plan_id = out.split("roughing plan ")[1].split(":")[0]
    doc = json.loads((tmp_path / "r" / "roughing.json").read_text())
    assert doc["plan_id"] == plan_id and doc["channel"] == 4 and len(doc["positions"]) == len(doc["labels"]) > 20
    mae = float(out.split("optimised")[1].split()[0])
    assert mae == pytest.approx(doc["stats"]["mean_abs"], abs=1e-5) and mae < doc["stats_initial"]["mean_abs"]
    axes = np.loadtxt(tmp_path / "r" / "axes.csv", delimiter=",", skiprows=1)
    for p in doc["positions"][::10]:             # each plunge bottom is a sample of the axis path
        assert axes[p["sample"], 0] == p["sample"]
    rc, out, err = _run(argv)
    assert rc == 0 and "from the plan store" in out and "optimise" not in err
    rc, out, err = _run(["export", plan_id, "--store", store, "--out", str(tmp_path / "nc"), "--format", "nc"])
    assert rc == 0, err
    nc = parse_nc((tmp_path / "nc" / f"{plan_id}.nc").read_text())
    assert nc["plan_id"] == plan_id and 2 <= len(nc["positions"]) <= len(axes)
    rc, _, err = _run(argv + ["--tool-radius", "50"])
    assert rc == ErrorCode.INFEASIBLE and "exceeds r_max" in err
    rc, _, err = _run(argv + ["--allowance", "-1"])
    assert rc == ErrorCode.INVALID_REQUEST and err.count("INVALID_REQUEST") == 1
