"""`python -m fuzz`: mutate bags, chunks, CDR payloads, course logs and params files.

Bounded (--budget-s) and seeded (--seed: input i of target t depends on seed, t and i
only). Prints per target the inputs tried and how they ended, writes results/fuzz.json,
keeps every failing input in fuzz/failures/<target>/<sha1>.bin (a gzip'd tar of the files
plus case.json) and exits 1 when any input was uncaught, hung or silently wrong.
"""

from __future__ import annotations

import os

# One BLAS thread per process: the workers are the parallelism.
for _name in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_name, '1')

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402
import sys  # noqa: E402

from fuzz.harness import FAILING, fuzz  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m fuzz', description=__doc__.split('\n')[0])
    parser.add_argument('--seed', type=int, default=0, help='seed of every input')
    parser.add_argument('--inputs', type=int, default=400,
                        help='inputs per target (scaled by its share)')
    parser.add_argument('--budget-s', type=float, default=240.0,
                        help='stop handing out inputs after this many seconds')
    parser.add_argument('--jobs', type=int, default=2, help='worker processes')
    parser.add_argument('--run-every', type=int, default=10,
                        help='also run `gyro-ekf run` on every n-th readable input')
    parser.add_argument('--targets', default='', help='comma-separated targets (all if empty)')
    parser.add_argument('--report', type=Path, default=REPO / 'results' / 'fuzz.json')
    parser.add_argument('--corpus', type=Path, default=REPO / 'fuzz' / 'failures')
    args = parser.parse_args(argv)
    names = [n for n in args.targets.split(',') if n]
    summary = fuzz(names, args.seed, args.inputs, args.budget_s, args.jobs, args.run_every,
                   args.corpus, args.report)
    failing = sum(summary['total'][k] for k in FAILING) + summary['total']['fuzzer_errors']
    print(f'fuzz: report {args.report}; failing inputs in {args.corpus}/' if failing else
          f'fuzz: report {args.report}; nothing failed')
    return 1 if failing else 0


if __name__ == '__main__':
    sys.exit(main())
