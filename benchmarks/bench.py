"""Benchmarks of `make bench` (measured, never asserted by tests).

- *core*: microseconds per GyroBiasEkf.predict and .update call, side by side in the same
  process with filterpy's ExtendedKalmanFilter running the same model (models.py) on the
  same inputs, and the largest difference of their final estimates.
- *run*: real-time factor of `gyro-ekf run` on a bag (bag read, detection, association,
  filter, CSV, summary and estimates bag; plots excluded), in a child process.
- *memory*: peak resident memory of `gyro-ekf convert` and `gyro-ekf run` on a long
  simulated trip, each in its own child process (``os.wait4`` reports the child's maximum
  resident set size).
- *loop_memory*: `gyro-ekf replay --loops 30` of a bundled bag at a high rate into
  landmark_detector_node and ekf_node (child processes, loopback DDS): the resident memory
  (VmRSS from /proc/PID/status) of the replayer and of each node, sampled twice a second;
  growth is the last sample minus the first one of the third pass (goal < 5 MB).
- *live*: ekf_node in a child process over Fast DDS on loopback, fed odom + imu at 200 Hz
  and 1 kHz: latency from an IMU message in to its pose out (p50/p99/max, matched by header
  stamp), poses missing and the node's CPU per step, publishing pose, odometry and bias
  (`live_bench.py`); calibration_node's CPU per IMU message and landmark_detector_node's per
  361-beam scan. Each on the serialized path (nodes/wire.py, the default) and on the
  rclpy-message path (GYRO_EKF_NODE_IO=rclpy, the nodes before it), in the same run.
- *replay*: the 2016 log replayed at 10x into the three nodes with their default QoS: the
  calibration and EKF biases against their goals and the share of IMU messages processed
  (`replay_bench.py`).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

log = logging.getLogger(__name__)


def _inputs(steps: int, seed: int) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    return {
        'speed': 0.5 + 0.3 * rng.random(steps),
        'rate': 0.2 * rng.standard_normal(steps),
        'landmark': rng.uniform(-5.0, 5.0, size=(steps, 2)),
        'noise': rng.standard_normal((steps, 2)) * [0.02, 0.005],
    }


def core_benchmark(steps: int = 20_000, dt_s: float = 0.005, seed: int = 0
                   ) -> dict[str, Any]:
    """Time predict and update of the core EKF and of filterpy on identical inputs.

    Each step predicts once and updates with one observation of a random landmark
    (generated from the filter's own prior plus noise, so both filters see the same z).

    Returns:
        Microseconds per call for both, the speed-up ratios and the largest absolute
        difference of the final state and covariance.
    """
    from filterpy.kalman import ExtendedKalmanFilter

    from gyro_ekf.core import models
    from gyro_ekf.core.config import EkfConfig
    from gyro_ekf.core.ekf import GyroBiasEkf
    from gyro_ekf.core.types import LidarMount

    # The report's model with the gyro's wander modelled (the five states every step of a
    # gyro that wanders computes); filterpy's R is one matrix, without the map's term.
    config = EkfConfig(initial_position_sigma_m=0.1, initial_yaw_sigma_rad=0.05,
                       landmark_sigma_m=0.0, gyro_wander_rad_s=math.radians(0.03))
    mount = LidarMount(0.4, 0.0, 0.0)
    data = _inputs(steps, seed)
    ours = GyroBiasEkf(config, pose=[0.0, 0.0, 0.3], bias_rad_s=0.0)
    theirs = ExtendedKalmanFilter(dim_x=5, dim_z=2)
    theirs.x = ours.x.reshape(5, 1).copy()
    theirs.P = ours.P.copy()
    theirs.R = ours.R.copy()
    z_all = np.empty((steps, 2))
    landmarks = data['landmark']
    # Observations from the core's prior, fixed up front so both filters get the same z.
    probe = GyroBiasEkf(config, pose=[0.0, 0.0, 0.3], bias_rad_s=0.0)
    for k in range(steps):
        probe.predict(data['speed'][k], data['rate'][k], dt_s)
        z_all[k] = models.observe(probe.x, landmarks[k], mount) + data['noise'][k]
        probe.update(z_all[k], landmarks[k], mount)

    def residual(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        out = a - b
        out[1] = (out[1] + math.pi) % (2.0 * math.pi) - math.pi
        return out

    t_pred = t_upd = f_pred = f_upd = 0.0
    clock = time.perf_counter
    for k in range(steps):
        speed, rate, landmark, z = data['speed'][k], data['rate'][k], landmarks[k], z_all[k]
        t0 = clock()
        ours.predict(speed, rate, dt_s)
        t1 = clock()
        ours.update(z, landmark, mount)
        t2 = clock()
        # filterpy: same model; F, Q and f(x) computed per step as its API requires.
        x = theirs.x.ravel()
        tau = config.gyro_wander_tau_s
        theirs.F = models.process_jacobian(x, speed, dt_s, tau)
        theirs.Q = models.process_noise(x, dt_s, config.speed_noise_m_s,
                                        config.gyro_noise_rad_s,
                                        config.position_random_walk_m_sqrt_s,
                                        config.bias_random_walk_rad_s2,
                                        config.gyro_wander_rad_s, tau)
        theirs.x = models.predict_state(x, speed, rate, dt_s, tau).reshape(5, 1)
        theirs.P = theirs.F @ theirs.P @ theirs.F.T + theirs.Q
        t3 = clock()
        theirs.update(z.reshape(2, 1),
                      lambda s: models.observation_jacobian(s.ravel(), landmark, mount),
                      lambda s: models.observe(s.ravel(), landmark, mount).reshape(2, 1),
                      residual=residual)
        t4 = clock()
        t_pred += t1 - t0
        t_upd += t2 - t1
        f_pred += t3 - t2
        f_upd += t4 - t3
    us = 1e6 / steps
    return {
        'steps': steps, 'dt_s': dt_s,
        'core_predict_us': t_pred * us, 'core_update_us': t_upd * us,
        'filterpy_predict_us': f_pred * us, 'filterpy_update_us': f_upd * us,
        'predict_speedup': f_pred / t_pred, 'update_speedup': f_upd / t_upd,
        'cycle_speedup': (f_pred + f_upd) / (t_pred + t_upd),
        'max_abs_state_difference': float(np.max(np.abs(ours.x - theirs.x.ravel()))),
        'max_abs_covariance_difference': float(np.max(np.abs(ours.P - theirs.P))),
    }


def _gyro_ekf(*args: str) -> list[str]:
    return [sys.executable, '-m', 'gyro_ekf.cli.main', '-q', *args]


def _tree_pss_mb(pid: int) -> float:
    """Proportional set size of a process and its descendants (MB); 0 where unreadable.

    A command that forks helpers (`gyro-ekf run`: the pole detector and the products
    writer) uses its processes' memory together; PSS counts the pages they share once.
    """
    total, stack = 0.0, [pid]
    while stack:
        process = stack.pop()
        try:
            for task in os.listdir(f'/proc/{process}/task'):
                with open(f'/proc/{process}/task/{task}/children', encoding='ascii') as file:
                    stack += [int(child) for child in file.read().split()]
            with open(f'/proc/{process}/smaps_rollup', encoding='ascii') as file:
                total += next((int(line.split()[1]) for line in file
                               if line.startswith('Pss:')), 0) / 1024.0
        except (OSError, ValueError):
            continue  # gone meanwhile, or no such file on this system
    return total


def measure_child(command: list[str], env: dict[str, str] | None = None
                  ) -> dict[str, Any]:
    """Run a command as a child; return its wall time, exit code and peak memory (MB).

    ``peak_rss_mb``: the largest of its processes (the kernel's figure); ``peak_tree_mb``:
    the sum of the PSS of it and its children, sampled every 50 ms (Linux; 0 elsewhere).
    """
    import threading

    began = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                             env=env)
    tree = [0.0]
    done = threading.Event()

    def sample() -> None:
        while not done.wait(0.05):
            tree[0] = max(tree[0], _tree_pss_mb(child.pid))
    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    _, status, usage = os.wait4(child.pid, 0)
    done.set()
    sampler.join()
    elapsed = time.perf_counter() - began
    stderr = child.stderr.read().decode(errors='replace') if child.stderr else ''
    if child.stderr:
        child.stderr.close()
    child.returncode = os.waitstatus_to_exitcode(status)
    return {'command': ' '.join(command[2:]), 'wall_s': elapsed,
            'exit_code': child.returncode, 'peak_rss_mb': usage.ru_maxrss / 1024.0,
            'peak_tree_mb': tree[0],
            'stderr_tail': stderr[-500:] if child.returncode else ''}


def run_benchmark(bag: Path, work: Path, repeats: int = 3) -> dict[str, Any]:
    """Real-time factor of `gyro-ekf run --no-plots` on a bag (child processes, cold starts).

    The factor is trip duration over the run's own processing time (bag read to last
    output, from summary.json), and over the child's whole wall time (Python start-up and
    imports included). The run is repeated, as run-to-run noise on a shared machine is
    large, and the median is reported with the spread.

    Raises:
        ValueError: repeats < 1.
    """
    if repeats < 1:
        raise ValueError(f'repeats must be at least 1, got {repeats}')
    out = work / 'run_out'
    runs = []
    for _ in range(repeats):
        result = measure_child(_gyro_ekf('run', str(bag), '-o', str(out), '--no-plots',
                                         '--no-progress', '--force'))
        if result['exit_code'] != 0:
            return result
        summary = json.loads((out / 'summary.json').read_text())
        timing = summary['timing']
        duration = summary['trip']['duration_s']
        processing = timing['read_s'] + timing['run_and_outputs_s']
        result.update({'trip_duration_s': duration, 'processing_s': processing,
                       'read_s': timing['read_s'],
                       'real_time_factor': duration / processing,
                       'real_time_factor_wall': duration / result['wall_s']})
        runs.append(result)
    factors = sorted(r['real_time_factor'] for r in runs)
    median = runs[[r['real_time_factor'] for r in runs].index(factors[len(factors) // 2])]
    return {**median, 'repeats': repeats,
            'real_time_factor_min': factors[0], 'real_time_factor_max': factors[-1],
            'runs': runs}


def memory_benchmark(duration_s: float, work: Path, seed: int = 0) -> dict[str, Any]:
    """Peak memory of convert and run on a simulated trip of the given length."""
    trip_file = work / 'long_trip.npz'
    bag = work / 'long_bag'
    simulate = measure_child(_gyro_ekf('simulate', '-o', str(trip_file), '--seed', str(seed),
                                       '--duration-s', str(duration_s), '--force'))
    convert = measure_child(_gyro_ekf('convert', str(trip_file), '-o', str(bag), '--force'))
    run = measure_child(_gyro_ekf('run', str(bag), '-o', str(work / 'long_out'),
                                  '--no-plots', '--no-progress', '--force'))
    return {'trip_duration_s': duration_s, 'simulate': simulate, 'convert': convert,
            'run': run}


def convert_course_log(data_dir: Path, work: Path) -> Path | None:
    """Convert the real 2016 log to a bag under work; None when the data are missing."""
    logs = data_dir / '2016_project1'
    map_file = data_dir / '2021_aas01' / 'MapMTRN4010.mat'
    if not logs.is_dir() or not map_file.exists():
        log.warning('%s: the 2016 log or its map is missing; no real-time factor', data_dir)
        return None
    bag = work / 'log2016'
    result = measure_child(_gyro_ekf('convert', str(logs), '--map', str(map_file), '-o',
                                     str(bag), '--force'))
    if result['exit_code'] != 0:
        log.warning('converting the 2016 log failed: %s', result['stderr_tail'])
        return None
    return bag


def live_benchmark(duration_s: float = 10.0) -> dict[str, Any]:
    """Live ekf_node latency and CPU over Fast DDS on loopback (see live_bench.py).

    Args:
        duration_s: measured length of each case, s; 0 skips the live benchmark.

    Returns:
        live_bench.live_suite's results, or {'measured': False, 'reason': ...}.
    """
    if duration_s <= 0.0:
        return {'measured': False, 'reason': 'skipped (--live-s 0)'}
    try:
        from benchmarks import live_bench
    except ImportError as err:
        return {'measured': False, 'reason': f'rclpy or the ROS messages are missing: {err}'}
    cases = tuple(dataclasses.replace(case, duration_s=duration_s)
                  for case in live_bench.DEFAULT_CASES)
    node_cases = tuple(dataclasses.replace(case, duration_s=duration_s)
                       for case in live_bench.NODE_CASES)
    return live_bench.live_suite(cases, node_cases=node_cases)


def replay_suite(bag: Path | None, rate: float = 10.0) -> dict[str, Any]:
    """Replay the 2016 log at 10x into the nodes on both message paths (replay_bench.py)."""
    if bag is None:
        return {'measured': False, 'reason': 'the 2016 log is missing'}
    try:
        from benchmarks import replay_bench
    except ImportError as err:
        return {'measured': False, 'reason': f'rclpy or the ROS messages are missing: {err}'}
    runs = []
    for node_io in ('serialized', 'rclpy'):
        log.info('replay of %s at x%g into the nodes (%s path)', bag, rate, node_io)
        try:
            runs.append(replay_bench.replay_benchmark(bag, rate, node_io))
        except Exception as err:  # noqa: BLE001 - one failed case must not end the bench
            log.warning('replay on the %s path failed: %s', node_io, err)
            runs.append({'rate': rate, 'node_io': node_io, 'measured': False,
                         'error': f'{type(err).__name__}: {err}'})
    return {'measured': all(run.get('measured') for run in runs), 'runs': runs}


REPO = Path(__file__).resolve().parents[1]
LOOP_BAG = REPO / 'bags' / 'sim_static_start'
LOOP_GOAL_MB = 5.0


def vm_rss_mb(pid: int) -> float | None:
    """Resident set size of a running process, MB (VmRSS of /proc/PID/status); None if gone."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


