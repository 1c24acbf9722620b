"""viewer.layers: the side panel's histogram of a layer (pure numpy)."""

from __future__ import annotations

import numpy as np
import pytest

from viewer.layers import HIST_BINS, histogram


def test_hdr_histogram_is_of_log2_luminance_or_one_channel():
    a = np.ones((8, 16, 3), np.float32)
    a[4:] = 4.0  # half the pixels at 0 EV, half at +2 EV
    a[0, 0] = (0.0, np.nan, np.inf)  # neither positive-finite luminance nor finite: not counted
    counts, lo, hi, unit = histogram(a, "hdr")
    assert unit.startswith("log2")
    assert lo == pytest.approx(0.0, abs=0.01) and hi == pytest.approx(2.0, abs=0.01)
    assert counts.sum() == 8 * 16 - 1 and counts[0] == 63 and counts[-1] == 64
    a[:, :, 0] = 2.0 ** np.arange(16)[None, :]  # R alone spans 0..15 EV
    counts, lo, hi, _ = histogram(a, "hdr", channel="r")
    assert lo == pytest.approx(0.0, abs=0.05) and hi == pytest.approx(15.0, abs=0.05)
    assert counts.sum() == 8 * 16 and (counts > 0).sum() == 16  # one bin per exposure step


def test_colour_scalar_and_normal_histograms():
    a = np.full((4, 8, 3), 0.25, np.float32)
    counts, lo, hi, _ = histogram(a, "colour", channel="g")
    assert (lo, hi) == (0.0, 1.0) and counts[int(0.25 * HIST_BINS)] == 32
    d = np.linspace(1.0, 5.0, 32, dtype=np.float32).reshape(4, 8, 1)
    d[0, 0] = np.nan
    counts, lo, hi, _ = histogram(d, "scalar")
    assert (lo, hi) == (pytest.approx(d[0, 1, 0]), 5.0) and counts.sum() == 31
    assert histogram(a, "normal") is None
