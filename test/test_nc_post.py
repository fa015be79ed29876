"""The post-processor and its dialects, read back by an independent G-code parser (pygcode, PyPI).

One real certified plan (the rear electrode of the front/rear split, ``rear_cycle``) and the same plan
under another id as a second electrode make a whole-blisk program over three channels: clear legs, index
moves at the clear position, a tool change. It is written in both shipped dialects and both structures.
pygcode splits every line into words; the few words it does not model (G52, M98, M99, O) are applied by
this test's own interpreter, independent of :func:`edm_planner.cnc.post.read_program`.
"""

import copy
import csv
import io
import math
import re
from dataclasses import replace

import numpy as np
import pytest
from pygcode import Line

from edm_planner.errors import EdmError, ErrorCode
from edm_planner.cnc.config import default_machine_path, load_machine
from edm_planner.cnc.dialect import load_dialect, parse_dialect
from edm_planner.cnc.kinematics import axis_poses
from edm_planner.cnc.nc import program_csv
from edm_planner.cnc.post import ProgramRun, check_program, write_program
from edm_planner.cnc.trajectory import time_run
from edm_planner.machining.program import INDEX, PlanCycle, blisk_program_steps, program_runs

DIALECTS = ("iso_fanuc", "beckhoff_edm_plus")
CHANNELS = 3


@pytest.fixture(scope="module")
def program(rear_cycle):
    g, field, electrode, design, plan, builder = rear_cycle
    a = PlanCycle.of_plan(copy.deepcopy(plan))
    b = replace(a, plan_id="f" * 16, electrode_id="front")
    runs = program_runs(blisk_program_steps([a.plan_id, b.plan_id], CHANNELS), {a.plan_id: a, b.plan_id: b},
                        g.blisk.pitch)
    machine = load_machine(default_machine_path())
    cache = {}
    timed = [time_run(r.legs, machine, cache=cache) for r in runs]
    posts = [ProgramRun(t, r.label, r.plan.plan_id) for t, r in zip(timed, runs)]
    texts = {(d, s): write_program(posts, "prog", plan.geometry_id, "blisk_program", machine, d, s)
             for d in DIALECTS for s in ("subprograms", "flat")}
    return dict(g=g, electrode=electrode, plan=plan, runs=runs, timed=timed, posts=posts, machine=machine,
                texts=texts, csv=program_csv(timed))


def _csv_positions(text, names):
    """Per trajectory, the (n, k) joint positions of the program CSV (what cycle.csv holds) [mm, rad]."""
    rows = list(csv.DictReader(io.StringIO(text)))
    out = {}
    for r in rows:
        out.setdefault(int(r["trajectory"]), []).append(
            [float(r[f"{n}_{'mm' if n in 'XYZ' else 'rad'}"]) for n in names])
    return [np.array(out[k]) for k in sorted(out)]


