"""Offline reading times every stamped message by its header.stamp, as the nodes do.

Each test rewrites the synthetic trip's bag message by message (`rewrite` of
test_bag_bad_input) with its log times (the recorder's receive times) or header stamps
changed, and reads it with the fast reader, read_bag's rosbags path and the test oracle.
The log time only orders the reading: a bag received late or recorded from a faster replay
reads as the original; header stamps that go back reach the validation boundary in the
order read; a message recorded twice is dropped and counted; two different messages with
one stamp are refused.
"""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest
from test_bag_bad_input import _read_rosbags_path, clean_bag, of, READERS, rewrite  # noqa: F401

from gyro_ekf.cli.main import main
from gyro_ekf.core.errors import InvalidInputError
from gyro_ekf.core.stamps import join_ns
from gyro_ekf.core.validation import validate_trip
from gyro_ekf.io.bag_reader import read_bag
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.messages import to_time
from gyro_ekf.io.sidecar import read_sidecar, sidecar_path, to_yaml

STAMPED = ('/imu', '/odom', '/scan', '/scan2', '/ground_truth')


def _by_log_time(items):
    """What a recorder writes: messages in the order received (stable for ties)."""
    return sorted(items, key=lambda item: item[2])


def _header_ns(item) -> int:
    stamp = item[3].header.stamp
    return join_ns(stamp.sec, stamp.nanosec)


def _set_header(item, ns: int) -> None:
    item[3].header.stamp = to_time(ns)


def _assert_same_trip(got, want) -> None:
    """Equal stamps and values, stream by stream."""
    a, b = got.trip, want.trip
    for x, y in ((a.imu.stamp_s, b.imu.stamp_s),
                 (a.imu.angular_velocity_rad_s, b.imu.angular_velocity_rad_s),
                 (a.speed.stamp_s, b.speed.stamp_s), (a.speed.speed_m_s, b.speed.speed_m_s),
                 (a.ground_truth.stamp_s, b.ground_truth.stamp_s),
                 (a.ground_truth.pose, b.ground_truth.pose)):
        np.testing.assert_array_equal(x, y)
    assert [s.topic for s in a.scans] == [s.topic for s in b.scans]
    for s, t in zip(a.scans, b.scans):
        np.testing.assert_array_equal(s.stamp_s, t.stamp_s)
        np.testing.assert_array_equal(s.ranges_m, t.ranges_m)
    assert got.start_time_ns == want.start_time_ns


def _run(bag: Path, out: Path) -> tuple[bytes, dict]:
    assert main(['-q', 'run', str(bag), '-o', str(out), '--no-plots', '--no-bag',
                 '--no-progress']) == 0
    summary = json.loads((out / 'summary.json').read_text())
    summary.pop('timing')
    summary['input'].pop('source')  # the bag's folder name
    return (out / 'estimates.csv').read_bytes(), summary


@pytest.fixture(scope='module')
def clean_run(clean_bag, tmp_path_factory):  # noqa: F811
    return _run(clean_bag, tmp_path_factory.mktemp('clean_run') / 'out')


def _compressed(items):
    # A recording of `gyro-ekf replay --rate 3` without --clock: received three times
    # faster, header stamps as published.
    zero = min(item[2] for item in items)
    for item in items:
        item[2] = zero + (item[2] - zero) // 3
    return _by_log_time(items)


def _scans_late(items):
    # A LiDAR driver stamps the scan at acquisition; the recorder receives it 0.2 s later.
    for item in items:
        if item[0] in ('/scan', '/scan2'):
            item[2] += 200_000_000
    return _by_log_time(items)


@pytest.mark.parametrize('change', [_compressed, _scans_late],
                         ids=['log_times_compressed_3x', 'scans_logged_0p2s_late'])
@READERS
def test_log_times_other_than_the_header_stamps_read_as_the_original(
        tmp_path, clean_bag, read, change):  # noqa: F811
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    _assert_same_trip(read(bag), read_bag(clean_bag))


@pytest.mark.parametrize('change', [_compressed, _scans_late],
                         ids=['log_times_compressed_3x', 'scans_logged_0p2s_late'])
