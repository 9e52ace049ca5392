"""Stream ordering for live use: StreamMerger releases in driver order behind a watermark."""

from gyro_ekf.core.event_records import EventKind
from gyro_ekf.core.stream_order import StreamMerger


def test_merger_releases_in_driver_order_and_reports_late_events():
    buffer = StreamMerger(window_s=0.05, clock=lambda: 0.0)
    released = []
    for stream, stamp, kind, name in [
            ('imu', 1.00, EventKind.IMU, 'imu@1.00'),
            ('odom', 1.00, EventKind.SPEED, 'speed@1.00'),
            ('scan', 0.99, EventKind.OBSERVATION, 'scan@0.99'),
            ('odom', 1.07, EventKind.SPEED, 'speed@1.07'),
            ('scan', 1.07, EventKind.OBSERVATION, 'scan@1.07'),
            ('imu', 1.06, EventKind.IMU, 'imu@1.06')]:
        ready, late = buffer.push(stream, stamp, kind, name)
        assert late == []
        released += [p for _, _, p in ready]
    # Released once every stream has passed them and they are window_s behind the newest.
    assert released == ['scan@0.99', 'speed@1.00', 'imu@1.00']
    ready, late = buffer.push('imu', 0.98, EventKind.IMU, 'imu@0.98')
    assert ready == [] and late == ['imu@0.98']
    assert [p for _, _, p in buffer.flush()] == ['imu@1.06', 'speed@1.07', 'scan@1.07']


def test_merger_waits_for_the_slowest_active_stream_until_it_goes_stale():
    now = [0.0]
    buffer = StreamMerger(window_s=0.01, stale_after_s=1.0, clock=lambda: now[0])
    buffer.push('imu', 1.0, EventKind.IMU, 'imu@1.0')
    # odom runs 2 s ahead, but the IMU has not reached those stamps: nothing past 1.0 goes.
    released = []
    for k in range(20):
        released += buffer.push('odom', 1.0 + 0.1 * k, EventKind.SPEED, k)[0]
    assert [p for _, _, p in released] == [0, 'imu@1.0']  # speed first at equal stamps
    now[0] = 2.0  # the IMU has been silent for 2 s of wall time: it no longer holds back
    released = buffer.push('odom', 3.0, EventKind.SPEED, 'last')[0]
    assert len(released) == 19 and released[-1][2] == 19


def test_merger_is_bounded():
    buffer = StreamMerger(window_s=100.0, max_events=3, clock=lambda: 0.0)
    released = []
    for k in range(5):
        released += buffer.push('imu', float(k), EventKind.IMU, k)[0]
    assert len(buffer) == 3 and [p for _, _, p in released] == [0, 1]


def test_merger_waits_for_the_expected_streams_before_the_first_release():
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0],
                          expected_streams=('imu', 'odom'))
    assert buffer.push('imu', 1.0, EventKind.IMU, 'imu1') == ([], [])
    # odom's first message is older than imu's: without the wait it would be late.
    ready, late = buffer.push('odom', 0.99, EventKind.SPEED, 'odom0')
    assert late == [] and [p for _, _, p in ready] == ['odom0']   # imu1 waits for odom
    # After a reset it waits again; a stream that never comes stops the wait when stale:
    # stale_after_s on the clock and in the stamps of the others.
    buffer.clear()
    assert buffer.push('imu', 2.0, EventKind.IMU, 'imu2') == ([], [])
    now[0] = 1.5
    assert buffer.push('imu', 2.01, EventKind.IMU, 'imu3') == ([], [])  # stamps: 0.01 s
    ready, _ = buffer.push('imu', 3.01, EventKind.IMU, 'imu4')
    assert [p for _, _, p in ready] == ['imu2', 'imu3', 'imu4']


def test_a_starved_process_does_not_find_its_streams_stale():
    # The process slept 5 s on the clock; both queues still hold messages 10 ms apart.
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0],
                          expected_streams=('imu', 'odom'))
    late = []
    for k in range(100):
        if k == 50:
            now[0] += 5.0
        stamp = 0.01 * k
        late += buffer.push('imu', stamp + 0.005, EventKind.IMU, k)[1]
        late += buffer.push('odom', stamp, EventKind.SPEED, k)[1]
    assert late == []
    assert buffer.active_streams() == {'imu', 'odom'}