def rss_growth(times_s: list[float], rss_mb: list[float], warm_up_s: float
               ) -> dict[str, float | None]:
    """Growth of a sampled RSS after warm_up_s.

    Returns:
        The first sample after warm_up_s, the last one, their difference and the
        least-squares slope per minute over those samples (MB; None without two samples).
    """
    picked = [(t, m) for t, m in zip(times_s, rss_mb) if t >= warm_up_s]
    if len(picked) < 2:
        return {'rss_after_warm_up_mb': None, 'rss_end_mb': None, 'growth_mb': None,
                'slope_mb_per_min': None}
    t = np.array([p[0] for p in picked])
    m = np.array([p[1] for p in picked])
    slope = float(np.polyfit(t, m, 1)[0] * 60.0) if np.ptp(t) > 0 else None
    return {'rss_after_warm_up_mb': float(m[0]), 'rss_end_mb': float(m[-1]),
            'growth_mb': float(m[-1] - m[0]), 'slope_mb_per_min': slope}


def _passes_begun(replay_log: Path) -> int:
    """Count the passes the replay has begun, from its 'pass N' log lines."""
    try:
        return replay_log.read_text(errors='replace').count(': pass ')
    except OSError:
        return 0


def loop_memory_benchmark(bag: Path = LOOP_BAG, loops: int = 30, rate: float = 20.0,
                          domain_id: int | None = None, timeout_s: float = 1800.0
                          ) -> dict[str, Any]:
    """RSS growth of replay --loops and of the nodes it feeds (see the module docstring).

    Args:
        bag: a bag with a params sidecar (a bundled one).
        loops: passes over the bag.
        rate: replay speed-up factor.
        domain_id: ROS domain of the children (default: live_bench's choice).
        timeout_s: give up (and report it) after this long.
    """
    from benchmarks import live_bench
    from gyro_ekf.cli.demo import _config_file

    params = [str(f) for f in (_config_file(), bag.parent / (bag.name + '.params.yaml'))
              if f is not None and f.exists()]
    params_args = [a for f in params for a in ('--params-file', f)]
    results: dict[str, Any] = {'bag': str(bag), 'loops': loops, 'rate': rate,
                               'goal_growth_mb': LOOP_GOAL_MB}
    with live_bench.ros_environment(domain_id) as env:
        work = Path(env['GYRO_EKF_LIVE_WORK'])
        names = ('landmark_detector_node', 'ekf_node', 'replay')
        commands = {
            'landmark_detector_node': [sys.executable, '-m',
                                       'gyro_ekf.nodes.landmark_detector_node', '--ros-args',
                                       *params_args],
            'ekf_node': [sys.executable, '-m', 'gyro_ekf.nodes.ekf_node', '--ros-args',
                         *params_args],
            'replay': _gyro_ekf('replay', str(bag), '--loops', str(loops), '--rate', f'{rate:g}',
                                '--topics', 'imu', 'odom', 'scan', 'landmark_map',
                                'initialpose', '--wait-for', 'imu:1', '--wait-for', 'scan:1'),
        }
        children: dict[str, subprocess.Popen] = {}
        samples: dict[str, list[float]] = {name: [] for name in names}
        times: list[float] = []
        warm_up_s = None
        try:
            for name in names:
                with (work / f'{name}.log').open('w') as out:
                    children[name] = subprocess.Popen(commands[name], env=env, stdout=out,
                                                      stderr=subprocess.STDOUT)
            began = time.monotonic()
            replay = children['replay']
            while replay.poll() is None and time.monotonic() - began < timeout_s:
                now = time.monotonic() - began
                # The first two passes load code, caches and DDS history: growth is
                # counted from the start of the third (the replay logs each pass).
                if warm_up_s is None and _passes_begun(work / 'replay.log') > min(2, loops - 1):
                    warm_up_s = now
                rss = {name: vm_rss_mb(children[name].pid) for name in names}
                if all(v is not None for v in rss.values()):
                    times.append(now)
                    for name in names:
                        samples[name].append(rss[name])
                time.sleep(0.5)
            wall_s = time.monotonic() - began
            results['finished'] = replay.poll() is not None
            results['replay_exit_code'] = replay.poll()
        finally:
            for child in children.values():
                live_bench._stop(child)
        results['wall_s'] = wall_s
        tail = live_bench._tail(work / 'replay.log', 2000).splitlines()
        results['replay_summary'] = next((line for line in reversed(tail)
                                          if line.startswith('replayed ')), '\n'.join(tail[-3:]))
        results['warm_up_s'] = warm_up_s
        if warm_up_s is None:
            warm_up_s = math.inf  # the third pass never began: no figure
        for name in names:
            results[name] = rss_growth(times, samples[name], warm_up_s)
            growth = results[name]['growth_mb']
            results[name]['within_goal'] = growth is not None and growth < LOOP_GOAL_MB
    return results


