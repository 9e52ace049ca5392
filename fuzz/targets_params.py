"""Params-file target: config/gyro_ekf.yaml, damaged, through `read_params_file`.

A value is made bad (NaN, inf, huge, negative, the wrong type), a key dropped or the
text damaged. The reader must refuse a bad file with a ParamsFileError (a GyroEkfError)
or return configs holding only finite values within their bounds; a returned NaN or inf
(or a node option of the wrong kind) is silently wrong: the filter would run on it.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
import random

from fuzz import isolate
from fuzz.harness import Case, Target, Verdict
from fuzz.targets_bag import mutate_yaml_values

PARAMS = Path(__file__).resolve().parent.parent / 'config' / 'gyro_ekf.yaml'


def read(path: Path) -> list[str]:
    """Problems of the values read_params_file returns."""
    from gyro_ekf.io.params_file import read_params_file
    params = read_params_file(path)
    out = []
    for group in ('ekf', 'calibration', 'detector', 'options'):
        config = getattr(params, group)
        for spec in dataclasses.fields(config):
            value = getattr(config, spec.name)
            if isinstance(value, float) and not math.isfinite(value):
                out.append(f'{group}.{spec.name} = {value}')
            low, high = spec.metadata.get('min'), spec.metadata.get('max')
            if isinstance(value, (int, float)) and not isinstance(value, bool) and (
                    (low is not None and value < low) or (high is not None and value > high)):
                out.append(f'{group}.{spec.name} = {value} outside [{low}, {high}]')
    for spec in dataclasses.fields(params.options):
        value = getattr(params.options, spec.name)
        if isinstance(spec.default, bool) and not isinstance(value, bool):
            out.append(f'option {spec.name} = {value!r} is not a boolean')
    return out


class Params(Target):
    name = 'params'
    share = 0.6

    def generate(self, rng: random.Random) -> Case:
        data, note = mutate_yaml_values(PARAMS.read_bytes(), rng)
        return Case({'params.yaml': data}, note)

    def check(self, case: Case, folder: Path, run: bool) -> Verdict:
        verdict = Verdict()
        outcome = isolate.call(read, folder / 'params.yaml')
        verdict.account('read_params_file', outcome)
        if outcome.status == 'ok' and outcome.value:
            verdict.worse('silent', f'read_params_file returned: {outcome.value[0]}')
        return verdict


TARGETS = [Params()]
