"""One BLAS thread for the project's own processes (the CLI and the nodes).

Imported before numpy by the two entry points, never by the core: a library must not set
a user's threading. The matrices here are small, and after each call big enough to go
parallel (the odometry path fits, core/odometry_online.py) OpenBLAS's worker threads spin
for a while, taking CPU from the main thread wherever the cores are busy: with two other
processes at 100 % on 2 cores, `run_trip` on the 2016 log took 1.61-1.69 s threaded
against 0.87 s with one thread (the same on an idle machine, the same numbers). A caller's
own setting wins.
"""

from __future__ import annotations

import os

for _name in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_name, '1')