def run_all(data_dir: Path, long_trip_s: float = 3600.0, core_steps: int = 20_000,
            work: Path | None = None, live_s: float = 10.0, loop_count: int = 30,
            loop_rate: float = 20.0, replay_rate: float = 10.0) -> dict[str, Any]:
    """Run every benchmark; returns the JSON-ready results.

    live_s is the length of each live case; loop_count 0 skips the loop memory case;
    replay_rate 0 skips the replay of the 2016 log.
    """
    own = work is None
    work = Path(tempfile.mkdtemp(prefix='gyro_ekf_bench_')) if own else work
    results: dict[str, Any] = {'python': sys.version.split()[0], 'cpu_count': os.cpu_count()}
    log.info('core predict/update against filterpy (%d steps)', core_steps)
    results['core'] = core_benchmark(core_steps)
    bag = convert_course_log(data_dir, work)
    log.info('gyro-ekf run on the 2016 log')
    results['run_2016'] = run_benchmark(bag, work) if bag is not None else None
    results['live'] = live_benchmark(live_s)
    if replay_rate > 0:
        results['replay'] = replay_suite(bag, replay_rate)
    if loop_count > 0:
        log.info('memory of replay --loops %d and the nodes it feeds', loop_count)
        results['loop_memory'] = loop_memory_benchmark(loops=loop_count, rate=loop_rate)
    log.info('peak memory on a %.0f s simulated trip', long_trip_s)
    results['memory'] = memory_benchmark(long_trip_s, work)
    if own:
        import shutil
        shutil.rmtree(work, ignore_errors=True)
    return results


