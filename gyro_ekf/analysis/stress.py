"""The stress suite of `make stress` (a benchmark, never a test): seeded trips per class.

Each class is one kind of perturbation of the simulator (docs/stress.md; the simulator's
docstring says what each does), drawn per trip from ranges fixed here. Every trip goes
through what `gyro-ekf run` does between reading a bag and writing its products: the
validation boundary, `analysis.offline.run_trip` with the default parameters (the EventDriver
over every event) and `analysis.summary.summarize`, whose health verdict is the one the run
would print. A trip *passes* when it meets all the bounds; it *failed silently* when it
misses one while the verdict says ok.

Seeds: trip k of every class is simulated with seed ``seed * 10_000 + k``, so all classes
share the same scenes (the clean class is the control of each); a class's perturbation is
drawn from ``np.random.default_rng([seed, crc32(class name), k])``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
import dataclasses
from dataclasses import dataclass
import logging
import math
import multiprocessing
from statistics import NormalDist
import time
from typing import Any
import zlib

import numpy as np

from gyro_ekf.core.simulator import SimulationConfig, gyro_wander, simulate_trip
from gyro_ekf.core.types import Trip

__all__ = ['BOUNDS', 'CLASSES', 'StressClass', 'best_bias_error', 'run_suite', 'table',
           'trip_jobs']

DEG = math.pi / 180.0

POSITION_RMSE_BOUND_M = 0.02
"""Position RMSE against the truth, m (issue 12's bounds)."""
BIAS_ERROR_BOUND_DEG_S = 0.02
"""|Final bias estimate minus the true bias at the end|, deg/s."""
NEES_SHARE_BOUND = 0.9
"""Least share of pose NEES samples inside the two-sided 95 % chi-square band."""
BOUNDS = {'position_rmse_m': POSITION_RMSE_BOUND_M,
          'bias_error_final_deg_s': BIAS_ERROR_BOUND_DEG_S,
          'nees_share_in_band': NEES_SHARE_BOUND}

_Z95 = NormalDist().inv_cdf(0.975)
"""The standard normal's two-sided 95 % quantile (the pass and silent shares' intervals)."""

DEFAULT_DURATION_S = 120.0
"""Trip length: the simulator's default (a 2016-like trip: 8 s static, then driving)."""
MAX_STATIC_SHARE = 0.5
"""Largest share of a trip its static start may take (``--static-s``): the rest is driven, and
a bias step still falls while driving, at least a quarter of the trip before its end."""

Draw = Callable[[np.random.Generator, SimulationConfig], dict[str, Any]]


@dataclass(frozen=True)
class StressClass:
    """One kind of perturbation: its name, what it draws, and the draw itself.

    ``draw(rng, base)`` returns the SimulationConfig fields to change for one trip.
    """

    name: str
    description: str
    draw: Draw


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def _mount_yaw(rng: np.random.Generator, base: SimulationConfig) -> dict[str, Any]:
    prefix = ('lidar', 'lidar2')[int(rng.integers(2))]
    return {'second_lidar': True,
            f'{prefix}_yaw_error_rad': _sign(rng) * rng.uniform(0.0, 10.0) * DEG}


def _mount_offset(rng: np.random.Generator, base: SimulationConfig) -> dict[str, Any]:
    prefix = ('lidar', 'lidar2')[int(rng.integers(2))]
    size, direction = rng.uniform(0.0, 0.10), rng.uniform(0.0, 2.0 * math.pi)
    return {'second_lidar': True, f'{prefix}_x_error_m': size * math.cos(direction),
            f'{prefix}_y_error_m': size * math.sin(direction)}


def _bias_step(rng: np.random.Generator, base: SimulationConfig) -> dict[str, Any]:
    # While driving, and early enough that a quarter of the trip follows it.
    at = rng.uniform(base.static_s, 0.75 * base.duration_s)
    return {'gyro_bias_step_rad_s': _sign(rng) * rng.uniform(0.0, 0.5) * DEG,
            'gyro_bias_step_at_s': at}


def _coloured(rng: np.random.Generator, base: SimulationConfig) -> dict[str, Any]:
    return {'gyro_colored_noise_rad_s': rng.uniform(0.01, 0.04) * DEG,
            'gyro_colored_noise_tau_s': rng.uniform(0.5, 5.0)}


CLASSES: tuple[StressClass, ...] = (
    StressClass('clean', 'no perturbation (the control)', lambda rng, base: {}),
    StressClass('second_lidar', 'a second, rear-facing LiDAR, both mounts exact',
                lambda rng, base: {'second_lidar': True}),
    StressClass('mount_yaw', 'two LiDARs; one (either) off its stated yaw by 0-10 deg, '
                'either sign', _mount_yaw),
    StressClass('mount_offset', 'two LiDARs; one (either) off its stated x/y by 0-10 cm, '
                'any direction', _mount_offset),
    StressClass('speed_scale', 'odometry speed-scale error of -5 % to +5 %',
                lambda rng, base: {'speed_scale_error': rng.uniform(-0.05, 0.05)}),
    StressClass('bias_step', 'yaw-rate bias step of up to +-0.5 deg/s while driving, at '
                'least a quarter of the trip before its end', _bias_step),
    StressClass('bias_ramp', 'yaw-rate bias ramp of up to +-1 deg/s per minute from the start',
                lambda rng, base: {'gyro_bias_ramp_rad_s2':
                                   _sign(rng) * rng.uniform(0.0, 1.0) * DEG / 60.0}),
    StressClass('coloured_gyro', 'Gauss-Markov yaw-rate noise, sigma 0.01-0.04 deg/s, '
                'correlation time 0.5-5 s, on top of the white noise', _coloured),
    StressClass('extra_reflectors', '1-4 reflective poles in the world but not in the map',
                lambda rng, base: {'extra_reflectors': int(rng.integers(1, 5))}),
    StressClass('missing_poles', '1-4 map poles missing in the world',
                lambda rng, base: {'missing_poles': int(rng.integers(1, 5))}),
    StressClass('lidar_dropout', 'one LiDAR dropout of 2-10 s while driving',
                lambda rng, base: {'lidar_dropouts': 1,
                                   'lidar_dropout_s': rng.uniform(2.0, 10.0)}),
    StressClass('imu_gaps', '1-3 IMU gaps of 0.1-1 s each while driving',
                lambda rng, base: {'imu_gaps': int(rng.integers(1, 4)),
                                   'imu_gap_s': rng.uniform(0.1, 1.0)}),
)


@dataclass(frozen=True)
class TripJob:
    """One trip of the suite: its class, index, simulator seed and config changes.

    ``static_s`` None: the suite's default static start (``base_config``).
    """

    stress_class: str
    index: int
    seed: int
    changes: dict[str, Any]
    duration_s: float
    static_s: float | None = None

    @property
    def config(self) -> SimulationConfig:
        """The suite's base config with this job's changes."""
        return dataclasses.replace(base_config(self.duration_s, self.static_s), **self.changes)

    def simulate(self) -> Trip:
        """Simulate the trip: its config, its seed."""
        return simulate_trip(self.config, self.seed)

    def best_bias_error_rad_s(self) -> float | None:
        """Return the best estimate's final bias error on this wander, rad/s (None: none).

        See ``best_bias_error``: the final bias error the trip's own data leave.
        """
        config = self.config
        if config.gyro_colored_noise_rad_s <= 0.0:
            return None
        return best_bias_error(gyro_wander(config, self.seed), 1.0 / config.imu_rate_hz,
                               config.gyro_colored_noise_tau_s)


def best_bias_error(wander: np.ndarray, period_s: float, tau_s: float) -> float:
    """Return the error of the best estimate of a constant bias seen through a wander.

    A gyro whose yaw-rate error is a constant b plus a first-order Gauss-Markov wander c
    (correlation time tau_s, sampled every period_s) tells b apart from c only by c's mean
    reversion. Even an estimator that saw b + c itself at every sample, with no white noise
    and the wander's sigma and tau known, has b's best linear unbiased estimate (generalised
    least squares with the AR(1) covariance sigma^2 phi^|i-j|, phi = exp(-period_s / tau_s))
    off by a weighted mean of the wander::

        (c_0 + c_(n-1) + (1 - phi) sum(c_1 .. c_(n-2))) / (2 + (n - 2) (1 - phi))

    (the AR(1) inverse covariance is tridiagonal: its row sums are 1 - phi at the ends and
    (1 - phi)^2 inside). Where that lies beyond the bias bound, the trip's own data
    mislead the best estimate: a filter that passes it is lucky, and one that misses it
    is not at fault.

    Args:
        wander: c at each sample, shape (n,), rad/s.
        period_s: the sample period, s.
        tau_s: the wander's correlation time, s.
    """
    values = np.asarray(wander, dtype=float)
    if values.size <= 2:
        return float(values.mean())
    weight = 1.0 - math.exp(-period_s / tau_s)
    inner = float(values[1:-1].sum())
    return ((float(values[0]) + float(values[-1]) + weight * inner)
            / (2.0 + (values.size - 2) * weight))


def base_config(duration_s: float, static_s: float | None = None) -> SimulationConfig:
    """Return the unperturbed config of the suite's trips: the defaults at this length.

    The static start is ``static_s`` when given (at most ``MAX_STATIC_SHARE`` of the
    trip), else the default 8 s, or a quarter of a short trip.

    Raises:
        ValueError: ``static_s`` is negative or more than ``MAX_STATIC_SHARE`` of the trip.
    """
    if static_s is None:
        static_s = min(SimulationConfig().static_s, 0.25 * duration_s)
    elif not 0.0 <= static_s <= MAX_STATIC_SHARE * duration_s:
        raise ValueError(f'a static start of {static_s:g} s in a {duration_s:g} s trip: it '
                         f'must be at least 0 s and at most {MAX_STATIC_SHARE:g} of the trip')
    return SimulationConfig(duration_s=duration_s, static_s=static_s)


def trip_jobs(trips_per_class: int, seed: int, duration_s: float = DEFAULT_DURATION_S,
              classes: tuple[StressClass, ...] = CLASSES,
              static_s: float | None = None) -> list[TripJob]:
    """Return every trip of the suite, class by class (see the module docstring for seeds)."""
    base = base_config(duration_s, static_s)
    jobs = []
    for stress_class in classes:
        key = zlib.crc32(stress_class.name.encode())
        for k in range(trips_per_class):
            rng = np.random.default_rng([seed, key, k])
            changes = {name: (value if isinstance(value, (bool, int)) else float(value))
                       for name, value in stress_class.draw(rng, base).items()}
            jobs.append(TripJob(stress_class.name, k, seed * 10_000 + k, changes, duration_s,
                                static_s))
    return jobs


def stress_trip(class_name: str, seed: int, index: int) -> Trip:
    """Simulate trip ``index`` of a class of ``gyro-ekf stress --seed seed`` (default length)."""
    chosen = tuple(c for c in CLASSES if c.name == class_name)
    if not chosen:
        raise ValueError(f'no stress class {class_name!r}')
    return trip_jobs(index + 1, seed, classes=chosen)[index].simulate()


def _finite(value: Any) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def run_job(job: TripJob) -> dict[str, Any]:
    """Simulate one trip and run it as `gyro-ekf run` does; return its record."""
    # Imported here: a worker process needs them, the parent only to build the jobs.
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.analysis.summary import summarize
    from gyro_ekf.core.validation import validate_trip
    from gyro_ekf.errors import GyroEkfError

    # One info line per trip from the offline calibration would bury the table.
    logging.getLogger('gyro_ekf.analysis.offline').setLevel(logging.WARNING)
    record: dict[str, Any] = {'class': job.stress_class, 'index': job.index, 'seed': job.seed,
                              'changes': job.changes}
    best = job.best_bias_error_rad_s()
    # A coloured trip's wander may itself end the best estimate beyond the bias bound.
    record.update({'best_bias_error_deg_s': None if best is None else math.degrees(best),
                   'beyond_reach': best is not None
                   and abs(math.degrees(best)) > BIAS_ERROR_BOUND_DEG_S})
    began = time.perf_counter()
    try:
        trip = job.simulate()
        trip, report = validate_trip(trip, trip.name)
        summary = summarize(run_trip(trip), report)
    except GyroEkfError as err:
        # Loud, not silent: the run stopped with an error a user would see.
        record.update({'error': str(err), 'passed': False, 'silent': False,
                       'verdict': None, 'elapsed_s': time.perf_counter() - began})
        return record
    truth = summary['ground_truth']
    figures = {'position_rmse_m': _finite(truth['position_rmse_m']),
               'position_max_error_m': _finite(truth['position_max_error_m']),
               'bias_error_final_deg_s': _finite(truth['bias_error_final_deg_s']),
               'nees_share_in_band': _finite(truth['nees_share_in_band']),
               # Which side a NEES miss lies on: below the band the covariance is larger
               # than the error (conservative), above it smaller (overconfident).
               'nees_share_below_band': _finite(truth['nees_share_below_band']),
               'nees_share_above_band': _finite(truth['nees_share_above_band']),
               'share_associated': _finite(summary['association']['share_associated']),
               'nis_mean': _finite(summary['nis']['mean']),
               'bias_reopened': summary['online_bias']['reopened'],
               'gyro_noise_scale': summary['online_bias']['gyro_noise_scale'],
               'gyro_wander_deg_s': summary['online_bias']['gyro_wander_deg_s'],
               'gyro_wander_prior_ruled_out_s':
                   summary['online_bias']['gyro_wander_prior_ruled_out_s'],
               'bias_rate_deg_s_per_min': summary['online_bias']['rate_deg_s_per_min']}
    # A figure that could not be computed (None) misses its bound.
    rmse, bias_error, nees = (figures[name] for name in BOUNDS)
    missed = [name for name, ok in (
        ('position_rmse_m', rmse is not None and rmse <= POSITION_RMSE_BOUND_M),
        ('bias_error_final_deg_s',
         bias_error is not None and abs(bias_error) <= BIAS_ERROR_BOUND_DEG_S),
        ('nees_share_in_band', nees is not None and nees >= NEES_SHARE_BOUND)) if not ok]
    verdict = summary['health']['verdict']
    record.update(figures)
    record.update({'verdict': verdict, 'reasons': summary['health']['reasons'],
                   'missed': missed, 'passed': not missed,
                   'silent': bool(missed) and verdict == 'ok',
                   'elapsed_s': time.perf_counter() - began})
    return record


def _records(jobs: list[TripJob], workers: int) -> Iterator[dict[str, Any]]:
    if workers <= 1:
        yield from map(run_job, jobs)
        return
    with multiprocessing.get_context().Pool(workers) as pool:
        yield from pool.imap_unordered(run_job, jobs, chunksize=1)


def _median(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.median(kept)) if kept else None


def wilson_interval(count: int, trips: int) -> list[float] | None:
    """Return the two-sided 95 % Wilson score interval [low, high] of a share count / trips.

    25 trips say little about a share near 95 %: 24 of 25 passed is 80-99 %, and no silent
    failure in 25 trips only bounds its share below 13 %. The Wilson interval keeps within
    [0, 1] and has a width at 0 or 25 of 25, where the normal (Wald) one shrinks to a point.
    """
    if trips <= 0:
        return None
    z2 = _Z95 * _Z95
    share = count / trips
    centre = (share + z2 / (2.0 * trips)) / (1.0 + z2 / trips)
    half = (_Z95 / (1.0 + z2 / trips)
            * math.sqrt(share * (1.0 - share) / trips + z2 / (4.0 * trips * trips)))
    # At 0 and all of trips the bound is exactly 0 or 1 (the formula leaves rounding).
    return [0.0 if count == 0 else max(0.0, centre - half),
            1.0 if count == trips else min(1.0, centre + half)]


def _class_summary(stress_class: StressClass, records: list[dict[str, Any]]
                   ) -> dict[str, Any]:
    n = len(records)
    passed = sum(r['passed'] for r in records)
    silent = [r for r in records if r['silent']]
    return {
        'description': stress_class.description, 'trips': n,
        'passed': passed, 'pass_rate': passed / n if n else None,
        'pass_rate_ci95': wilson_interval(passed, n),
        'silent_failures': len(silent), 'silent_rate': len(silent) / n if n else None,
        'silent_rate_ci95': wilson_interval(len(silent), n),
        'errors': sum('error' in r for r in records),
        'verdicts': dict(Counter(str(r['verdict']) for r in records)),
        # Verdict not ok on a trip within the bounds: a false alarm on clean data, a fair
        # warning where a sensor is off (an excluded LiDAR is a reason to be degraded).
        'flagged_within_bounds': sum(r['passed'] and r['verdict'] != 'ok' for r in records),
        # Trips whose wander leaves even the best estimate beyond the bias bound
        # (best_bias_error): a miss there is the data's, not the filter's.
        'beyond_reach': sum(bool(r.get('beyond_reach')) for r in records),
        'missed': dict(Counter(b for r in records for b in r.get('missed', ()))),
        'silent_missed': dict(Counter(b for r in silent for b in r['missed'])),
        # Silent failures that missed the NEES share alone, with more of their samples
        # below the band than above it: a covariance larger than the error, the estimate
        # within its bounds (the static starts of docs/stress.md).
        'silent_nees_below_band': sum(
            r['missed'] == ['nees_share_in_band']
            and (r.get('nees_share_below_band') or 0.0) > (r.get('nees_share_above_band') or 0.0)
            for r in silent),
        'median_position_rmse_m': _median([r.get('position_rmse_m') for r in records]),
        'worst_position_rmse_m': max((r['position_rmse_m'] for r in records
                                      if r.get('position_rmse_m') is not None), default=None),
        'median_abs_bias_error_deg_s': _median([
            None if r.get('bias_error_final_deg_s') is None else abs(r['bias_error_final_deg_s'])
            for r in records]),
        'median_nees_share_in_band': _median([r.get('nees_share_in_band') for r in records]),
    }


def run_suite(trips_per_class: int, seed: int = 0, workers: int = 2,
              duration_s: float = DEFAULT_DURATION_S,
              progress: Callable[[int], None] | None = None,
              static_s: float | None = None) -> dict[str, Any]:
    """Run every trip of every class; return the JSON-ready results.

    Args:
        trips_per_class: trips simulated per class (>= 1).
        seed: base seed of the suite (>= 0).
        workers: processes (1: in this process).
        duration_s: length of each trip, s.
        progress: called with 1 after each trip.
        static_s: the static start of every trip, s (None: ``base_config``'s default).
    """
    jobs = trip_jobs(trips_per_class, seed, duration_s, static_s=static_s)
    began = time.perf_counter()
    records = []
    for record in _records(jobs, workers):
        records.append(record)
        if progress is not None:
            progress(1)
    elapsed = time.perf_counter() - began
    records.sort(key=lambda r: ([c.name for c in CLASSES].index(r['class']), r['index']))
    classes = {c.name: _class_summary(c, [r for r in records if r['class'] == c.name])
               for c in CLASSES}
    total = len(records)
    passed = sum(r['passed'] for r in records)
    silent = sum(r['silent'] for r in records)
    return {
        'suite': {'trips_per_class': trips_per_class, 'seed': seed, 'workers': workers,
                  'duration_s': duration_s,
                  'static_s': base_config(duration_s, static_s).static_s,
                  'trips': total, 'elapsed_s': elapsed,
                  'trip_seconds_per_second': total * duration_s / elapsed if elapsed else None},
        'bounds': BOUNDS,
        'totals': {'passed': passed, 'pass_rate': passed / total if total else None,
                   'pass_rate_ci95': wilson_interval(passed, total),
                   'silent_failures': silent, 'silent_rate_ci95': wilson_interval(silent, total),
                   'silent_nees_below_band': sum(c['silent_nees_below_band']
                                                 for c in classes.values()),
                   'errors': sum('error' in r for r in records)},
        'classes': classes,
        'trips': records,
    }


def _percent(value: float | None) -> str:
    return 'n/a' if value is None else f'{100.0 * value:.0f} %'


def _span(interval: list[float], digits: int = 0) -> str:
    low, high = interval
    return f'{100.0 * low:.{digits}f}-{100.0 * high:.{digits}f}'


def _with_interval(value: float | None, interval: list[float] | None) -> str:
    if value is None or interval is None:
        return _percent(value)
    return f'{_percent(value)} ({_span(interval)})'


def table(results: dict[str, Any]) -> str:
    """Return the per-class figures, pass and silent-failure shares first, as text."""
    header = ('class', 'trips', 'pass (95 % CI)', 'silent (95 % CI)', 'verdict ok/deg/fail',
              'RMSE med (cm)', '|bias err| med (deg/s)', 'NEES med')
    rows = []
    for name, c in results['classes'].items():
        verdicts = c['verdicts']
        rmse = c['median_position_rmse_m']
        bias = c['median_abs_bias_error_deg_s']
        nees = c['median_nees_share_in_band']
        rows.append((name, str(c['trips']),
                     _with_interval(c['pass_rate'], c.get('pass_rate_ci95')),
                     _with_interval(c['silent_rate'], c.get('silent_rate_ci95')),
                     '/'.join(str(verdicts.get(v, 0)) for v in ('ok', 'degraded', 'failed')),
                     'n/a' if rmse is None else f'{100.0 * rmse:.2f}',
                     'n/a' if bias is None else f'{bias:.4f}',
                     'n/a' if nees is None else f'{nees:.3f}'))
    widths = [max(len(row[i]) for row in rows + [header]) for i in range(len(header))]
    lines = ['  '.join(cell.ljust(w) if i == 0 else cell.rjust(w)
                       for i, (cell, w) in enumerate(zip(row, widths)))
             for row in [header] + rows]
    for name, c in results['classes'].items():
        if c.get('beyond_reach'):
            lines.append(f"{name}: {c['beyond_reach']} of {c['trips']} trip(s) end on a "
                         f"wander that leaves even the best estimate of a constant bias "
                         f"beyond {BIAS_ERROR_BOUND_DEG_S:g} deg/s (best_bias_error_deg_s in "
                         f"the JSON): a miss there is the data's, not the filter's")
    suite, totals = results['suite'], results['totals']
    below = (f" ({totals['silent_nees_below_band']} of them the NEES share alone missed below "
             f"the band: a covariance larger than the error)"
             if totals.get('silent_nees_below_band') else '')
    silent_interval = totals.get('silent_rate_ci95')
    silent_share = ('' if silent_interval is None
                    else f' (share {_span(silent_interval, 1)} %, 95 % CI)')
    lines.append(f"{suite['trips']} trips of {suite['duration_s']:g} s ("
                 f"{suite['static_s']:g} s static start), seed {suite['seed']}: "
                 f"{_with_interval(totals['pass_rate'], totals.get('pass_rate_ci95'))} "
                 f"within the bounds (RMSE <= "
                 f"{100 * POSITION_RMSE_BOUND_M:g} cm, |final bias error| <= "
                 f"{BIAS_ERROR_BOUND_DEG_S:g} deg/s, NEES share in band >= "
                 f"{NEES_SHARE_BOUND:g}); {totals['silent_failures']} silent failure(s)"
                 f"{silent_share}{below}; "
                 f"{totals['errors']} error(s); {suite['elapsed_s']:.0f} s on "
                 f"{suite['workers']} worker(s)")
    return '\n'.join(lines)
