"""A geometry's summary kept on disk by content (``LoadedGeometry.summary``, ``geometry.loader.summary_key``).

The geometry loader summarises every geometry it loads, the default one at each start; the channel's
centreline alone takes 0.8 s of it. What is shown: the cached summary is the computed one, value for value;
a process that loads the same file again reads it without computing anything; what the file holds is what is
answered, and an unusable file is computed again and replaced; the key follows the electrodes and the blisk.
"""

import json
import logging
from dataclasses import replace

import pytest

from edm_planner.bench.common import rear_design
from edm_planner.geometry import loader
from edm_planner.geometry.electrode_cache import cached_design
from edm_planner.geometry.loader import load_geometry, summary_key

from conftest import CONFIG, REPO


def _files(cache):
    return sorted((cache / "summary").glob("*.json"))


def test_the_summary_of_a_second_load_is_read_from_the_cache_value_for_value(tmp_path, monkeypatch):
    path = CONFIG / "default_blisk.yaml"
    computed = load_geometry(path, cache_dir=tmp_path).summary()
    [kept] = _files(tmp_path)

    def not_again(*_):
        raise AssertionError("the summary was computed again")

    monkeypatch.setattr(loader, "channel_centerline", not_again)
    read = load_geometry(path, cache_dir=tmp_path).summary()
    assert read == computed
    assert {k: type(v) for k, v in read.items()} == {k: float if isinstance(v, float) else type(v)
                                                     for k, v in computed.items()}
    assert read["min_channel_width"] > 0 and read["electrode_count"] == 1
    # what the file holds is what is answered
    doc = json.loads(kept.read_text())
    doc["value"]["centerline_length"] = 123.5
    kept.write_text(json.dumps(doc))
    assert load_geometry(path, cache_dir=tmp_path).summary()["centerline_length"] == 123.5


def test_an_unusable_summary_file_is_computed_again_and_replaced(tmp_path, caplog):
    path = CONFIG / "default_blisk.yaml"
    computed = load_geometry(path, cache_dir=tmp_path).summary()
    [kept] = _files(tmp_path)
    for broken in ('{"format": "edm_planner.summary/2", "val', '{"format": "another/9", "value": {}}',
                   '{"format": "edm_planner.summary/2", "value": [1, 2]}'):
        kept.write_text(broken)
        with caplog.at_level(logging.WARNING, logger="edm_planner.geometry.disk_cache"):
            assert load_geometry(path, cache_dir=tmp_path).summary() == computed
        assert "computed again" in caplog.text
        assert json.loads(kept.read_text())["value"] == json.loads(json.dumps(computed))
        caplog.clear()


def test_the_key_covers_the_electrodes_and_the_blisk(tmp_path, default_geometry):
    key = summary_key(default_geometry)
    assert summary_key(load_geometry(CONFIG / "default_blisk.yaml")) == key
    rear = replace(default_geometry, designed=cached_design(default_geometry.blisk, rear_design(), cache_dir=None))
    assert summary_key(rear) != key
    other = load_geometry(REPO / "test" / "cases" / "blisk72" / "geometry.yaml")
    assert summary_key(other) != key


@pytest.mark.parametrize("cache_dir", [None, ""])
def test_without_a_cache_directory_nothing_is_written(tmp_path, monkeypatch, cache_dir):
    monkeypatch.chdir(tmp_path)
    g = load_geometry(CONFIG / "default_blisk.yaml", cache_dir=tmp_path)
    g.cache_dir = cache_dir
    assert g.summary()["blade_count"] == 60 and not (tmp_path / "summary").exists()
