"""Fuzzing the `edm-plan` command line and the geometry files it reads (issue 15, reliability point 1).

Hypothesis-generated command lines and files: malformed YAML, wrong types, inverted hub/shroud, YAML bombs
and deep nesting, empty, garbage, non-watertight and enormous STL blade meshes, broken plan and set exports,
machine files, hostile option values (NaN, infinities, negative sizes) and plain wrong arguments. Every run
must end with an exit code (the ErrorCode value, 1 .. 7, or argparse's 2; never INTERNAL's 8, never 0 for a
bad input) and one clear ``error: CODE: message`` line on stderr naming what was wrong; no exception may
escape. Most examples call ``edm_planner.cli.main(argv, out, err)`` in this process (fast); a few run the
installed ``edm-plan`` as a subprocess, to show that no traceback reaches the user.

Nothing here may plan: each command line carries at least one fault that the command meets before planning.
EDM_FUZZ_EXAMPLES=N runs N examples per test; EDM_FUZZ_COUNTS=FILE.json receives the counts.
"""

import contextlib
import io
import json
import os
import struct
import subprocess
import sys
import textwrap

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from edm_planner.cli import main
from edm_planner.errors import ErrorCode

from conftest import CONFIG
from test_fuzz_services import (CHARS, SANDBOX_FILES, bad_documents, fuzz_settings, make_sandbox,
                                record_counts, summary_line)

NAN, INF = float("nan"), float("inf")
DEFAULT = str(CONFIG / "default_blisk.yaml")
COUNTS = {}


def count(area, rc):
    c = COUNTS.setdefault(area, {"runs": 0})
    c["runs"] += 1
    c[f"exit_{rc}"] = c.get(f"exit_{rc}", 0) + 1


@pytest.fixture(scope="module")
def files(request, tmp_path_factory):
    """The services' sandbox (bad geometry files, symlinks) plus broken STLs, exports and machine files."""
    root = tmp_path_factory.mktemp("fuzz_cli")
    sandbox = make_sandbox(root)
    write_stl_files(sandbox)
    write_exports(root)
    yield root, sandbox
    record_counts("cli", COUNTS)
    runs = sum(c["runs"] for c in COUNTS.values())
    areas = ", ".join(f"{k} {v['runs']}" for k, v in sorted(COUNTS.items()))
    summary_line(request, f"fuzz cli: {areas}, {runs} runs, 0 tracebacks")


