"""The workpiece deviation kept on disk (``mesh_deviation.cached_channel_mesh_deviation``): the same bits, never stale.

Every plan export states how far its workpiece mesh lies from the true surfaces (0.5 s on a 2-core PC), and
a cell exports every channel from a new process. The cache must answer exactly what the measurement gives,
key on everything it depends on (the blisk, the channel, the resolution, float32, the code), and never cost
an answer. Units: mm.
"""

import json
import logging

from edm_planner.geometry import disk_cache
from edm_planner.geometry.loader import load_geometry
from edm_planner.geometry.mesh_deviation import cached_channel_mesh_deviation, channel_mesh_deviation
from edm_planner.records.plan_export import write_plan

from conftest import REPO
from plan_samples import failed_box_plan

CHANNEL = 3


def _files(cache):
    return sorted((cache / "mesh_deviation").glob("*.json"))


def test_the_cached_deviation_is_the_measured_one_and_is_read_back(tmp_path, default_geometry):
    blisk = default_geometry.blisk
    measured = channel_mesh_deviation(blisk, CHANNEL, 0.5)
    first = cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=tmp_path)
    assert first == measured                        # frozen dataclasses: every field, floats bit for bit
    [path] = _files(tmp_path)
    assert cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=tmp_path) == measured
    assert _files(tmp_path) == [path]
    # the second answer comes from the file: what the file holds is what is answered
    doc = json.loads(path.read_text())
    doc["value"]["hub"]["into_channel"] = 12.5
    path.write_text(json.dumps(doc))
    assert cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=tmp_path)["hub"].into_channel == 12.5
    # without a cache directory: measured, nothing written
    assert cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=None) == measured


def test_the_key_covers_the_blisk_channel_resolution_float32_and_code(tmp_path, default_geometry, monkeypatch):
    blisk = default_geometry.blisk
    cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=tmp_path)
    other = load_geometry(REPO / "test" / "cases" / "blisk72" / "geometry.yaml").blisk
    calls = [dict(channel=CHANNEL + 1), dict(resolution=0.75), dict(float32=False), dict(blisk=other)]
    for n, change in enumerate(calls, start=2):
        args = dict(blisk=blisk, channel=CHANNEL, resolution=0.5, float32=True) | change
        got = cached_channel_mesh_deviation(args.pop("blisk"), **args, cache_dir=tmp_path)
        assert len(_files(tmp_path)) == n, f"{change} answered from another key's file"
        assert got == channel_mesh_deviation(change.get("blisk", blisk), args["channel"], args["resolution"],
                                             float32=args["float32"])
    # other code (any edit of the package changes the sources digest) is another key
    monkeypatch.setattr(disk_cache, "code_digest", lambda: "another package")
    cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=tmp_path)
    assert len(_files(tmp_path)) == len(calls) + 2


def test_an_unreadable_or_unwritable_cache_measures_again(tmp_path, default_geometry, caplog):
    blisk = default_geometry.blisk
    measured = cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=tmp_path)
    [path] = _files(tmp_path)
    path.write_text('{"format": "edm_planner.mesh_deviation/2", "val')          # cut short
    with caplog.at_level(logging.WARNING):
        assert cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=tmp_path) == measured
    assert "unusable" in caplog.text
    assert json.loads(path.read_text())["value"]["suction"]["triangles"] > 0, "the file is written again"
    blocked = tmp_path / "a file"
    blocked.write_text("not a directory")
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert cached_channel_mesh_deviation(blisk, CHANNEL, 0.5, cache_dir=blocked) == measured
    assert "not written" in caplog.text


def test_an_export_with_the_cache_is_the_export_without(tmp_path, default_geometry):
    g = default_geometry
    plan = failed_box_plan(g, CHANNEL, "cache-1")
    docs = []
    for name, cache in (("plain", None), ("first", tmp_path / "cache"), ("again", tmp_path / "cache")):
        doc = json.loads(write_plan(plan, tmp_path / name, g.blisk, cache_dir=cache).read_text())
        doc.pop("created")
        docs.append(doc)
    assert docs[0] == docs[1] == docs[2]
    assert len(_files(tmp_path / "cache")) == 1