def interpret(text, dialect):
    """Joint positions per tool and every feed, from pygcode's words (subprograms and G52 applied here)."""
    d = load_dialect(dialect)
    programs, current = {}, None
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line == "%":
            continue
        if line.startswith("%"):                       # ISG program name line
            current = "main"
            programs[current] = []
            continue
        words = Line(line).block.words                # pygcode: every line must parse
        if words and words[0].letter == "O":
            current = "main" if int(words[0].value) == d.program_number else int(words[0].value)
            programs[current] = []
            continue
        programs[current].append((line, words))
    tools, feeds, state = [], [], {"shift": 0.0, "mode": None, "pos": {}}

    def run(name):
        for line, words in programs[name]:
            letters = {w.letter: w.value for w in words if w.letter != "N"}
            gs = {float(w.value) for w in words if w.letter == "G"}
            ms = {float(w.value) for w in words if w.letter == "M"}
            if 52.0 in gs:
                state["shift"] = math.radians(float(letters.get("A", 0.0)))
                continue
            if 98.0 in ms:
                run(int(letters["P"]))
                continue
            if 99.0 in ms:
                return
            if 6.0 in ms:
                assert state["mode"] in (None, 94.0), f"tool change in G{state['mode']}: {line}"
                tools.append([])
                state["pos"] = {}
                continue
            for g in (93.0, 94.0):
                if g in gs:
                    state["mode"] = g
            axes = {k: float(v) for k, v in letters.items() if k in "XYZABC"}
            if not axes:
                continue
            q = {k: (v if k in "XYZ" else math.radians(v) + (state["shift"] if k == "A" else 0.0))
                 for k, v in axes.items()}
            state["pos"].update(q)
            if 1.0 in gs:
                feeds.append((state["mode"], float(letters["F"])))
                if not tools[-1]:
                    tools[-1].append(dict(state["pos_at_start"]))
                tools[-1].append(dict(state["pos"]))
            else:                                       # positioning from the changer: X alone first
                assert 0.0 in gs and not tools[-1], line
                state["pos_at_start"] = dict(state["pos"])
                state.setdefault("positioning", []).append(sorted(axes))

    run("main")
    return tools, feeds, state


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("structure", ("subprograms", "flat"))
def test_an_independent_parser_reads_the_program_back_to_the_timed_points(program, dialect, structure):
    text, stats = program["texts"][(dialect, structure)]
    d = load_dialect(dialect)
    names = tuple(program["timed"][0].axis_names)
    tools, feeds, state = interpret(text, dialect)
    reference = _csv_positions(program["csv"], names)
    assert len(tools) == len(reference) == 2
    res = np.array([0.5 * 10.0 ** -d.decimals(n) * (1.0 if n in "XYZ" else math.pi / 180) for n in names]) + 1e-12
    w = np.array([1.0 if n in "XYZ" else d.rotary_lever for n in names])
    for points, q in zip(tools, reference):
        got = np.array([[p[n] for n in names] for p in points])
        # every program point is a CSV row, in order, within the decimals' rounding ...
        j, kept = 0, []
        for p in got:
            while j < len(q) and np.any(np.abs(q[j] - p) > res):
                j += 1
            assert j < len(q), f"program point {p} is no point of cycle.csv"
            kept.append(j)
        assert kept[0] == 0 and kept[-1] == len(q) - 1
        # ... and every row left out lies within the merge tolerance of its block's line
        for a, b in zip(kept[:-1], kept[1:]):
            if b - a > 1:
                p0, p1 = q[a] * w, q[b] * w
                inner = q[a + 1:b] * w
                s = np.clip((inner - p0) @ (p1 - p0) / ((p1 - p0) @ (p1 - p0)), 0, 1)
                dev = np.linalg.norm(inner - p0 - s[:, None] * (p1 - p0), axis=1).max()
                assert dev <= d.merge_tolerance + 1e-9
    # every F within its mode's range, both modes used (G94 on linear-only moves, G93 with a rotary axis)
    modes = {93.0: d.rotary_feed, 94.0: d.linear_feed}
    for mode, f in feeds:
        assert modes[mode].min <= f <= modes[mode].max, (mode, f)
    assert {m for m, _ in feeds} == {93.0, 94.0}
    # positioning after each tool change: X alone, then the other axes
    assert state["positioning"] == [["X"], sorted(set(names) - {"X"})] * 2
    assert stats.slowed_blocks == 0 and stats.points == sum(len(t.times) - 1 for t in program["timed"])


def test_subprograms_keep_the_program_size_with_the_electrodes_not_the_channels(program):
    sub, s_stats = program["texts"][("iso_fanuc", "subprograms")]
    flat, f_stats = program["texts"][("iso_fanuc", "flat")]
    # the two "electrodes" run the same cycle: one channel pass, called in every channel by each
    assert s_stats.subprograms == 1 and s_stats.calls == 2 * CHANNELS
    assert len(re.findall(r"^N\d+ G52 A-?\d+\.\d{4}$", sub, re.M)) == 2 * CHANNELS
    assert len(sub) < 0.5 * len(flat)
    assert f_stats.subprograms == 0 and "M98" not in flat
    # the main program comes first, its subprogram after (LinuxCNC wants it so), each ends as it must
    assert sub.index("O1000") < sub.index("O1001") and sub.rstrip().endswith("M99\n%".rstrip())


