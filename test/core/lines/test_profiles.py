"""Samples along profiles and their sub-sample peaks (core/lines/profiles.py), which place the
line detector's edge points and the image circle's boundary. ROS-free."""
import math

import numpy as np

from zeroshot_calib_ros.core.lines.profiles import peak_offsets, sample


def test_an_edge_between_samples_is_placed_to_a_tenth_of_a_sample():
    positions = np.arange(-5.0, 5.5, 1.0)
    for true in (-0.4, -0.1, 0.0, 0.25, 0.45, 2.3):
        g = np.exp(-0.5 * ((positions - true) / 1.2) ** 2)[None, :] * 30.0  # a blurred edge's gradient
        offset, peak, ok = peak_offsets(g, positions, 1.0)
        assert ok[0] and abs(offset[0] - true) < 0.1 and 25 < peak[0] <= 30.0


def test_a_peak_at_a_profiles_end_or_not_positive_is_no_edge():
    g = np.array([[9.0, 1.0, 0.5, 0.2], [0.0, 0.2, 1.0, 9.0], [-3.0, -1.0, -2.0, -4.0],
                  [-np.inf, -np.inf, -np.inf, -np.inf]])
    _, _, ok = peak_offsets(g, np.arange(4.0), 1.0)
    assert not ok.any()


def test_samples_are_bilinear_inside_and_nan_outside_or_at_nan_positions():
    img = np.arange(12, dtype=np.float32).reshape(3, 4)  # value = 4 y + x
    x = np.array([[0.5, 2.25], [-3.0, math.nan]])
    y = np.array([[1.0, 0.5], [1.0, 1.0]])
    out = sample(img, x, y)
    assert out.shape == (2, 2)
    np.testing.assert_allclose(out[0], [4.5, 4.25], atol=1e-3)
    assert np.isnan(out[1]).all()
