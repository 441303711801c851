"""`teach-bench --newest-commissioning` (sim_bridge/commission.py, newest_commissioned): each
seed's newest complete commissioning in the cache, whatever code made it."""

from __future__ import annotations

import os

import pytest

from sim_bridge.commission import newest_commissioned


def folder(root, name: str, mtime: float, complete: bool = True):
    d = root / name
    d.mkdir()
    (d / "model.json").write_text("{}")
    if complete:
        (d / "inner_loop.json").write_text("{}")
    os.utime(d / "model.json", (mtime, mtime))
    return d


def test_the_newest_complete_folder_of_the_seed_is_taken_whatever_its_digest(tmp_path):
    folder(tmp_path, "seed7-aaaa", 1000.0)
    newest = folder(tmp_path, "seed7-bbbb", 2000.0)
    folder(tmp_path, "seed7-cccc", 3000.0, complete=False)  # a build that did not finish
    folder(tmp_path, "seed70-dddd", 4000.0)  # another seed
    done = newest_commissioned(7, root=tmp_path)
    assert done is not None and done.folder == newest and done.plant_seed == 7


def test_no_commissioning_of_the_seed_is_none_and_a_negative_seed_is_refused(tmp_path):
    folder(tmp_path, "seed8-aaaa", 1000.0)
    assert newest_commissioned(7, root=tmp_path) is None
    with pytest.raises(ValueError, match="plant seed"):
        newest_commissioned(-1, root=tmp_path)