def test_tool_change_sequence_at_the_clear_position(program):
    text, _ = program["texts"][("iso_fanuc", "subprograms")]
    lines = [re.sub(r"^N\d+ ", "", line) for line in text.splitlines() if not line.startswith("(")]
    for tool, offset in ((1, "G54"), (2, "G55")):
        i = lines.index(f"T{tool} M06")
        assert lines[i - 1] == "G94" and lines[i + 1:i + 3] == [f"G43 H{tool}", offset]
        assert re.fullmatch(r"G00 X-?\d+\.\d{4}", lines[i + 3])
        assert re.fullmatch(r"G00 Y\S+ Z\S+ A\S+ C\S+", lines[i + 4])
    # before the second tool change the first electrode is back at its clear position, G52 cancelled
    i = lines.index("T2 M06")
    assert lines[i - 2] == "G52 A0." and "M30" in lines


def test_every_index_and_clear_move_is_certified_beyond_the_part(program):
    plan, electrode = program["plan"], program["electrode"]
    zone = plan.cycle.clear_zone
    margin = plan.cycle.margin
    names = tuple(plan.axis_names)
    verts = np.asarray(electrode.mesh.vertices)
    for run in program["runs"]:
        phases = [leg.phase for leg in run.legs]
        assert phases[0] == "clear" and phases[-1] == "clear" and phases.count(INDEX) == CHANNELS - 1
        for leg in run.legs:
            assert np.all(leg.clearance_lower_bound >= margin - 1e-12), (leg.phase, leg.label)
            if leg.phase != INDEX:
                continue
            i = run.legs.index(leg)
            assert run.legs[i - 1].phase == "clear" and run.legs[i + 1].phase == "clear"
            # independently: the electrode's vertices all along the A turn lie beyond the envelope's plane
            a = np.linspace(0.0, 1.0, 200)[:, None]
            q = leg.samples[0] + a * (leg.samples[-1] - leg.samples[0])
            poses = axis_poses(plan.final_pose, names, q)
            x = np.einsum("nij,vj->nvi", poses[:, :3, :3], verts)[..., 0] + poses[:, None, 0, 3]
            edge = zone.envelope[1] if zone.side > 0 else -zone.envelope[0]
            gap = (zone.side * x - edge).min()
            assert gap >= leg.clearance_lower_bound[0] - 1e-9 >= margin - 1e-9
    assert zone.separation(zone.clear_x) >= 2.0 - 1e-9          # the cycle's clearance


@pytest.mark.parametrize("tamper, why", [
    (lambda t: re.sub(r"(G93 G01 [^\n]*F)\S+", r"\g<1>12000.000", t, count=1), "outside"),
    (lambda t: t.replace("(EDM_PLANNER PLAN PROG)", "(edm_planner plan: prog [x])"), "comment"),
    (lambda t: t.replace("(EDM_PLANNER PLAN PROG)", "(" + "A" * 100 + ")"), "comment"),
    (lambda t: t.replace("N20 G94\n", "N20 G93\n", 1), "tool change in G93"),
    (lambda t: t.replace("N20 G94\n", "N20 C180\n", 1), "axis words without motion"),
    (lambda t: t.replace("(EDM_PLANNER PLAN PROG)", "(" + "A" * 30 + ")" + " " * 300), "characters"),
])
def test_the_final_check_refuses_a_program_breaking_its_dialect(program, tamper, why):
    text, _ = program["texts"][("iso_fanuc", "flat")]
    check_program(text, "iso_fanuc", program["timed"])             # as written: accepted
    bad = tamper(text)
    assert bad != text
    with pytest.raises(EdmError) as e:
        check_program(bad, "iso_fanuc", program["timed"])
    assert e.value.code == ErrorCode.INTERNAL and why in e.value.message


