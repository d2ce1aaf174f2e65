"""core.atomic.atomic_path: a file is replaced whole or left as it was, with nothing left beside it."""
import numpy as np
import pytest

from perceptual_uv.core.atomic import atomic_path


def test_the_file_appears_only_when_the_block_finishes(tmp_path):
    target = tmp_path / "sub" / "pixels.npy"
    with atomic_path(target) as temporary:
        assert temporary.parent == target.parent and temporary.suffix == ".npy"
        np.save(temporary, np.arange(3))  # np.save keeps a name that ends in .npy
        assert not target.exists()
    np.testing.assert_array_equal(np.load(target), [0, 1, 2])
    assert [p.name for p in target.parent.iterdir()] == ["pixels.npy"]


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "report.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as temporary:
        temporary.write_text("half")
        raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["report.json"]


def test_two_writers_of_one_file_do_not_share_a_temporary(tmp_path):
    # Two processes writing the same cache entry at once: each renames its own whole file; the last one stays.
    with atomic_path(tmp_path / "a.txt") as first, atomic_path(tmp_path / "a.txt") as second:
        assert first != second
        first.write_text("first")
        second.write_text("second")
    assert (tmp_path / "a.txt").read_text() == "first"  # the outer block finishes last
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]
