"""`teach-bench --newest-commissioning` (sim_bridge/commission.py, newest_commissioned): each
seed's newest complete commissioning in the cache, whatever code made it."""

from __future__ import annotations

import os

import pytest

from sim_bridge.commission import newest_commissioned
from sim_bridge.harness import REPO


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


def test_each_cell_config_has_its_own_commissionings(tmp_path):
    """A robot is commissioned through the drives it has: the CiA 402 cell's folders are not
    the default cell's, nor the other way round."""
    cia402 = REPO / "deploy" / "config" / "sim_cell_cia402.toml"
    default = folder(tmp_path, "seed7-aaaa", 1000.0)
    through_cia402 = folder(tmp_path, "seed7-sim_cell_cia402-bbbb", 2000.0)
    assert newest_commissioned(7, root=tmp_path).folder == default
    assert newest_commissioned(7, root=tmp_path, cell_file=cia402).folder == through_cia402
    assert newest_commissioned(8, root=tmp_path, cell_file=cia402) is None