def test_a_stream_whose_queue_lags_in_stamps_still_holds_the_others_back():
    # The IMU keeps arriving, 2 s behind the odometry in stamps (a queue that drains
    # slower than it fills): it is not stale, so no IMU sample becomes late.
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0],
                          expected_streams=('imu', 'odom'))
    late, released = [], []
    for k in range(400):
        now[0] += 0.01
        ready, gone = buffer.push('odom', 2.0 + 0.01 * k, EventKind.SPEED, ('odom', k))
        released += ready
        late += gone
        ready, gone = buffer.push('imu', 0.01 * k, EventKind.IMU, ('imu', k))
        released += ready
        late += gone
    assert late == []
    assert max(stamp for stamp, _, _ in released) <= 0.01 * 399


def test_a_stopped_stream_goes_stale_on_the_clock_and_in_the_stamps():
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0])
    buffer.push('scan', 0.0, EventKind.OBSERVATION, 'scan')
    for k in range(300):
        now[0] = 0.01 * k
        buffer.push('imu', 0.01 * k, EventKind.IMU, k)
    assert buffer.active_streams() == {'imu'}
    assert len(buffer) < 5


def test_a_longer_wall_time_waits_for_a_slow_upstream_and_still_ends_a_stopped_one():
    # Reliable inputs: a detector starved upstream sends nothing for 3 s of steady clock
    # while 3 s of IMU stamps arrive; with the clock's part at 10 s it still holds them.
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0],
                          stale_wall_s=10.0)
    buffer.push('scan', 0.0, EventKind.OBSERVATION, 'scan')
    for k in range(300):
        now[0] = 0.01 * k
        buffer.push('imu', 0.01 * k, EventKind.IMU, k)
    assert buffer.active_streams() == {'imu', 'scan'}
    assert len(buffer) == 299  # all IMU samples after the scan's stamp are held
    late = buffer.push('scan', 2.9, EventKind.OBSERVATION, 'late scan')[1]
    assert late == []
    # Stopped for good: 10 s on the clock and 1 s of stamps end the wait.
    now[0] = 13.0
    buffer.push('imu', 4.0, EventKind.IMU, 300)
    assert buffer.active_streams() == {'imu'}
    assert len(buffer) < 5


def _drain(buffer, now, rounds, clock_step_s, streams):
    """Serve each stream's queue one message per round, as the executor does; return late.

    streams: name -> (first stamp, period, kind); the clock moves clock_step_s per round.
    """
    late = []
    for k in range(rounds):
        now[0] += clock_step_s
        for name, (first, period, kind) in streams.items():
            late += buffer.push(name, first + period * k, kind, (name, k))[1]
    return late


def test_a_clock_running_ahead_of_the_queues_makes_no_stream_stale():
    # A starved node under use_sim_time: /clock (depth 1) is always the newest and moves
    # 2 s between two executor rounds, while the queues drain one message per round: the
    # 200 Hz IMU falls 5 s behind the 100 Hz odometry in stamps. It keeps coming, so none
    # of it is late.
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0],
                          expected_streams=('imu', 'odom'))
    late = _drain(buffer, now, 1000, 2.0, {'odom': (0.0, 0.01, EventKind.SPEED),
                                           'imu': (0.0, 0.005, EventKind.IMU)})
    assert late == []
    assert buffer.active_streams() == {'imu', 'odom'}
    assert buffer.released_s <= 0.005 * 999


def test_an_input_whose_stamps_run_5_s_ahead_holds_nothing_back_and_loses_nothing():
    # Odometry stamped 5 s ahead of the IMU, first to arrive: the IMU is not stale while
    # the newest stamp stands at the odometry's, and odometry waits for the IMU to pass it.
    for first in ('odom', 'imu'):
        now = [0.0]
        buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0],
                              expected_streams=('imu', 'odom', 'laser'))
        streams = {'odom': (5.0, 0.01, EventKind.SPEED), 'imu': (0.0, 0.01, EventKind.IMU)}
        if first == 'imu':
            streams = dict(reversed(streams.items()))
        late = _drain(buffer, now, 1000, 0.01, streams)
        assert late == [], first
        assert buffer.released_s == 9.99  # the last IMU sample; odometry after it waits
        assert buffer.active_streams() == {'imu', 'odom'}


