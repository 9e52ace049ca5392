"""The replay's jitter statistics in constant memory agree with the exact ones."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip('rclpy')

from gyro_ekf.nodes.replayer import JitterStats  # noqa: E402


def test_jitter_statistics_match_numpy_to_the_bin_width():
    rng = np.random.default_rng(4)
    samples = np.concatenate([rng.exponential(2e-4, 20_000), [0.0, -1e-5, 0.75]])
    stats = JitterStats()
    for value in samples.tolist():
        stats.add(value)
    clipped = np.maximum(samples, 0.0)
    assert stats.count == samples.size
    assert stats.total_s / stats.count == pytest.approx(clipped.mean(), rel=1e-12)
    assert stats.max_s == 0.75
    exact = np.sort(clipped)[int(0.95 * samples.size)]
    assert stats.quantile(0.95) == pytest.approx(exact, rel=0.012)
    assert stats.quantile(1.0) == 0.75


def test_no_samples_give_zeros():
    stats = JitterStats()
    assert (stats.count, stats.quantile(0.95), stats.max_s) == (0, 0.0, 0.0)