def test_the_final_check_refuses_points_that_are_not_the_trajectory(program):
    text, _ = program["texts"][("iso_fanuc", "flat")]
    i = text.index(" G01 X") + len(" G01 X")
    bad = text[:i] + "9" + text[i:]                                   # one coordinate changed
    with pytest.raises(EdmError) as e:
        check_program(bad, "iso_fanuc", program["timed"])
    assert e.value.code == ErrorCode.INTERNAL


def test_a_narrow_feed_range_slows_blocks_and_says_so(program):
    doc = _dialect_doc("iso_fanuc")
    doc["feed"]["rotary"]["max"] = 60.0                            # no rotary block shorter than 1 s
    d = parse_dialect(doc, "narrow")
    text, stats = write_program(program["posts"][:1], "prog", "g", "plan", program["machine"], d, "flat")
    assert stats.slowed_blocks > 0 and stats.added_seconds > 0 and "BLOCKS SLOWED" in text
    back = check_program(text, d)
    g93 = [f for tr in back["trajectories"] for code, f in tr["feeds"] if code == "G93"]
    assert g93 and max(g93) <= 60.0
    # slower, never faster: the program takes the timed duration plus what the header says it added
    total = back["trajectories"][0]["times"][-1]
    duration = program["timed"][0].duration
    assert total > duration and abs(total - duration - stats.added_seconds) < 1e-4 * total


def _dialect_doc(name):
    import yaml
    from edm_planner.cnc.dialect import DIALECT_DIR
    return yaml.safe_load((DIALECT_DIR / f"{name}.yaml").read_text())


@pytest.mark.parametrize("change, key", [
    (lambda d: d.pop("feed"), "feed.linear_only.code"),
    (lambda d: d["feed"]["rotary"].update(unit="per_fortnight"), "feed.rotary.unit"),
    (lambda d: d["feed"]["rotary"].update(min=10.0, max=1.0), "feed.rotary"),
    (lambda d: d["comments"].update(allowed="A-Z()"), "comments.allowed"),
    (lambda d: d.update(work_offsets=[]), "work_offsets"),
    (lambda d: d["block_numbers"].update(enabled="yes"), "block_numbers.enabled"),
])
def test_a_bad_dialect_file_is_refused_naming_the_key(change, key):
    doc = _dialect_doc("iso_fanuc")
    change(doc)
    with pytest.raises(EdmError) as e:
        parse_dialect(doc, "bad.yaml")
    assert e.value.code == ErrorCode.INVALID_REQUEST and key in e.value.message


def test_unknown_dialect_names_the_shipped_ones(tmp_path):
    with pytest.raises(EdmError) as e:
        load_dialect("sodick_lq")
    assert e.value.code == ErrorCode.INVALID_REQUEST and "iso_fanuc" in e.value.message
    p = tmp_path / "mine.yaml"
    p.write_text("name: [unclosed\n")
    with pytest.raises(EdmError) as e:
        load_dialect(str(p))
    assert e.value.code == ErrorCode.INVALID_REQUEST and "malformed YAML" in e.value.message


def test_decimals_per_axis(program):
    doc = _dialect_doc("iso_fanuc")
    doc["decimals"]["C"] = 3
    d = parse_dialect(doc, "c3")
    text, _ = write_program(program["posts"][:1], "prog", "g", "plan", program["machine"], d, "flat")
    c_words = re.findall(r" C(-?\d+\.\d*)", text)
    x_words = re.findall(r" X(-?\d+\.\d*)", text)
    assert c_words and all(len(w.split(".")[1]) == 3 for w in c_words)
    assert all(len(w.split(".")[1]) == 4 for w in x_words)
    check_program(text, d, program["timed"][:1])         # the coarser C still reproduces the timed points


