"""The fuzzer is a top-level package of the repository (fuzz/), not part of gyro_ekf."""

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
