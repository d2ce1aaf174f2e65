"""bench.attribute: the regions of a view's pooled cells, by hand."""
import numpy as np

from perceptual_uv.bench.attribute import REGIONS, region_labels


def test_region_labels_by_hand():
    # 8 x 8 screen: face 0 (chart 0, at the box floor) in columns 0-3, face 1 (chart 1) in columns 4-7, nothing
    # in rows 6-7. Pooled cell (i, j) reads screen rows 2i-2 .. 2i+3 and columns 2j-2 .. 2j+3 (clamped).
    ids = np.full((8, 8), -1)
    ids[:6, :4], ids[:6, 4:] = 0, 1
    labels = region_labels(ids, face_chart=np.array([0, 1]), at_floor=np.array([True, False]))
    f, s, r, si, b = (REGIONS.index(k) for k in ("floor", "seam", "rest", "silhouette", "background"))
    np.testing.assert_array_equal(labels, [[f, s, s, r], [f, s, s, r], [si] * 4, [b] * 4])
