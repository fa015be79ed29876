"""Untrusted input stays contained (issue 15.5): file size limits before parsing, a YAML loader with limits,
exports that never leave export_dir, and a garbage STL refused for what it is."""

import os
import time

import pytest
import yaml
from edm_planner_msgs.msg import ErrorCode as MsgErrorCode
from edm_planner_msgs.srv import LoadGeometry
from rclpy.node import Node
from rclpy.parameter import Parameter

from conftest import CONFIG
from edm_planner.errors import EdmError, ErrorCode, GeometryFileError
from edm_planner.geometry import mesh_read as blade_mesh
from edm_planner.geometry.loader import (MAX_YAML_ALIASES, FileLimits, expanded_node_count, load_geometry,
                                         parse_document)
from edm_planner.paths import check_export_name, export_path, open_for_export

#: nine aliases of nine aliases ... of nine scalars, 9 lines: 490 329 064 nodes once expanded
BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{n}: &{n} [" + ", ".join([f"*{p}"] * 9) + "]\n" for p, n in zip("abcdefgh", "bcdefghi"))
#: two aliases a level, 40 levels: 80 aliases (within MAX_YAML_ALIASES) that stand for 2^42 nodes
DOUBLING = "a0: &a0 [x, x]\n" + "".join(f"a{i + 1}: &a{i + 1} [*a{i}, *a{i}]\n" for i in range(40))
DEEP = "blade_count: " + "[" * 10000 + "]" * 10000 + "\n"


def _refused(call, *words):
    """(CPU seconds the refusal took: the same on a loaded machine, message)."""
    start = time.process_time()
    with pytest.raises(GeometryFileError) as err:
        call()
    elapsed = time.process_time() - start
    assert err.value.code == ErrorCode.FILE_ERROR
    for word in words:
        assert word in err.value.message, (word, err.value.message)
    return elapsed, err.value.message


# -- YAML ---------------------------------------------------------------------------------------------------

def test_a_yaml_bomb_is_refused_quickly_naming_the_limit():
    elapsed, message = _refused(lambda: parse_document(BOMB, "inline YAML"), "inline YAML", "MAX_YAML_NODES",
                                "nodes with its aliases expanded, more than 2000000")
    assert elapsed < 0.5                      # 0.004 s measured: refused while composing, never expanded
    elapsed, _ = _refused(lambda: parse_document(DOUBLING, "inline YAML"), "MAX_YAML_NODES")
    assert elapsed < 0.5                      # 0.007 s measured


def test_deep_nesting_and_many_aliases_are_refused():
    elapsed, _ = _refused(lambda: parse_document(DEEP, "inline YAML"), "nested deeper than 32 levels",
                          "MAX_YAML_DEPTH", "line 1")
    assert elapsed < 2.0                      # 0.28 s measured (the scanner reads every bracket)
    many = "a: &a 1\nb: [" + ", ".join(["*a"] * (MAX_YAML_ALIASES + 1)) + "]\n"
    _refused(lambda: parse_document(many, "inline YAML"), f"more than {MAX_YAML_ALIASES} aliases", "MAX_YAML_ALIASES")
    _refused(lambda: parse_document("a: &a [1, *a]\n", "inline YAML"), "recursive")


def test_plain_yaml_with_a_few_aliases_and_python_tags():
    doc = parse_document("hub: &h [[0, 100], [10, 100]]\nshroud: *h\n", "inline YAML")
    assert doc == {"hub": [[0, 100], [10, 100]], "shroud": [[0, 100], [10, 100]]}
    # a safe loader: no Python objects
    _refused(lambda: parse_document("a: !!python/object/apply:os.system ['true']\n", "inline YAML"), "malformed YAML")
    assert expanded_node_count(yaml.compose("[1, [2, 3]]")) == 5
    # within the depth limit: the default blisk loads as before
    assert load_geometry(CONFIG / "default_blisk.yaml").blisk.blade_count == 60


# -- file size limits, before parsing ------------------------------------------------------------------------

@pytest.fixture
def no_parsing(monkeypatch):
    """Fail the test if a mesh or table parser is reached."""
    def parsed(*args, **kwargs):
        raise AssertionError("the file was parsed")

    monkeypatch.setattr(blade_mesh.trimesh, "load", parsed)
    for name in ("load_blade_mesh", "read_nasa_meridional", "read_nasa_table", "read_sections_csv"):
        monkeypatch.setattr(f"edm_planner.geometry.loader.{name}", parsed)
    return parsed