def test_run_gives_the_same_estimates_whatever_the_log_times(
        tmp_path, clean_bag, clean_run, change):  # noqa: F811
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    estimates, summary = _run(bag, tmp_path / 'out')
    assert estimates == clean_run[0]
    assert summary == clean_run[1]


def _imu_back_10s(items):
    for item in of(items, '/imu')[200:]:
        _set_header(item, _header_ns(item) - 10_000_000_000)


def _imu_back_onto_earlier_stamps(items):
    # From message 200 on, the stamps of messages 100, 101, ... again: stamps that repeat
    # earlier ones with other contents are time going back, not two values for one instant.
    imu = of(items, '/imu')
    stamps = [_header_ns(item) for item in imu]
    for k, item in enumerate(imu[200:]):
        _set_header(item, stamps[100 + k])


BACK = pytest.mark.parametrize('change, went_back', [
    (_imu_back_10s, r'time went back 9\.99'),
    (_imu_back_onto_earlier_stamps, r'time went back 0\.\d+ s')], ids=['10s', 'onto_earlier'])


@BACK
@READERS
def test_imu_header_stamps_going_back_reach_validation_in_the_order_read(
        tmp_path, clean_bag, read, change, went_back):  # noqa: F811
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    trip = read(bag).trip
    steps = np.diff(trip.imu.stamp_s)
    assert steps[199] < 0 and (np.delete(steps, 199) > 0).all()  # not sorted away
    with pytest.raises(InvalidInputError, match=r'imu\.stamp_s\[200\]: ' + went_back):
        validate_trip(trip, bag.name)


