"""Small meshes the tests share (import with ``from meshes import ...``: tests/ is on sys.path under pytest)."""
import numpy as np


def grid_mesh(cells=6, uv_low=0.25, uv_high=0.75):
    """Flat square of ``2 cells^2`` triangles in z = 0, UVs an axis-aligned square of the texture."""
    t = np.linspace(0.0, 1.0, cells + 1)
    X, Y = np.meshgrid(t, t)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    F = []
    for i in range(cells):
        for j in range(cells):
            a = i * (cells + 1) + j
            F += [[a, a + 1, a + cells + 2], [a, a + cells + 2, a + cells + 1]]
    F = np.array(F, dtype=np.int64)
    uv = (uv_low + (uv_high - uv_low) * V[:, :2])[F]
    return V, F, uv