def test_files_larger_than_their_limit_are_refused_before_parsing(no_parsing):
    size = (CONFIG / "mesh_blisk" / "blade.stl").stat().st_size
    _, message = _refused(lambda: load_geometry(CONFIG / "mesh_blisk.yaml", limits=FileLimits(mesh_bytes=100_000)),
                          "blade.mesh.file", f"{size} bytes", "limit for mesh files of 100000 bytes", "max_mesh_bytes")
    _refused(lambda: load_geometry(CONFIG / "rotor37.yaml", limits=FileLimits(table_bytes=1000)),
             "hub_profile.file", "limit for table files of 1000 bytes", "max_table_bytes")
    with pytest.MonkeyPatch.context() as m:           # the YAML parser is not reached either
        m.setattr("edm_planner.geometry.loader.LimitedSafeLoader", no_parsing)
        _refused(lambda: load_geometry(CONFIG / "default_blisk.yaml", limits=FileLimits(yaml_bytes=100)),
                 "limit for yaml files of 100 bytes", "max_yaml_bytes")
        _refused(lambda: load_geometry(text="blade_count: 60\n" * 10, limits=FileLimits(yaml_bytes=100)),
                 "inline YAML", "160 bytes", "max_yaml_bytes")
    _refused(lambda: blade_mesh.load_blade_mesh(CONFIG / "mesh_blisk" / "blade.stl", max_bytes=1000),
             "max_mesh_bytes")
    with pytest.raises(ValueError, match="mesh_bytes"):
        FileLimits(mesh_bytes=0)


def test_the_default_limits_take_real_files():
    limits = FileLimits()
    assert limits.mesh_bytes == 200 * 2 ** 20 and limits.table_bytes == 16 * 2 ** 20
    assert load_geometry(CONFIG / "mesh_blisk.yaml").blisk.source == "mesh"
    assert load_geometry(CONFIG / "rotor37.yaml").blisk.blade_count == 36


def test_a_garbage_stl_is_refused_for_what_it_is(tmp_path):
    garbage = tmp_path / "blade.stl"
    garbage.write_bytes(os.urandom(3000))
    _, message = _refused(lambda: blade_mesh.load_blade_mesh(garbage), "blade.stl", "not an STL",
                          "neither a binary STL of consistent size", "the file has 3000", "nor ASCII STL text")
    assert "module" not in message and "charset" not in message
    text = tmp_path / "text.stl"
    text.write_bytes(b"solid blade\n\xff\xfe\x00 facet")
    _, message = _refused(lambda: blade_mesh.load_blade_mesh(text), "starts like ASCII STL", "not UTF-8")
    assert "module" not in message
    # the same through a geometry YAML: the file named as the blade
    doc = (CONFIG / "mesh_blisk.yaml").read_text().replace("mesh_blisk/blade.stl", str(garbage))
    _refused(lambda: load_geometry(text=doc, base_dir=tmp_path), "not an STL")


# -- exports ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["../up", "..", "/etc/passwd", "a/b", ".hidden", "", "x" * 129, "a\0b", "é"])
def test_an_export_name_must_be_plain(name):
    with pytest.raises(EdmError) as err:
        check_export_name(name, "plan id")
    assert err.value.code == ErrorCode.INVALID_REQUEST and "cannot name an export" in err.value.message


def test_a_symlink_planted_in_export_dir_is_never_followed(tmp_path):
    exports, outside = tmp_path / "exports", tmp_path / "outside"
    outside.mkdir()
    assert export_path(exports, "0123abcd", suffixes=(".nc", ".csv")) == exports / "0123abcd"
    (exports / "p1.nc").symlink_to(outside / "victim.nc")                   # a file link
    with pytest.raises(EdmError) as err:
        export_path(exports, "p1", suffixes=(".nc", ".csv"))
    assert err.value.code == ErrorCode.FILE_ERROR and "symbolic link" in err.value.message
    (exports / "p2").symlink_to(outside, target_is_directory=True)          # a directory link
    with pytest.raises(EdmError, match="symbolic link"):
        export_path(exports, "p2")
    (exports / "p3").mkdir()                                                # a link inside an export directory
    (exports / "p3" / "plan.json").symlink_to(outside / "plan.json")
    with pytest.raises(EdmError, match="holds a symbolic link"):
        export_path(exports, "p3")
    # a link planted after the check: open_for_export does not follow it either
    (exports / "late.nc").symlink_to(outside / "late.nc")
    with pytest.raises(EdmError) as err:
        open_for_export(exports / "late.nc")
    assert err.value.code == ErrorCode.FILE_ERROR
    assert not any(outside.iterdir())
    # the export directory itself may be a link (the operator's configuration)
    (tmp_path / "linked").symlink_to(exports, target_is_directory=True)
    with open_for_export(export_path(tmp_path / "linked", "ok", suffixes=(".nc",)).with_suffix(".nc")) as f:
        f.write("G21\n")
    assert (exports / "ok.nc").read_text() == "G21\n"


