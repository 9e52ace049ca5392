"""A short deterministic slice of `make fuzz`: a few hundred mutated inputs, seed 0.

Every input must end as a clean one-line error (a GyroEkfError) or a result equal to its
oracle (rosbags' reader for bags and CDR payloads; finite, plausible values for course
logs and params files). The full run with its figures is `make fuzz` (results/fuzz.json).
"""

from fuzz.harness import FAILING, fuzz

SLICE = {'bag': 25, 'mcap_chunk': 25, 'bag_meta': 25, 'cdr': 80, 'mat': 80, 'params': 50}


def test_fuzz_slice_has_no_uncaught_hang_or_silently_wrong(tmp_path):
    summary = fuzz(sorted(SLICE), seed=0, inputs=SLICE, budget_s=1e9, jobs=2,
                   run_every=10 ** 9, corpus=tmp_path / 'failures',
                   report=tmp_path / 'fuzz.json', out=lambda line: None)
    assert summary['total']['inputs'] == sum(SLICE.values())
    assert summary['total']['fuzzer_errors'] == 0, summary
    failures = [f"{name} #{f['index']} {f['kind']}: {f['note']} -> {f['detail']}"
                for name, p in summary['targets'].items() for f in p['failures']]
    counts = {k: summary['total'][k] for k in FAILING}
    assert not failures, f'{counts}; first failures:\n' + '\n'.join(failures[:20])