def table(results: dict[str, Any]) -> str:
    """Human-readable table of the results."""
    core = results['core']
    rows = [('core predict (us/call)', f"{core['core_predict_us']:.2f}"),
            ('filterpy predict (us/call)', f"{core['filterpy_predict_us']:.2f}"),
            ('core update (us/call)', f"{core['core_update_us']:.2f}"),
            ('filterpy update (us/call)', f"{core['filterpy_update_us']:.2f}"),
            ('speed-up predict / update / cycle',
             f"{core['predict_speedup']:.1f}x / {core['update_speedup']:.1f}x / "
             f"{core['cycle_speedup']:.1f}x"),
            ('max |x| / |P| difference vs filterpy',
             f"{core['max_abs_state_difference']:.1e} / "
             f"{core['max_abs_covariance_difference']:.1e}")]
    run = results.get('run_2016')
    if run and run.get('real_time_factor'):
        spread = (f", {run['real_time_factor_min']:.0f}-{run['real_time_factor_max']:.0f}x "
                  f"over {run['repeats']} runs" if run.get('repeats') else '')
        rows += [('run on 2016 log: real-time factor (median)',
                  f"{run['real_time_factor']:.0f}x ({run['real_time_factor_wall']:.0f}x with "
                  f'start-up{spread})'),
                 ('run on 2016 log: peak RSS (MB)', f"{run['peak_rss_mb']:.0f}")]
    rows += live_rows(results['live'])
    if results.get('replay'):
        from benchmarks.replay_bench import replay_rows
        rows += replay_rows(results['replay'])
    rows += loop_memory_rows(results.get('loop_memory'))
    memory = results['memory']
    for step in ('convert', 'run'):
        item = memory[step]
        rows.append((f"{step} peak RSS, {memory['trip_duration_s'] / 3600:.2f} h trip (MB)",
                     f"{item['peak_rss_mb']:.0f}, all its processes "
                     f"{item.get('peak_tree_mb', 0):.0f} ({item['wall_s']:.0f} s"
                     f"{', FAILED' if item['exit_code'] else ''})"))
    width = max(len(name) for name, _ in rows)
    return '\n'.join(f'{name:<{width}}  {value}' for name, value in rows)