def test_a_burst_of_one_stream_does_not_make_the_others_stale():
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0])
    late = _drain(buffer, now, 100, 0.01, {'odom': (0.0, 0.01, EventKind.SPEED),
                                           'imu': (0.0, 0.01, EventKind.IMU)})
    # 5 s of IMU stamps arrive at once (no time on the clock): odometry still holds them.
    late += _drain(buffer, now, 500, 0.0, {'imu': (1.0, 0.01, EventKind.IMU)})
    assert buffer.active_streams() == {'imu', 'odom'}
    late += _drain(buffer, now, 500, 0.0, {'odom': (1.0, 0.01, EventKind.SPEED)})
    assert late == [] and buffer.released_s == 5.99


def test_a_stream_that_stops_goes_stale_and_holds_back_again_when_it_resumes():
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0])
    both = {'odom': (0.0, 0.01, EventKind.SPEED), 'imu': (0.0, 0.01, EventKind.IMU)}
    late = _drain(buffer, now, 100, 0.01, both)
    # Odometry stops for 10 s of stamps and clock: the IMU goes on without it.
    late += _drain(buffer, now, 1000, 0.01, {'imu': (1.0, 0.01, EventKind.IMU)})
    assert buffer.active_streams() == {'imu'}
    assert buffer.released_s == 10.99
    late += _drain(buffer, now, 100, 0.01, {'odom': (11.0, 0.01, EventKind.SPEED),
                                            'imu': (11.0, 0.01, EventKind.IMU)})
    assert late == []
    assert buffer.active_streams() == {'imu', 'odom'}


def test_when_inputs_stop_streams_that_ended_together_release_everything():
    # The end of a replay: IMU and odometry to 10.0 s, the LiDAR's last scan at 9.9 s
    # (10 Hz). Its next scan could not be older than 10.0 s, so nothing waits for it.
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0],
                          stale_wall_s=30.0)
    late = []
    for k in range(1001):
        stamp = round(0.01 * k, 2)
        if k % 10 == 0 and k < 1000:
            late += buffer.push('scan', stamp, EventKind.OBSERVATION, k)[1]
        late += buffer.push('odom', stamp, EventKind.SPEED, k)[1]
        late += buffer.push('imu', stamp, EventKind.IMU, k)[1]
    assert late == [] and len(buffer) == 20  # after the last scan: 9.91-10.0 s
    now[0] += 0.5
    released = buffer.release_idle()
    assert len(buffer) == 0 and released[-1][0] == 10.0


def test_when_inputs_stop_a_lagging_stream_holds_the_rest_until_it_is_stale():
    # A reliable reader whose odometry from 8.0 s on is still to be sent again (lost on
    # the way) when the IMU has ended at 10 s: odometry arriving after the pause is not
    # late. Once odometry is silent for stale_wall_s on the clock, the rest goes.
    now = [0.0]
    buffer = StreamMerger(window_s=0.0, stale_after_s=1.0, clock=lambda: now[0],
                          stale_wall_s=30.0)
    late = _drain(buffer, now, 801, 0.001, {'odom': (0.0, 0.01, EventKind.SPEED),
                                            'imu': (0.0, 0.01, EventKind.IMU)})
    late += _drain(buffer, now, 200, 0.001, {'imu': (8.01, 0.01, EventKind.IMU)})
    now[0] += 0.5
    released = buffer.release_idle()
    assert released[-1][0] == 8.01  # up to odometry's next expected stamp
    late += _drain(buffer, now, 100, 0.001, {'odom': (8.01, 0.01, EventKind.SPEED)})
    assert late == [] and buffer.released_s == 9.0
    now[0] += 29.0
    # Within stale_wall_s: only up to odometry's next expected stamp again.
    assert [r[0] for r in buffer.release_idle()] == [9.01] and len(buffer) == 99
    now[0] += 2.0
    released = buffer.release_idle()
    assert len(buffer) == 0 and released[-1][0] == 10.0
