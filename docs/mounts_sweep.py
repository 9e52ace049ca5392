"""Measure `calibrate-mounts` on simulated two-LiDAR trips and course logs (docs/mounts.md).

    .venv/bin/python docs/mounts_sweep.py [--duration-s 60] [--logs ../shared/data/mtrn4010]

For each yaw error of the second LiDAR (one seed each, moving from t = 0 as the README's
simulator rows unless --static-s): simulate a bag, estimate the mounts as `calibrate-mounts`
does, write its params file, then `gyro-ekf run` the bag with the stated mounts, with the
params file and with the true mount.
Course logs with two LiDARs (the 2023 format) are converted and measured the same way.
Prints a Markdown table; nothing is written outside a temporary folder.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import math
from pathlib import Path
import sys
import tempfile

from gyro_ekf.cli.calibrate_mounts import estimate_mounts, params_yaml
from gyro_ekf.cli.main import main
from gyro_ekf.core.mount_calibration import MountSettings
from gyro_ekf.core.types import LidarMount
from gyro_ekf.io.bag_reader import read_bag

ERRORS_DEG = (-10.0, -9.0, -7.0, -5.0, -3.0, -1.0, -0.3, -0.15, 0.0, 0.15, 0.3, 1.0, 3.0,
              5.0, 7.0, 9.0, 10.0)
HEADER = ('| trip | true error (deg) | found (deg) | sigma (deg) | residual fit / stated (cm) '
          '| written | associated stated -> written | RMSE stated -> written (mm) '
          '| NEES share stated -> written (true mount) | bias error written (deg/s) |')


def _run(bag: Path, out: Path, *extra: str) -> dict:
    with contextlib.redirect_stdout(io.StringIO()):    # run's own table
        code = main(['-q', 'run', str(bag), '-o', str(out), '--no-progress', '--no-plots',
                     '--no-bag', *extra])
    if code != 0:
        raise SystemExit(f'{bag}: run failed')
    return json.loads((out / 'summary.json').read_text())


def _row(name: str, true_deg: float | None, bag: Path, work: Path,
         settings: MountSettings) -> str:
    trip = read_bag(bag, acceleration=False).trip
    (found,) = estimate_mounts(trip, str(bag), settings)
    params = work / f'{bag.name}.mounts.yaml'
    params.write_text(params_yaml([found], trip.scans[0]), encoding='utf-8')
    before = _run(bag, work / f'{bag.name}.stated')
    after = _run(bag, work / f'{bag.name}.written', '--params-file', str(params))
    exact = after
    if true_deg is not None:
        true = dataclasses.replace(found, mount=LidarMount(
            found.stated.x_m, found.stated.y_m, found.stated.yaw_rad + math.radians(true_deg)),
            significant=True)
        true_params = work / f'{bag.name}.true.yaml'
        true_params.write_text(params_yaml([true], trip.scans[0]), encoding='utf-8')
        exact = _run(bag, work / f'{bag.name}.true', '--params-file', str(true_params))

    def share(s: dict) -> str:
        return f"{100 * s['association']['share_associated']:.1f}"

    def truth(s: dict, key: str, scale: float, digits: int) -> str:
        value = (s.get('ground_truth') or {}).get(key)
        return 'no truth' if value is None else f'{scale * value:.{digits}f}'

    return ' | '.join([
        f'| {name}', 'stated exact' if true_deg is None else f'{true_deg:+.2f}',
        f'{math.degrees(found.yaw_error_rad):+.3f}', f'{math.degrees(found.sigma[0]):.3f}',
        f'{100 * found.rms_residual_m:.2f} / {100 * found.rms_residual_stated_m:.2f}',
        'fit' if found.significant else 'stated',
        f'{share(before)} -> {share(after)} %',
        f"{truth(before, 'position_rmse_m', 1e3, 1)} -> {truth(after, 'position_rmse_m', 1e3, 1)}",
        f"{truth(before, 'nees_share_in_band', 1, 3)} -> "
        f"{truth(after, 'nees_share_in_band', 1, 3)} ({truth(exact, 'nees_share_in_band', 1, 3)})",
        f"{truth(after, 'bias_error_final_deg_s', 1, 4)} |"])


def main_sweep(argv: list[str] | None = None) -> int:
    """Print the table; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration-s', type=float, default=60.0)
    parser.add_argument('--static-s', type=float, default=0.0)
    parser.add_argument('--first-seed', type=int, default=101)
    parser.add_argument('--no-logs', action='store_true')
    parser.add_argument('--min-improvement', type=float, default=0.1)
    parser.add_argument('--logs', type=Path,
                        default=Path(__file__).resolve().parents[2] / 'shared/data/mtrn4010')
    args = parser.parse_args(argv)
    settings = MountSettings(min_improvement=args.min_improvement)
    print(HEADER)
    print('|' + '---|' * HEADER.count(' | ') + '---|')
    with tempfile.TemporaryDirectory(prefix='mounts_sweep_') as folder:
        work = Path(folder)
        log2023 = args.logs / '2023_sim'
        if log2023.is_dir() and not args.no_logs:
            bag = work / 'course2023'
            if main(['-q', 'convert', str(log2023), '-o', str(bag)]) != 0:
                raise SystemExit(f'{log2023}: convert failed')
            print(_row('2023 course log', None, bag, work, settings), flush=True)
        for i, error in enumerate(ERRORS_DEG):
            seed = args.first_seed + i
            bag = work / f'sim{seed}'
            if main(['-q', 'simulate', '-o', str(bag), '--seed', str(seed), '--duration-s',
                     f'{args.duration_s:g}', '--static-s', f'{args.static_s:g}', '--second-lidar',
                     '--lidar2-yaw-error-deg', f'{error:g}']) != 0:
                raise SystemExit(f'seed {seed}: simulate failed')
            print(_row(f'sim seed {seed}', error, bag, work, settings), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main_sweep())