@BACK
def test_run_refuses_imu_header_stamps_going_back_in_one_line(
        tmp_path, clean_bag, capsys, change, went_back):  # noqa: F811
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    assert main(['-q', 'run', str(bag), '-o', str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err, err
    assert re.search(r'imu\.stamp_s\[200\]: ' + went_back, err), err
    assert not (tmp_path / 'out').exists()


@READERS
def test_with_skip_bad_a_message_back_at_the_last_kept_stamp_is_dropped(
        tmp_path, clean_bag, read):  # noqa: F811
    # Message 299 takes message 199's stamp, with other contents: the reader leaves it to
    # the validation boundary (the stamps went back at 200), where --skip-bad kept it, a
    # second value for one instant that the reader refuses when the stamps did not go back.
    bag = rewrite(clean_bag, tmp_path / 'bag', _imu_back_onto_earlier_stamps)
    trip = read(bag).trip
    assert trip.imu.stamp_s[299] == trip.imu.stamp_s[199]
    checked, report = validate_trip(trip, bag.name, skip_bad=True)
    assert np.all(np.diff(checked.imu.stamp_s) > 0)
    assert report.dropped == {('imu.stamp_s', 'time went back'): 100}    # 200 to 299
    assert report.samples_dropped == {'imu': 100}


def _duplicates(items):
    # Every 25th message, when it is an IMU one, recorded twice in a row; one odometry
    # message once more at the end of the bag (received again much later).
    out = []
    for k, item in enumerate(items):
        out.append(item)
        if item[0] == '/imu' and k % 25 == 0:
            out.append(copy.deepcopy(item))
    _duplicates.copies = len(out) - len(items)
    again = copy.deepcopy(of(items, '/odom')[40])
    again[2] = max(item[2] for item in items)
    return out + [again]


@READERS
def test_exact_duplicates_are_dropped_and_counted(tmp_path, clean_bag, read):  # noqa: F811
    bag = rewrite(clean_bag, tmp_path / 'bag', _duplicates)
    assert _duplicates.copies > 5
    got = read(bag)
    assert got.duplicates == {'/imu': _duplicates.copies, '/odom': 1}
    _assert_same_trip(got, read_bag(clean_bag))


def test_run_counts_dropped_duplicates_in_the_summary(
        tmp_path, clean_bag, clean_run):  # noqa: F811
    bag = rewrite(clean_bag, tmp_path / 'bag', _duplicates)
    estimates, summary = _run(bag, tmp_path / 'out')
    assert estimates == clean_run[0]
    assert summary['input'].pop('duplicates_dropped')['/odom'] == 1
    assert summary == clean_run[1]


@READERS
def test_two_messages_with_one_stamp_and_other_contents_are_refused(
        tmp_path, clean_bag, read):  # noqa: F811
    def change(items):
        imu = of(items, '/imu')
        other = copy.deepcopy(imu[37])
        other[3].angular_velocity.z += 0.3
        items.insert(items.index(imu[37]) + 1, other)
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    with pytest.raises(BagError, match=(
            r"bag: topic '/imu': message index 37 and message index 38 have the same "
            r'header\.stamp \(\d+ ns\) but different contents')):
        read(bag)


@READERS
def test_the_time_zero_is_the_sidecars(tmp_path, clean_bag, read):  # noqa: F811
    # As the nodes take trip.log_time_zero_ns: before, offline counted from the first log
    # time whatever the sidecar said.
    bag = rewrite(clean_bag, tmp_path / 'bag', lambda items: None)
    params = read_sidecar(bag)
    zero = params.log_time_zero_ns - 2_000_000_000
    sidecar_path(bag).write_text(to_yaml(type(params)(**{
        **{f: getattr(params, f) for f in params.__slots__}, 'log_time_zero_ns': zero})))
    got = read(bag)
    assert got.start_time_ns == zero
    np.testing.assert_allclose(got.trip.imu.stamp_s, read_bag(clean_bag).trip.imu.stamp_s + 2,
                               rtol=0, atol=1e-9)


def _sim_time(items):
    # Recorded with use_sim_time: header stamps count from the simulation's start (100 s),
    # log times are the wall clock.
    zero = min(_header_ns(item) for item in items if item[0] in STAMPED)
    for item in items:
        if item[0] in STAMPED:
            _set_header(item, _header_ns(item) - zero + 100_000_000_000)


@READERS
def test_a_bag_stamped_in_sim_time_without_a_sidecar_counts_from_its_first_header(
        tmp_path, clean_bag, read):  # noqa: F811
    bag = rewrite(clean_bag, tmp_path / 'bag', _sim_time)
    sidecar_path(bag).unlink()
    plain = rewrite(clean_bag, tmp_path / 'plain', lambda items: None)
    sidecar_path(plain).unlink()
    got, want = read(bag), read_bag(plain)
    assert got.start_time_ns == 100_000_000_000
    np.testing.assert_array_equal(got.trip.imu.stamp_s, want.trip.imu.stamp_s)
    np.testing.assert_array_equal(got.trip.scans[0].stamp_s, want.trip.scans[0].stamp_s)


@READERS
def test_a_sidecar_zero_on_another_clock_than_the_headers_is_refused(
        tmp_path, clean_bag, read):  # noqa: F811
    bag = rewrite(clean_bag, tmp_path / 'bag', _sim_time)
    with pytest.raises(BagError, match=(
            r'bag\.params\.yaml: trip\.log_time_zero_ns = \d+ lies -1\.7e\+09 s from the header '
            r"stamp of the first message read \(topic '/\w+' message index 0, header\.stamp "
            r'100000000000 ns\); the header stamps run on another clock')):
        read(bag)


@pytest.mark.parametrize('sec, nanosec, match', [
    (0, 0, r'message index 12: header\.stamp is 0 \(unset\)'),
    (1_700_000_000, 1_000_000_000,
     r'message index 12: header\.stamp\.nanosec = 1000000000 is not below 1e9')])
@READERS
def test_a_header_stamp_that_is_no_time_is_refused(
        tmp_path, clean_bag, read, sec, nanosec, match):  # noqa: F811
    def change(items):
        stamp = of(items, '/odom')[12][3].header.stamp
        stamp.sec, stamp.nanosec = sec, nanosec
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    with pytest.raises(BagError, match=r"bag: topic '/odom': " + match):
        read(bag)


@READERS
def test_without_a_sidecar_ground_truth_does_not_set_the_time_zero(
        tmp_path, clean_bag, read):  # noqa: F811
    # The nodes do not take /ground_truth: their zero is the first /imu, /odom or scan stamp.
    def change(items):
        truth = of(items, '/ground_truth')[0]
        truth[2] = min(item[2] for item in items) - 1_000_000
        _set_header(truth, truth[2])
        first_imu.append(_header_ns(of(items, '/imu')[0]))
        return _by_log_time(items)
    first_imu: list[int] = []
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    sidecar_path(bag).unlink()
    assert read(bag).start_time_ns == first_imu[0]
