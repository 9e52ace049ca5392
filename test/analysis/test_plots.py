"""Figures are written, non-blank and absent where they make no sense."""

from __future__ import annotations

import dataclasses

import numpy as np

from gyro_ekf.analysis.plots import write_plots


def _not_blank(path):
    import matplotlib.image
    pixels = matplotlib.image.imread(path)[..., :3]
    return pixels.std() > 0.05 and pixels.shape[0] > 200 and pixels.shape[1] > 200


def test_all_figures_are_written_and_not_blank(tmp_path, short_run):
    written = write_plots(short_run, tmp_path)
    names = sorted(p.name for p in written)
    assert names == ['bias.png', 'errors.png', 'nis.png', 'trajectory.png']
    for path in written:
        assert path.stat().st_size > 10_000
        assert _not_blank(path), path
    assert not list(tmp_path.glob('.*.tmp'))


def test_no_error_figure_without_ground_truth(tmp_path, short_run):
    run = dataclasses.replace(short_run, trip=dataclasses.replace(short_run.trip,
                                                                  ground_truth=None))
    names = sorted(p.name for p in write_plots(run, tmp_path))
    assert names == ['bias.png', 'nis.png', 'trajectory.png']


def test_summary_of_a_simulated_run_is_complete(short_run):
    from gyro_ekf.analysis.summary import summarize
    summary = summarize(short_run)
    assert summary['offline_bias'] is not None
    assert np.isfinite(summary['online_bias']['last_half_std_rad_s'])
    truth = summary['ground_truth']
    assert truth['samples'] > 1000
    assert set(truth) >= {'position_rmse_m', 'position_max_error_m', 'heading_rmse_rad',
                          'nees_share_in_band', 'bias_error_final_rad_s',
                          'bias_settling_time_s'}