# -- over DDS: the geometry_loader's parameters --------------------------------------------------------------

def test_geometry_loader_limits_are_parameters(ros, tmp_path):
    from edm_planner.nodes.geometry_loader import GeometryLoaderNode

    node = ros.add(GeometryLoaderNode(context=ros.context, parameter_overrides=[
        Parameter("geometry_file", value=""), Parameter("allowed_directories", value=[str(CONFIG), str(tmp_path)]),
        Parameter("max_mesh_bytes", value=100_000), Parameter("max_table_bytes", value=10_000),
        Parameter("max_yaml_bytes", value=65_536), Parameter("max_step_bytes", value=4_000)]))
    client = ros.add(Node("limits_client", context=ros.context))

    def load(**fields):
        start = time.perf_counter()
        res = ros.call(client, LoadGeometry, "load_geometry", LoadGeometry.Request(**fields), timeout=60)
        return res, time.perf_counter() - start

    def refused(res, *words):
        assert not res.success and res.error_code.val == MsgErrorCode.FILE_ERROR, res.message
        for word in words:
            assert word in res.message, (word, res.message)

    res, _ = load(path="mesh_blisk.yaml")
    refused(res, "blade.mesh.file", "max_mesh_bytes", "100000 bytes")
    res, _ = load(path="rotor37.yaml")
    refused(res, "max_table_bytes")
    (tmp_path / "big.step").write_text("ISO-10303-21;\n" + "/* padding */\n" * 400)
    (tmp_path / "step.yaml").write_text("step: big.step\n")
    res, _ = load(path=str(tmp_path / "step.yaml"))
    refused(res, "step.file", "max_step_bytes", "4000 bytes")
    res, _ = load(yaml_text="name: x\n" + "#" * 70_000)
    refused(res, "inline YAML", "max_yaml_bytes")
    res, elapsed = load(yaml_text=BOMB)
    refused(res, "inline YAML", "MAX_YAML_NODES")
    assert elapsed < 5.0
    res, elapsed = load(yaml_text=DEEP)
    refused(res, "MAX_YAML_DEPTH")
    assert elapsed < 5.0
    (tmp_path / "garbage.stl").write_bytes(os.urandom(3000))
    (tmp_path / "garbage.yaml").write_text((CONFIG / "mesh_blisk.yaml").read_text().replace(
        "mesh_blisk/blade.stl", "garbage.stl"))
    res, _ = load(path=str(tmp_path / "garbage.yaml"))
    refused(res, "not an STL")
    assert "module" not in res.message
    # a limit is a parameter: refused when not a positive integer, raised at run time
    assert not node.set_parameters([Parameter("max_mesh_bytes", value=0)])[0].successful
    assert node.set_parameters([Parameter("max_mesh_bytes", value=200 * 2 ** 20)])[0].successful
    res, _ = load(path="mesh_blisk.yaml")
    assert res.success and res.error_code.val == MsgErrorCode.SUCCESS, res.message


@pytest.mark.parametrize("content, words", [
    ("a: " + "[" * 5000 + "]" * 5000, "nested"),
    ("a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join([f'*{chr(97 + i)}'] * 9)}]\n" for i in range(8)), "nodes"),
    (b"\xff\xfe\x00garbage", "UTF-8"),
])
def test_a_hostile_machine_file_is_refused_with_file_error(tmp_path, content, words):
    from edm_planner.cnc.config import load_machine

    path = tmp_path / "machine.yaml"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(EdmError) as exc:
        load_machine(path)
    assert exc.value.code == ErrorCode.FILE_ERROR and words in exc.value.message


def test_an_endless_machine_file_is_refused_at_the_size_limit():
    from edm_planner.cnc.config import MAX_MACHINE_BYTES, load_machine

    with pytest.raises(EdmError) as exc:
        load_machine("/dev/zero")
    assert exc.value.code == ErrorCode.FILE_ERROR and str(MAX_MACHINE_BYTES) in exc.value.message
