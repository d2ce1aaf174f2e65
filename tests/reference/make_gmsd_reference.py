"""Make the GMSD reference values in ``gmsd_piq.json`` with the independent ``piq`` package.

The images are made here from fixed seeds with numpy only (``make_cases``), so ``tests/test_gmsd.py`` rebuilds
them bit for bit without torch; the GMSD values come from ``piq.gmsd`` in float64.

How the committed numbers were made (throwaway venv outside the repo; nothing of it is a project dependency)::

    python3 -m venv /tmp/piqenv
    /tmp/piqenv/bin/pip install torch==2.13.0     # a local CPU wheel
    /tmp/piqenv/bin/pip install piq               # piq 0.8.0 (it pulled torchvision, which upgraded torch)
    /tmp/piqenv/bin/pip install numpy
    /tmp/piqenv/bin/python tests/reference/make_gmsd_reference.py > tests/reference/gmsd_piq.json

piq's GMSD (``piq/gmsd.py``): RGB -> the Y row of YIQ (0.299, 0.587, 0.114); zero row and column appended when a
side is odd; ``avg_pool2d(2, stride 2)``; Prewitt ``[[-1, 0, 1]] * 3 / 3`` and its transpose by ``conv2d`` with
zero padding 1; ``GMS = (2 m_x m_y + t) / (m_x^2 + m_y^2 + t)``, ``t = 170 / 255^2``; population std over the map.
"""
import json
import sys

import numpy as np


def _smooth(image, passes):
    for _ in range(passes):
        image = (image + np.roll(image, 1, 0) + np.roll(image, -1, 0) + np.roll(image, 1, 1)
                 + np.roll(image, -1, 1)) / 5.0
    return image


def make_cases():
    """Fixed test image pairs: list of (name, reference, distorted), float64 in [0, 1]."""
    cases = []
    rng = np.random.default_rng(20220701)
    ref = rng.random((64, 64))
    cases.append(("grey_noise_64", ref, np.clip(ref + 0.1 * rng.standard_normal(ref.shape), 0, 1)))

    rng = np.random.default_rng(7)
    ref = _smooth(rng.random((48, 40, 3)), 2)
    cases.append(("rgb_smooth_48x40", ref, np.clip(_smooth(ref, 3) + 0.02 * rng.random(ref.shape), 0, 1)))

    rng = np.random.default_rng(11)
    ref = rng.random((33, 31))
    cases.append(("grey_odd_33x31", ref, _smooth(ref, 1)))

    y, x = np.mgrid[0:64, 0:64]
    ref = np.where(x + 0.5 * y > 40, 0.8, 0.2) * (x > 3) * (y < 60)  # step edge on a zero background
    dist = np.where(x + 0.5 * y > 41, 0.8, 0.2) * (x > 3) * (y < 60)
    cases.append(("edge_on_background_64", ref.astype(np.float64), dist.astype(np.float64)))

    rng = np.random.default_rng(3)
    ref = rng.random((16, 17, 3))
    cases.append(("rgb_odd_width_16x17", ref, rng.random((16, 17, 3))))
    return cases


def main():
    import piq
    import torch

    out = {"piq_version": piq.__version__, "torch_version": torch.__version__, "cases": {}}
    for name, ref, dist in make_cases():
        to_tensor = (lambda a: torch.from_numpy(np.ascontiguousarray(
            a[None, None] if a.ndim == 2 else np.moveaxis(a, -1, 0)[None])).to(torch.float64))
        value = piq.gmsd(to_tensor(dist), to_tensor(ref), data_range=1.0, reduction="none")
        out["cases"][name] = float(value.item())
    json.dump(out, sys.stdout, indent=2)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
