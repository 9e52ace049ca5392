"""The offline part of `make bench`, briefly: the run benchmark reports what the runs measured."""

from __future__ import annotations

from pathlib import Path

from gyro_ekf.analysis.bench import core_benchmark, run_benchmark

BUNDLED = Path(__file__).resolve().parents[2] / 'bags' / 'sim_moving_start'


def test_run_benchmark_reports_the_median_of_its_runs(tmp_path):
    result = run_benchmark(BUNDLED, tmp_path, repeats=3)
    assert result['exit_code'] == 0, result.get('stderr_tail')
    factors = sorted(run['real_time_factor'] for run in result['runs'])
    assert len(factors) == 3 and result['real_time_factor'] == factors[1]
    assert result['real_time_factor_min'] == factors[0]
    assert result['real_time_factor_max'] == factors[2]
    for run in result['runs']:
        assert run['trip_duration_s'] > 40.0
        assert 0.0 < run['read_s'] < run['processing_s']
        assert run['real_time_factor_wall'] < run['real_time_factor']


def test_core_benchmark_gives_filterpy_the_same_estimates():
    result = core_benchmark(steps=500)
    assert result['max_abs_state_difference'] < 1e-9
    assert result['max_abs_covariance_difference'] < 1e-9
    assert result['core_predict_us'] > 0.0 and result['filterpy_predict_us'] > 0.0
