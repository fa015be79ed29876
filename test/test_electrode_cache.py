"""Designed electrodes kept on disk (``geometry.electrode_cache``): the same bits as designing, never a stale one.

A cell plans every channel with one design, each ``edm-plan plan`` a new process; the nodes design again
after every start. The cache must give exactly what ``design_electrodes`` gives, key on everything the design
depends on (the blisk, the design, which electrode, the code), and never cost an answer. Units: mm, rad.
"""

import logging
import shutil
from dataclasses import replace

import numpy as np

from edm_planner.bench.common import rear_design
from edm_planner.environment import PACKAGE_DIR, package_sources_digest
from edm_planner.geometry import disk_cache
from edm_planner.geometry.electrode import design_electrodes
from edm_planner.geometry.electrode_cache import cached_design, design_key, read_electrodes, write_electrodes
from edm_planner.geometry.loader import load_geometry
from edm_planner.planning.plan import PlanOptions
from edm_planner.planning.planner import plan_channel
from edm_planner.planning.search import SearchOptions

from conftest import REPO


def _same(a, b):
    """Bit for bit: ids, vertices, faces, final poses and sample sets."""
    assert [e.electrode_id for e in a] == [e.electrode_id for e in b]
    for x, y in zip(a, b):
        assert np.array_equal(np.asarray(x.mesh.vertices), np.asarray(y.mesh.vertices))
        assert np.array_equal(np.asarray(x.mesh.faces), np.asarray(y.mesh.faces))
        assert np.array_equal(x.final_pose, y.final_pose)
        assert sorted(x.samples) == sorted(y.samples)
        for name in x.samples:
            assert np.array_equal(x.samples[name], y.samples[name])
        assert y.mesh.is_watertight and y.mesh.volume > 0


def _files(cache):
    return sorted((cache / "electrodes").glob("*.npz"))


def test_a_cached_design_is_the_design_bit_for_bit_and_is_read_back(tmp_path, default_geometry):
    blisk, design = default_geometry.blisk, rear_design()
    fresh = design_electrodes(blisk, design)
    first = cached_design(blisk, design, cache_dir=tmp_path)
    _same(fresh, first)
    [path] = _files(tmp_path)
    second = cached_design(blisk, design, cache_dir=tmp_path)
    _same(fresh, second)
    assert _files(tmp_path) == [path]
    # the second answer comes from the file: what the file holds is what is answered
    write_electrodes(path, second[:1])
    assert [e.electrode_id for e in cached_design(blisk, design, cache_dir=tmp_path)] == ["front"]
    # without a cache directory: designed, nothing written
    _same(fresh, cached_design(blisk, design, cache_dir=None))


def test_a_loaded_geometry_keeps_its_electrodes_in_the_cache_of_its_load(tmp_path, default_geometry):
    """The file's default electrode, designed on first use, is kept where the load keeps what is slow to read:
    the next process that loads the file (the geometry loader restarted, the next demo) reads it."""
    path = REPO / "config" / "default_blisk.yaml"
    first = load_geometry(path, cache_dir=tmp_path)
    assert first.designed is None and _files(tmp_path) == []
    _same(design_electrodes(default_geometry.blisk, default_geometry.design), first.electrodes)
    [kept] = _files(tmp_path)
    write_electrodes(kept, [])                      # what the file holds is what is answered
    assert load_geometry(path, cache_dir=tmp_path).electrodes == []
    assert load_geometry(path, cache_dir=tmp_path / "other").electrodes[0].electrode_id == "main"