def loop_memory_rows(loop: dict[str, Any] | None) -> list[tuple[str, str]]:
    """Table rows of the loop memory case: RSS growth per process."""
    if not loop:
        return []
    rows = []
    for name in ('replay', 'ekf_node', 'landmark_detector_node'):
        item = loop.get(name) or {}
        if item.get('growth_mb') is None:
            rows.append((f"{name} RSS growth, {loop['loops']} loops", 'not measured'))
            continue
        rows.append((f"{name} RSS growth, {loop['loops']} loops x{loop['rate']:g} (MB)",
                     f"{item['growth_mb']:+.1f} ({item['rss_after_warm_up_mb']:.0f} -> "
                     f"{item['rss_end_mb']:.0f}, {item['slope_mb_per_min']:+.2f} MB/min"
                     f"{'' if item['within_goal'] else ', OVER GOAL'})"))
    return rows


def _ms(values: dict[str, Any] | None) -> str:
    if not values or values.get('p50') is None:
        return 'none'
    return f"{values['p50']:.2f} / {values['p99']:.2f} / {values['max']:.2f}"


def live_rows(live: dict[str, Any]) -> list[tuple[str, str]]:
    """Table rows of the live benchmark: latency, completion latency, drops and CPU per case."""
    if not live.get('runs') and not live.get('node_runs'):
        return [('live latency', f"not measured ({live.get('reason', 'no runs')})")]
    rows = []
    for run in live['runs']:
        name = f"live {run['name']}"
        if 'latency_ms' not in run:
            rows.append((name, f"FAILED: {run.get('error', 'unknown error')}"))
            continue
        rows.append((f'{name}: imu->pose p50/p99/max (ms)', _ms(run['latency_ms'])))
        if run['case']['reorder_window_s'] or run['case']['landmarks_hz']:
            rows.append((f'{name}: from completing msg (ms)', _ms(run['completion_latency_ms'])))
        lost = run['poses_missing']
        flushed = run['poses_released_by_idle_flush']
        rows.append((f'{name}: poses missing', f"{lost} of {run['steps']} "
                     f"({100.0 * run['drop_share']:.1f}%{', DROPS' if lost else ''})"
                     + (f', {flushed} only at idle flush' if flushed else '')))
        rows.append((f'{name}: node CPU (us/step, us/msg)',
                     f"{run['node_cpu_us_per_step']:.0f}, {run['node_cpu_us_per_message']:.0f}"
                     f" ({100.0 * run['node_cpu_share']:.0f}% of a core)"))
        if run.get('error'):
            rows.append((f'{name}: error', run['error']))
    for run in live.get('node_runs', []):
        name = f"live {run['name']}"
        if 'node_cpu_us_per_message' not in run:
            rows.append((name, f"FAILED: {run.get('error', 'unknown error')}"))
            continue
        what = 'scan' if 'detector' in run['name'] else 'msg'
        lost = run['messages_sent'] - run['outputs_received']
        rows.append((f'{name}: node CPU (us/{what})',
                     f"{run['node_cpu_us_per_message']:.0f} ({100.0 * run['node_cpu_share']:.0f}%"
                     f" of a core{f', {lost} outputs missing' if lost else ''})"))
        if 'window_cpu_us_per_message' in run:
            rows.append((f'{name}: static window CPU (us/msg)',
                         f"{run['window_cpu_us_per_message']:.0f}"))
    return rows
