"""Pieces of the loop memory benchmark (the figures themselves are never asserted)."""

from __future__ import annotations

import os

from benchmarks.bench import loop_memory_rows, rss_growth, vm_rss_mb


def test_vm_rss_reads_this_process_and_none_for_a_missing_one():
    assert vm_rss_mb(os.getpid()) > 0.0
    assert vm_rss_mb(2**22 + 12345) is None


def test_growth_is_counted_after_the_warm_up():
    times = [0.0, 1.0, 2.0, 3.0, 4.0]
    rss = [10.0, 50.0, 60.0, 61.0, 62.0]
    result = rss_growth(times, rss, warm_up_s=2.0)
    assert result['rss_after_warm_up_mb'] == 60.0
    assert result['rss_end_mb'] == 62.0
    assert result['growth_mb'] == 2.0
    assert abs(result['slope_mb_per_min'] - 60.0) < 1e-9


def test_too_few_samples_give_no_figure_and_the_table_says_so():
    result = rss_growth([0.0], [10.0], warm_up_s=0.0)
    assert result['growth_mb'] is None
    rows = loop_memory_rows({'loops': 30, 'rate': 20.0, 'replay': result,
                             'ekf_node': result, 'landmark_detector_node': result})
    assert [value for _, value in rows] == ['not measured'] * 3