def test_the_key_covers_the_blisk_the_design_the_electrode_and_the_code(tmp_path, default_geometry, monkeypatch):
    blisk, design = default_geometry.blisk, rear_design()
    key = design_key(blisk, design)
    assert design_key(blisk, design) == key
    assert design_key(blisk, replace(design, circumferential_reduction=0.031)) != key
    assert design_key(blisk, replace(design, discharge_gap=design.discharge_gap + 0.01)) != key
    assert design_key(blisk, design, only="rear") != key
    other = load_geometry(REPO / "test" / "cases" / "blisk72" / "geometry.yaml").blisk
    assert design_key(other, design) != key
    # any edit of any module of the package is another key (here a copy of the package, one comment added)
    copy = tmp_path / "edm_planner"
    shutil.copytree(PACKAGE_DIR, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert package_sources_digest(str(copy)) == package_sources_digest()
    with open(copy / "geometry" / "electrode.py", "a") as source:
        source.write("# an edit\n")
    assert package_sources_digest(str(copy)) != package_sources_digest()
    # and the key holds that digest (read once per process: the code this process runs)
    assert disk_cache.code_digest() == package_sources_digest()
    monkeypatch.setattr(disk_cache, "code_digest", lambda: package_sources_digest(str(copy)))
    assert design_key(blisk, design) != key


def test_an_unreadable_file_is_designed_again_and_replaced(tmp_path, default_geometry, caplog):
    blisk, design = default_geometry.blisk, rear_design()
    fresh = cached_design(blisk, design, cache_dir=tmp_path)
    [path] = _files(tmp_path)
    path.write_bytes(b"not an npz file")
    with caplog.at_level(logging.WARNING):
        again = cached_design(blisk, design, cache_dir=tmp_path)
    _same(fresh, again)
    assert "unreadable" in caplog.text
    _same(fresh, read_electrodes(path))


def test_a_cache_that_cannot_be_written_costs_only_the_design(tmp_path, default_geometry, caplog):
    blocked = tmp_path / "a file, not a directory"
    blocked.write_text("")
    blisk, design = default_geometry.blisk, rear_design()
    with caplog.at_level(logging.WARNING):
        electrodes = cached_design(blisk, design, cache_dir=blocked)
    _same(design_electrodes(blisk, design), electrodes)
    assert "not written" in caplog.text


def test_only_the_most_recently_used_files_are_kept(tmp_path, default_geometry):
    blisk, design = default_geometry.blisk, rear_design()
    designs = [replace(design, circumferential_reduction=h) for h in (0.03, 0.032, 0.034)]
    cached_design(blisk, designs[0], cache_dir=tmp_path, keep=2)
    cached_design(blisk, designs[1], cache_dir=tmp_path, keep=2)
    cached_design(blisk, designs[0], cache_dir=tmp_path, keep=2)           # used again: now the newest
    cached_design(blisk, designs[2], cache_dir=tmp_path, keep=2)
    names = {p.name[:32] for p in _files(tmp_path)}
    assert names == {design_key(blisk, designs[0])[:32], design_key(blisk, designs[2])[:32]}


def test_a_plan_with_a_cached_electrode_is_the_plan_with_a_designed_one(tmp_path, default_geometry, default_field):
    opts = PlanOptions(search=SearchOptions(method="default", step=0.1, exit_side="downstream"))
    cached_design(default_geometry.blisk, rear_design(), cache_dir=tmp_path)          # in the cache now
    plans = [plan_channel(default_geometry, 0, "rear", opts, field=default_field, design=rear_design(),
                          cache_dir=cache, exact_clearance=False) for cache in (None, tmp_path)]
    assert len(_files(tmp_path)) == 1
    assert all(p.success for p in plans), [p.message for p in plans]
    assert plans[0].plan_id == plans[1].plan_id
    assert np.array_equal(plans[0].samples, plans[1].samples)
    assert plans[0].metrics.objfun1 == plans[1].metrics.objfun1


def test_arrays_digest_is_the_content_of_the_arrays():
    """The key of the caches keyed by a mesh (electrode.stl, the triangle grid): shapes, dtypes and values."""
    v = np.arange(12.0).reshape(4, 3)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    key = disk_cache.arrays_digest(v, f)
    assert disk_cache.arrays_digest(np.asfortranarray(v), f.copy()) == key          # layout is not content
    assert disk_cache.arrays_digest(v.reshape(3, 4), f) != key
    assert disk_cache.arrays_digest(v.astype(np.float32), f) != key
    assert disk_cache.arrays_digest(v, f.astype(np.int32)) != key
    w = v.copy()
    w[3, 2] = np.nextafter(w[3, 2], np.inf)
    assert disk_cache.arrays_digest(w, f) != key
    assert disk_cache.arrays_digest(f, v) != key