def test_condition_flushing_and_generator_words_follow_the_cutting_legs(program):
    plan = copy.deepcopy(program["plan"])
    for leg in plan.cycle.legs:                  # feed and process erode in the finish regime
        if leg.phase in ("feed", "process"):
            leg.regime, leg.removed_volume = "finish", 0.5
    (run,) = program_runs([(plan.plan_id, 0)], {plan.plan_id: PlanCycle.of_plan(plan)})
    timed = time_run(run.legs, program["machine"])
    code = program["machine"].process.regimes["finish"].condition_code
    doc = _dialect_doc("iso_fanuc")
    doc["edm"].update(condition_select="E{digits}", generator_on="M84", generator_off="M85")
    d = parse_dialect(doc, "with generator words")
    text, _ = write_program([ProgramRun(timed, "rear", plan.plan_id)], "p", "g", "plan", program["machine"], d)
    words = [re.sub(r"^N\d+ ", "", line) for line in text.splitlines()]
    on, off = words.index("M84"), words.index("M85")
    digits = re.sub(r"\D", "", code)
    assert words[on - 2:on] == [f"E{digits}", "M08"] and words[off + 1] == "M09"
    assert words.count("M84") == 1 and words.count("M85") == 1         # on once for all cutting legs
    # on before the feed's first block, off before the return's
    assert words.index("(PHASE FEED CH 0 FEED)") < on < next(i for i, w in enumerate(words) if w.startswith("G")
                                                              and i > words.index("(PHASE FEED CH 0 FEED)"))
    assert off == words.index("(PHASE RETURN CH 0 RETURN _THE FEED REVERSED_)") + 1
    check_program(text, d, [timed])
    # the process model's code itself as the word: on a machine with a C axis it reads as a C move: refused
    doc["edm"]["condition_select"] = "{code}"
    with pytest.raises(EdmError) as e:
        write_program([ProgramRun(timed, "rear", plan.plan_id)], "p", "g", "plan", program["machine"],
                      parse_dialect(doc, "code word"))
    assert e.value.code == ErrorCode.INTERNAL and "axis words without motion" in e.value.message


def test_channel_passes_within_rounding_of_each_other_share_a_subprogram(program, monkeypatch):
    """A channel's pass is timed on its own A values: its durations came out up to 3e-7 apart from another
    channel's (positions 6e-9 rad), enough to flip a feed's last digit, and the text alone then made a
    subprogram per channel. Passes within the tolerances share one; passes further apart do not."""
    from edm_planner.cnc import post

    posts = program["posts"]
    arrays = posts[0].arrays
    names = tuple(arrays.axis_names)
    ia = names.index("A")
    passes = [(a, b) for what, a, b, _, _ in post._channel_passes(arrays) if what == "pass"]
    assert len(passes) == CHANNELS

    def with_second_pass(dt_scale, da):
        """The first electrode with its second channel's durations scaled and its inner A values moved."""
        a, b = passes[1]
        t = np.array(arrays.times, dtype=np.float64)
        q = np.array(arrays.positions, dtype=np.float64)
        t[a + 1:b + 1] = t[a] + np.cumsum(np.diff(t[a:b + 1]) * dt_scale)
        t[b + 1:] += t[b] - arrays.times[b]
        q[a + 1:b, ia] += da
        return [replace(posts[0], arrays=replace(arrays, times=t, positions=q))] + list(posts[1:])

    def subprograms(runs):
        text, stats = write_program(runs, "prog", program["plan"].geometry_id, "blisk_program",
                                    program["machine"], "iso_fanuc", "subprograms")
        return stats.subprograms, stats.calls

    assert subprograms(posts) == (1, 2 * CHANNELS)
    # 4e-6 slower (feeds 0.01 lower: other text) and 1e-9 rad off: the same motion, one subprogram
    close = with_second_pass(1 + 4e-6, 1e-9)
    assert subprograms(close) == (1, 2 * CHANNELS)
    monkeypatch.setattr(post, "SAME_PASS_TIME", 0.0)
    assert subprograms(close)[0] >= 2, "the texts differ: the tolerance is what joins them"
    monkeypatch.undo()
    # beyond either tolerance: a subprogram of its own
    assert subprograms(with_second_pass(1 + 1e-4, 0.0)) == (2, 2 * CHANNELS)
    assert subprograms(with_second_pass(1.0, 1e-6)) == (2, 2 * CHANNELS)