def run(argv):
    """(exit status, stdout, stderr) of ``edm-plan argv`` in this process; no exception may escape."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err):          # argparse writes its usage errors to sys.stderr
        try:
            rc = main([str(a) for a in argv], out, err)
        except SystemExit as exc:                  # argparse: usage errors exit 2
            rc = exc.code
    return rc, out.getvalue(), err.getvalue()


def check_failure(argv, rc, err, named=(), area="cli"):
    """A clean failure: a defined exit status, one clear error line at the end of stderr naming the fault."""
    lines = err.strip().split("\n")
    assert "Traceback" not in err, f"{argv}: traceback on stderr:\n{err}"
    assert lines, f"{argv}: exit {rc} with nothing on stderr"
    last = lines[-1]
    if rc == 2 and ": error: " in last and last.startswith("edm-plan"):       # argparse's usage error
        pass
    else:
        assert rc in set(int(c) for c in ErrorCode) - {0}, f"{argv}: exit status {rc!r}:\n{err}"
        assert rc != ErrorCode.INTERNAL, f"{argv}: INTERNAL:\n{err}"
        errors = [ln for ln in lines if ln.startswith("error: ")]
        assert errors == [last], f"{argv}: expected one error line, last on stderr:\n{err}"
        assert last.startswith(f"error: {ErrorCode(rc).name}: "), f"{argv}: exit {rc} but {last!r}"
        if named:
            assert any(n.lower() in last.lower() for n in named), f"{argv}: names none of {named}: {last!r}"
    count(area, rc)


# -- geometry files ------------------------------------------------------------------------------------------

def binary_stl(triangles, count=None):
    data = b"\0" * 80 + struct.pack("<I", len(triangles) if count is None else count)
    for tri in triangles:
        data += struct.pack("<12fH", *([0.0, 0.0, 0.0] + [v for p in tri for v in p]), 0)
    return data


BOX = [((0, 0, 0), (1, 0, 0), (1, 1, 0)), ((0, 0, 0), (1, 1, 0), (0, 1, 0)),
       ((0, 0, 1), (1, 1, 1), (1, 0, 1)), ((0, 0, 1), (0, 1, 1), (1, 1, 1)),
       ((0, 0, 0), (1, 0, 1), (1, 0, 0)), ((0, 0, 0), (0, 0, 1), (1, 0, 1)),
       ((0, 1, 0), (1, 1, 0), (1, 1, 1)), ((0, 1, 0), (1, 1, 1), (0, 1, 1)),
       ((0, 0, 0), (0, 1, 0), (0, 1, 1)), ((0, 0, 0), (0, 1, 1), (0, 0, 1)),
       ((1, 0, 0), (1, 1, 1), (1, 1, 0)), ((1, 0, 0), (1, 0, 1), (1, 1, 1))]

STL_FILES = {
    "empty.stl": b"",
    "garbage.stl": b"solid junk\n" + bytes(range(256)) * 16,
    "open_box.stl": binary_stl(BOX[:-2]),                                      # not watertight
    "tiny_box.stl": binary_stl([[(x * 30, 100 + 20 * y, z * 5) for x, y, z in t] for t in BOX]),  # no blade
    "nan.stl": binary_stl([[(NAN, 0, 0), (1, INF, 0), (0, 1, -INF)]] * 4),
    "claims_huge.stl": binary_stl(BOX, count=2 ** 32 - 1),                     # header: 4 billion triangles
    "ascii_bad.stl": b"solid x\nfacet normal 0 0 1\nouter loop\nvertex a b c\nendloop\nendfacet\nendsolid x\n",
    "degenerate.stl": binary_stl([[(0, 0, 0)] * 3] * 50),
}


def write_stl_files(sandbox):
    doc = yaml.safe_load((CONFIG / "default_blisk.yaml").read_text())
    for name, data in STL_FILES.items():
        (sandbox / name).write_bytes(data)
        (sandbox / f"mesh_{name}.yaml").write_text(yaml.safe_dump({**doc, "blade": {"mesh": name}}))
    # an enormous STL: 2 million random triangles (96 MB would be more than a fuzz run should write: 19 MB
    # of 400 000 triangles of the bounding box's scale)
    import numpy as np

    rng = np.random.default_rng(7)
    tris = rng.uniform([-5, 95, -10], [30, 125, 10], size=(400_000, 3, 3)).astype("<f4")
    rec = np.zeros(len(tris), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = tris
    (sandbox / "enormous.stl").write_bytes(b"\0" * 80 + struct.pack("<I", len(tris)) + rec.tobytes())
    (sandbox / "mesh_enormous.stl.yaml").write_text(yaml.safe_dump({**doc, "blade": {"mesh": "enormous.stl"}}))


CLI_FILES = {  # sandbox file -> words one of which the error must name (the CLI reads files anywhere)
    **{f"mesh_{n}.yaml": [n, "blade", "mesh"] for n in STL_FILES},
    "mesh_enormous.stl.yaml": ["enormous.stl", "blade", "mesh"],
    **{n: w for n, w in SANDBOX_FILES.items() if n in (
        "empty.yaml", "binary.yaml", "latin1.yaml", "huge.yaml", "inverted.yaml", "mesh_garbage.yaml",
        "a_directory.yaml", "loop.yaml", "dangling.yaml", "no_such_file.yaml")},
    "/dev/zero": ["zero"], "/etc/hostname": ["hostname", "mapping", "YAML"],
}


@st.composite
def geometry_file(draw, sandbox):
    """(path, words): a bad document written to the sandbox, or one of the fixed bad files."""
    if draw(st.integers(0, 3)) == 0:
        name = draw(st.sampled_from(sorted(CLI_FILES)))
        return (name if name.startswith("/") else str(sandbox / name)), CLI_FILES[name]
    text, named = draw(bad_documents())
    path = sandbox / "case.yaml"
    path.write_text(text)
    return str(path), named


def test_geometry_files(files):
    root, sandbox = files

    @fuzz_settings(120)
    @given(geometry_file(sandbox), st.sampled_from(["validate", "info"]))
    def fuzz(case, action):
        path, named = case
        argv = ["geometry", action, path]
        rc, out, err = run(argv)
        assert rc != 0, f"{argv}: accepted a bad geometry file:\n{out}"
        check_failure(argv, rc, err, named, area="geometry files")

    fuzz()


# -- command lines ---------------------------------------------------------------------------------------------

def write_exports(root):
    """Broken plan exports, set directories, machine files and a file where a store directory should be."""
    (root / "no_plan").mkdir()
    for name, doc in {"plan_junk": "not json {", "plan_list": "[1, 2]", "plan_empty": "{}",
                      "plan_nan": json.dumps({"format": "edm_planner.plan/1", "plan_id": "x", "samples": [[NAN]]}),
                      "plan_wrong_format": json.dumps({"format": "docx", "units": {"length": "in"}})}.items():
        (root / name).mkdir()
        (root / name / "plan.json").write_text(doc)
    for name, doc in {"set_junk": "{", "set_empty": "{}", "set_types": json.dumps({"electrodes": 7}),
                      "set_escape": json.dumps({"electrodes": [{"plan_id": "p", "export": "../../../etc",
                                                                "order": 0}]}),
                      "set_missing": json.dumps({"electrodes": [{"plan_id": "p", "export": "e0", "order": 0}]})
                      }.items():
        (root / name).mkdir()
        (root / name / "set.json").write_text(doc)
    machines = {"m_junk": "{", "m_list": "[1]", "m_empty": "", "m_nan": "name: m\naxes: {X: {max_velocity: .nan}}\n",
                "m_axes": "name: m\naxes: 7\n", "m_deep": "a: " + "[" * 200 + "]" * 200 + "\n"}
    for name, text in machines.items():
        (root / f"{name}.yaml").write_text(text)
    (root / "store_is_a_file").write_text("not a directory")
    (root / "bad_store").mkdir()
    (root / "bad_store" / "plans.sqlite").write_bytes(b"SQLite format 3\0" + b"\xff" * 200)


POISON_FLOATS = st.sampled_from(["nan", "inf", "-inf", "-1", "-1e-9", "1e309", "0"])


@st.composite
def command_lines(draw, root, sandbox):
    """(argv, words) of a command that must fail before it plans anything."""
    bad_geometry = st.one_of(st.sampled_from([str(sandbox / n) for n in ("empty.yaml", "inverted.yaml",
                                                                          "binary.yaml", "mesh_garbage.yaml")]),
                             st.text(CHARS, min_size=1, max_size=30).map(lambda s: str(root / "nowhere" / s)))
    progress = ["--progress", draw(st.sampled_from(["none", "lines"]))]
    command = draw(st.sampled_from(["plan", "plan", "rough", "export", "check", "plot", "store", "geometry",
                                    "argparse"]))
    out_dir = str(root / "out")
    if command == "plan":
        fault = draw(st.sampled_from(["step", "margin-blade", "margin-hub-shroud", "time-budget", "geometry",
                                      "channel", "discharge-gap", "circumferential-reduction", "radial-reduction",
                                      "split-overlap", "cache-dir"]))
        argv = ["plan", "--geometry", DEFAULT, "--channel", str(draw(st.integers(0, 59))), "--out", out_dir,
                *progress, "--store", "none"]
        if fault in ("step", "margin-blade", "margin-hub-shroud", "time-budget"):
            value = draw(POISON_FLOATS.filter(lambda v: fault != "time-budget" or v != "0") if fault != "step"
                         else POISON_FLOATS)
            if fault.startswith("margin") and value == "0":
                value = "-2"
            argv += [f"--{fault}", value]
            return argv, [fault.replace("-", "_")]
        if fault == "geometry":
            argv[2] = draw(bad_geometry)
            return argv, []
        if fault == "channel":
            argv[4] = str(draw(st.one_of(st.integers(60, 10 ** 30), st.integers(-10 ** 30, -1))))
            return argv, ["channel"]
        if fault == "cache-dir":
            argv += ["--cache-dir", draw(st.sampled_from(["/proc/no/such", str(root / "store_is_a_file" / "x"),
                                                          "/dev/null/x"]))]
            return argv, ["cache-dir", "cache_dir"]
        value = draw(st.sampled_from(["nan", "inf", "-1", "1e9"]))
        argv += [f"--{fault}", value, "--split", "front_rear"]
        return argv, [fault.replace("-", "_")]
    if command == "rough":
        fault = draw(st.sampled_from(["tool-radius", "mu", "allowance", "geometry", "channel"]))
        argv = ["rough", "--geometry", DEFAULT, "--channel", str(draw(st.integers(0, 59))), *progress,
                "--store", "none"]
        if fault == "geometry":
            argv[2] = draw(bad_geometry)
            return argv, []
        if fault == "channel":
            argv[4] = str(draw(st.one_of(st.integers(60, 10 ** 9), st.integers(-10 ** 9, -1))))
            return argv, ["channel"]
        value = draw(st.sampled_from(["nan", "inf", "-1", "0"] + (["0.5", "0.999"] if fault == "mu" else [])))
        return argv + [f"--{fault}", value], [fault.replace("-", "_")]
    if command == "export":
        source = draw(st.one_of(st.sampled_from([str(root / n) for n in (
            "no_plan", "plan_junk", "plan_list", "plan_empty", "plan_nan", "plan_wrong_format", "set_junk",
            "set_empty", "set_types", "set_escape", "set_missing")]), st.text(CHARS, min_size=1, max_size=30)
            .filter(lambda s: not s.startswith("-"))))
        argv = ["export", source, "--store", draw(st.sampled_from([str(root / "store"), "none"]))]
        if draw(st.booleans()):
            argv += ["--all-channels"]
        if draw(st.booleans()):
            argv += ["--machine", draw(st.sampled_from([str(root / f"m_{n}.yaml") for n in (
                "junk", "list", "empty", "nan", "axes", "deep")] + [str(root / "nowhere.yaml")]))]
        return argv + ["--out", out_dir], []
    if command == "check":
        plan_dir = draw(st.sampled_from([str(root / n) for n in ("no_plan", "plan_junk", "plan_nan", "nowhere")]))
        return ["check", plan_dir, "--geometry", draw(st.one_of(bad_geometry, st.just(DEFAULT))),
                "--threshold", draw(POISON_FLOATS), "--progress", "none"], []
    if command == "plot":
        return ["plot", draw(st.sampled_from([str(root / n) for n in ("no_plan", "plan_junk", "plan_list",
                                                                      "plan_empty", "nowhere")])),
                "--out", out_dir], []
    if command == "store":
        return ["store", "list", "--store", draw(st.sampled_from(["none", str(root / "store_is_a_file"),
                                                                  str(root / "bad_store"), "/proc/self"]))], []
    if command == "geometry":
        return ["geometry", draw(st.sampled_from(["validate", "info"])), draw(bad_geometry)], []
    # random tokens: argparse refuses them (no valid geometry file is among them)
    tokens = st.one_of(st.sampled_from(["plan", "rough", "export", "geometry", "check", "plot", "store", "list",
                                        "--channel", "--geometry", "--out", "--axes", "7", "--method", "simplex",
                                        "--reference", "-v", "--help-me", "--", "-", "nan", "validate"]),
                       st.text(CHARS, max_size=12))
    return draw(st.lists(tokens, max_size=8).filter(lambda a: "--help" not in a and "-h" not in a)), []


def test_command_lines(files):
    root, sandbox = files

    @fuzz_settings(100)
    @given(command_lines(root, sandbox))
    def fuzz(case):
        argv, named = case
        rc, out, err = run(argv)
        if rc == 0:      # only `store list` of a usable store may succeed here
            assert argv[:2] == ["store", "list"], f"{argv}: exit 0:\n{out}\n{err}"
            count("command lines", 0)
            return
        check_failure(argv, rc, err, named, area="command lines")

    fuzz()


# -- as a subprocess: no traceback reaches the user --------------------------------------------------------------

def test_no_traceback_from_the_installed_command(files):
    root, sandbox = files
    cases = [["geometry", "validate", str(sandbox / "mesh_garbage.stl.yaml")],
             ["geometry", "info", str(sandbox / "binary.yaml")],
             ["rough", "--geometry", DEFAULT, "--channel", "0", "--mu", "nan", "--store", "none"],
             ["plan", "--geometry", DEFAULT, "--channel", "0", "--out", str(root / "o"), "--step", "-1"],
             ["export", "no-such-plan-id", "--store", str(root / "store")],
             ["store", "list", "--store", str(root / "store_is_a_file")],
             ["plan", "--channel", "x"]]
    exe = os.path.join(sys.prefix, "bin", "edm-plan")
    procs = [subprocess.Popen([exe, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for argv in cases]
    for argv, proc in zip(cases, procs):
        out, err = proc.communicate(timeout=120)
        expected, _, _ = run(argv)
        assert proc.returncode == expected != 0, f"{argv}: exit {proc.returncode}, in process {expected}\n{err}"
        check_failure(argv, proc.returncode, err, area="subprocess")


# -- regressions: inputs that once broke the loader ------------------------------------------------------------

def deep_document(depth):
    return yaml.safe_dump(yaml.safe_load((CONFIG / "default_blisk.yaml").read_text())) + \
        "name: " + "[" * depth + "]" * depth + "\n"


def billion_laughs():
    lines = ["lol0: &lol0 [" + ", ".join(["lol"] * 9) + "]"]
    lines += [f"lol{i}: &lol{i} [" + ", ".join([f"*lol{i - 1}"] * 9) + "]" for i in range(1, 9)]
    return "\n".join(lines) + "\n"


def test_deeply_nested_yaml_is_refused_with_a_line(files):
    root, sandbox = files
    path = sandbox / "deep.yaml"
    path.write_text(deep_document(5000))
    rc, out, err = run(["geometry", "validate", str(path)])
    check_failure(["geometry", "validate", path], rc, err, ["nest", "deep", "YAML"], area="regressions")


def test_yaml_bomb_is_refused_quickly(tmp_path):
    """Billion laughs through the node's path (a GeometryMemo): refused in seconds, within 1.5 GB."""
    script = textwrap.dedent(f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (1536 << 20, 1536 << 20))
        from edm_planner.errors import EdmError
        from edm_planner.geometry.loader import GeometryMemo, load_geometry
        try:
            load_geometry(text=sys.stdin.read(), allowed_dirs=[{str(CONFIG)!r}], memo=GeometryMemo())
        except EdmError as exc:
            print(int(exc.code), exc.message[:300])
    """)
    proc = subprocess.run([sys.executable, "-c", script], input=billion_laughs(), capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0 and proc.stdout.split()[0] in {str(int(ErrorCode.INVALID_GEOMETRY)),
                                                               str(int(ErrorCode.FILE_ERROR))}, \
        proc.stdout + proc.stderr[-2000:]
    count("regressions", int(proc.stdout.split()[0]))


def test_an_error_is_one_line_even_when_its_message_has_line_breaks(files, tmp_path):
    """Regressions: a YAML error's position and a file name with a line break took a second line."""
    nul = tmp_path / "nul.yaml"
    nul.write_text("a: \x00\n")
    odd = tmp_path / "two\nlines" / "z.yaml"
    for argv, named in ((["geometry", "validate", nul], ["nul.yaml"]), (["geometry", "info", odd], ["z.yaml"]),
                        (["export", "a\nb\u2028c", "--store", "none"], ["plan id"])):
        rc, out, err = run(argv)
        assert err.count("\n") == 1, err
        check_failure(argv, rc, err, named, area="regressions")
