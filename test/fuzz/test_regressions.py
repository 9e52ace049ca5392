"""Every input the fuzzer once failed on, replayed through its target.

test/fuzz/regressions/<target>/<name>.bin is a case as the fuzzer saves it (a gzip'd tar of
the files plus case.json with the mutation and what the check needs); promote one with
`cp fuzz/failures/<target>/<sha1>.bin test/fuzz/regressions/<target>/<what-it-is>.bin`.
Each must now end as a clean error or a correct result (never uncaught, hang or silently
wrong); the bags in it were written by the project's simulator.
"""

from pathlib import Path

import pytest

from fuzz.harness import Case, discover, judge

HERE = Path(__file__).resolve().parent / 'regressions'
CASES = sorted(HERE.glob('*/*.bin'))


def test_there_are_regression_cases():
    assert len(CASES) >= 5


@pytest.mark.parametrize('path', CASES, ids=[f'{p.parent.name}/{p.stem}' for p in CASES])
def test_regression_case_ends_clean_or_correct(path):
    target = discover()[path.parent.name]
    case = Case.from_bytes(path.read_bytes())
    verdict = judge(target, case, run=True)
    assert verdict.kind in ('clean', 'correct'), (
        f'{case.note}: {verdict.kind}: {verdict.detail}')
