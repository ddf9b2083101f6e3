"""The SSIM metric of the project's protocol: skimage's SSIM per image pair, data range 1,
7 x 7 window, computed in float64 on min-max normalised images. Training validation, every
evaluation and every floor use this one function."""
from __future__ import annotations

import numpy as np

from .errors import ImageError

#: the side of SSIM's uniform window [px] (skimage's default); an image side must be at least this
WINDOW = 7


def ssim_images(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """SSIM per image pair (skimage, data_range=1, a :data:`WINDOW` x :data:`WINDOW` uniform window).

    Args:
        pred, gt: float [K, H, W], already min-max normalised to [0, 1].

    Returns:
        float64 [K].
    """
    from skimage.metrics import structural_similarity

    pred, gt = np.asarray(pred), np.asarray(gt)
    if pred.shape != gt.shape or pred.ndim != 3:
        raise ImageError(f"ssim_images: pred {pred.shape} and gt {gt.shape} must both be [K, H, W]")
    # float64 one image at a time: a whole stack's copy (1260 test images: 2 x 327 MB) cost more
    # in page faults than the SSIMs on this project's machine; the values are the same
    return np.array([structural_similarity(np.asarray(p, np.float64), np.asarray(g, np.float64), data_range=1.0,
                                           win_size=WINDOW)
                     for p, g in zip(pred, gt)], dtype=np.float64)
