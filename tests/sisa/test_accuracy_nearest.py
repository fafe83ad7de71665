"""The check points' nearest pixel, searched over the lines that can hold it only, is the one
np.nanargmin over the whole block finds (ties and NaN included)."""

import numpy as np

from sisa.wiring.accuracy import _nearest_pixel, _row_boxes


def _whole_block(te, tn, e, n):
    d2 = (te - e) ** 2 + (tn - n) ** 2
    if not np.isfinite(d2).any():
        return None
    i, j = np.unravel_index(int(np.nanargmin(d2)), d2.shape)
    return int(i), int(j)


def test_the_nearest_pixel_is_the_whole_blocks():
    rng = np.random.default_rng(7)
    for _ in range(300):
        lines, pixels = rng.integers(1, 40), rng.integers(1, 30)
        along = np.arange(lines)[:, None] * rng.uniform(0.5, 5)
        across = np.arange(pixels)[None, :] * rng.uniform(0.5, 5)
        te = 500_000.0 + across + rng.normal(0, 2, (lines, pixels))
        tn = 4_600_000.0 + along + rng.normal(0, 2, (lines, pixels))
        if rng.random() < 0.5:  # whole lines missed, and pixels
            te[rng.random(lines) < 0.3] = np.nan
            tn[np.isnan(te)] = np.nan
            gone = rng.random((lines, pixels)) < 0.1
            te[gone], tn[gone] = np.nan, np.nan
        if rng.random() < 0.3:  # exact ties: a pixel repeated
            te[-1, -1], tn[-1, -1] = te[0, 0], tn[0, 0]
            te[lines // 2], tn[lines // 2] = te[0], tn[0]
        e = float(np.nanmean(te)) if np.isfinite(te).any() else 0.0
        n = float(np.nanmean(tn)) if np.isfinite(tn).any() else 0.0
        if rng.random() < 0.3 and np.isfinite(te[0, 0]):
            e, n = float(te[0, 0]), float(tn[0, 0])
        for pe, pn in ((e, n), (e + rng.normal(0, 20), n + rng.normal(0, 20))):
            assert _nearest_pixel(te, tn, _row_boxes(te, tn), pe, pn) == \
                _whole_block(te, tn, pe, pn)


def test_a_block_of_nan_has_no_nearest_pixel():
    te = np.full((3, 4), np.nan)
    assert _nearest_pixel(te, te, _row_boxes(te, te), 1.0, 2.0) is None
