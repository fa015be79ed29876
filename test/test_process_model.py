"""The process model (machine YAML ``process:``) and erosion-timed cutting legs (issue 25, points 1 and 3)."""

import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from edm_planner.errors import EdmError, ErrorCode
from edm_planner.cnc.config import default_machine_path, load_machine, parse_machine
from edm_planner.cnc.trajectory import time_leg, time_run
from edm_planner.machining.program import PlanCycle, ProgramLeg
from edm_planner.process.model import DEFAULT_PROCESS, parse_process

AXES = ("X", "Y", "Z", "A", "C")


@pytest.fixture(scope="module")
def machine():
    return load_machine(default_machine_path())


def _doc():
    return yaml.safe_load(default_machine_path().read_text())


def test_the_default_machine_file_configures_rough_and_finish_for_copper_on_a_superalloy(machine):
    p = machine.process
    assert p == DEFAULT_PROCESS, "config/machine.yaml and the built-in defaults must agree"
    assert set(p.regimes) >= {"rough", "finish"}
    assert p.rough.spark_gap > p.finish.spark_gap
    assert p.rough.removal_rate > p.finish.removal_rate
    assert p.rough.roughness_ra > p.finish.roughness_ra
    assert p.finish.spark_gap == 0.1, "the finish gap is the electrode designs' default discharge gap"
    assert math.isclose(p.rough_electrode_gap, p.rough.spark_gap + p.finish_allowance)
    text = default_machine_path().read_text()
    for source in ("Ahmad & Lajis", "Kuppan", "Czelusniak", "Liu Yuting"):
        assert source in text, f"the defaults name their source {source}"
    # 120 mm^3 at 40 mm^3/min: 3 minutes
    assert p.rough.erosion_seconds(120.0) == pytest.approx(180.0)


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["process"]["regimes"]["rough"].pop("removal_rate_mm3_min"), "missing key 'removal_rate_mm3_min'"),
    (lambda d: d["process"]["regimes"]["finish"].update(spark_gap_mm=-0.1), "must not be negative"),
    (lambda d: d["process"]["regimes"]["finish"].update(wear_ratio_percent=500), "out of range"),
    (lambda d: d["process"]["regimes"]["rough"].update(removal_rate_mm3_min="fast"), "expected a finite number"),
    (lambda d: d["process"]["regimes"]["rough"].update(spark_gap_m=0.2), "unknown keys ['spark_gap_m']"),
    (lambda d: d["process"]["regimes"]["rough"].update(condition_code=""), "condition_code"),
    (lambda d: d["process"]["regimes"]["rough"].update(spark_gap_mm=0.05), "smaller than the finish gap"),
    (lambda d: d["process"].update(finish_allowance_mm=0.4), "exceeds the 0.5 mm"),
    (lambda d: d["process"].update(wear_compensation="yes"), "expected true or false"),
    (lambda d: d["process"].update(speed=3), "unknown keys ['speed']"),
    (lambda d: d.update(process=[1, 2]), "expected a mapping"),
])
def test_bad_process_sections_name_the_key(edit, words):
    doc = _doc()
    edit(doc)
    with pytest.raises(EdmError) as exc:
        parse_machine(doc, "m.yaml")
    assert exc.value.code == ErrorCode.INVALID_REQUEST
    assert words in exc.value.message and "m.yaml" in exc.value.message


def test_a_given_section_overrides_key_by_key_and_an_absent_one_is_the_default():
    doc = _doc()
    del doc["process"]
    assert parse_machine(doc).process == DEFAULT_PROCESS
    p = parse_process({"regimes": {"semi": {"spark_gap_mm": 0.15, "removal_rate_mm3_min": 12, "wear_ratio_percent": 6,
                                            "roughness_ra_um": 3.2, "condition_code": "C140"}},
                       "wear_compensation": True})
    assert set(p.regimes) == {"rough", "finish", "semi"} and p.regimes["semi"].removal_rate == 12.0
    # compensation lets the front wear further (as far as its certified reach), not the side faces
    assert p.wear_compensation and p.max_compensated_wear == DEFAULT_PROCESS.max_compensated_wear
    assert p.wear_limit("rough") == DEFAULT_PROCESS.wear_limit("rough") == 0.03
    assert p.wear_limit("finish") == DEFAULT_PROCESS.wear_limit("finish") == 0.02
    assert p.rough == DEFAULT_PROCESS.rough


def _plan():
    return PlanCycle("p" * 16, "g", "main", 0, AXES, np.eye(4), np.zeros((2, 5)))


def _legs(volume, regime="rough"):
    plan = _plan()
    out = np.array([[0.0, 0, 0, 0, 0], [2.0, 0.3, 0, 0.01, 0]])
    back = out[::-1].copy()
    return [ProgramLeg("feed", "feed", out, 0, plan, regime, volume),
            ProgramLeg("return", "return", back, 0, plan, "", 0.0)]


def test_a_cutting_leg_takes_its_volume_over_the_removal_rate_and_a_rapid_keeps_the_machine_limits(machine):
    rough = machine.process.rough
    motion = time_leg(_legs(0.0)[0].samples, AXES, machine)
    arrays = time_run(_legs(150.0), machine)
    feed, ret = arrays.phases
    assert feed.regime == "rough" and feed.condition_code == rough.condition_code and feed.generator_on
    assert not ret.generator_on and ret.regime == ""
    # the feed: exactly 150 mm^3 / 40 mm^3/min = 225 s (to the whole nanosecond), the return at the limits
    assert ret.time == pytest.approx(rough.erosion_seconds(150.0), abs=1e-9)
    assert arrays.duration - ret.time == pytest.approx(motion.duration, abs=1e-9)
    k = rough.erosion_seconds(150.0) / motion.duration
    assert k > 10
    # the same path, slower: positions equal, velocities k times lower
    n = len(motion.times)
    assert np.array_equal(arrays.positions[:n], motion.positions)
    assert np.allclose(arrays.velocities[:n] * k, motion.velocities, atol=1e-12)
    assert np.allclose(arrays.times[:n], motion.times * k, rtol=1e-9)
    # a leg whose motion takes longer than its erosion keeps its motion time
    quick = time_run(_legs(1e-3), machine)
    assert quick.phases[1].time == pytest.approx(motion.duration, abs=1e-9)
    assert quick.phases[0].generator_on


def test_nothing_removed_means_the_generator_stays_off_and_an_unknown_regime_is_refused(machine):
    dry = time_run(_legs(0.0), machine)
    assert not any(m.generator_on for m in dry.phases)
    assert dry.phases[1].time == pytest.approx(time_leg(_legs(0.0)[0].samples, AXES, machine).duration)
    with pytest.raises(EdmError) as exc:
        time_run(_legs(10.0, regime="medium"), machine)
    assert exc.value.code == ErrorCode.INVALID_REQUEST and "'medium'" in exc.value.message
    # a machine without the regime's removal-rate override: the other machine's rate times it
    slow = replace(machine, process=replace(machine.process, regimes=dict(
        machine.process.regimes, rough=replace(machine.process.rough, removal_rate=4.0))))
    assert time_run(_legs(150.0), slow).phases[1].time == pytest.approx(2250.0, abs=1e-9)
