"""Course-log target: small valid .mat logs of every vintage with one value made bad.

The logs come from test/io/synthetic_logs.py (the io tests' writers, in the layout of each
vintage); a `change` hook sets values to NaN, inf, huge or negative numbers, reshapes or
retypes a field, drops it, or makes stamps go back; one input in ten damages the written
file's bytes instead. `load_log` must refuse such a log with a LogFormatError (or another
GyroEkfError) or return a trip without problems (oracle.trip_problems): a returned trip
holding NaN, inf, values beyond InputLimits or stamps going back is silently wrong.
"""

from __future__ import annotations

from pathlib import Path
import random
import sys
import tempfile
from typing import Any, Callable

import numpy as np

from fuzz import isolate
from fuzz.harness import Case, Target, Verdict
from fuzz.oracle import summarise_trip
from fuzz.targets_bag import mutate_bytes

_TEST_IO = Path(__file__).resolve().parent.parent / 'test' / 'io'
_MAT_HEADER = b'MATLAB 5.0 MAT-file, written by the gyro_ekf fuzzer'.ljust(116)

VINTAGES = ('2016', '2021', '2022', '2023')
TIME_KEYS = ('times', 't', 'table')


def _writers() -> dict[str, Callable[..., Any]]:
    if str(_TEST_IO) not in sys.path:
        sys.path.insert(0, str(_TEST_IO))
    import synthetic_logs as logs
    return {'2016': lambda d, change: logs.write_2016(d, change=change),
            '2021': lambda d, change: logs.write_2021(d, change=change),
            '2022': lambda d, change: logs.write_2022(d / 'data019b.mat', change=change),
            '2023': lambda d, change: logs.write_2023(d / 'DataUsr_006k.mat', change=change)}


def _arrays(tree: dict[str, Any], prefix: tuple = ()) -> list[tuple]:
    out = []
    for key, value in tree.items():
        if isinstance(value, dict):
            out += _arrays(value, prefix + (key,))
        elif not isinstance(value, str):
            out.append(prefix + (key,))
    return out


def _get(tree: dict[str, Any], path: tuple) -> Any:
    for key in path:
        tree = tree[key]
    return tree


def _put(tree: dict[str, Any], path: tuple, value: Any) -> None:
    for key in path[:-1]:
        tree = tree[key]
    if value is _DELETE:
        del tree[path[-1]]
    else:
        tree[path[-1]] = value


_DELETE = object()


def change_value(rng: random.Random) -> Callable[[dict[str, Any]], str]:
    """Make a change hook for a synthetic writer; what it did goes to `change.notes`."""
    def change(variables: dict[str, Any]) -> None:
        leaves = _arrays(variables)
        times = [p for p in leaves if p[-1] in TIME_KEYS]
        path = rng.choice(times) if times and rng.random() < 0.3 else rng.choice(leaves)
        value = np.array(_get(variables, path))
        name = '.'.join(path)
        kind = rng.choice(('nan', 'inf', '-inf', 'huge', '-huge', 'negative', 'zero', 'back',
                           'jump', 'shape', 'dtype', 'delete', 'scalar'))
        flat = value.astype(np.float64).ravel().copy() if value.size else np.zeros(0)
        picks = sorted({rng.randrange(flat.size) for _ in range(rng.randint(1, 3))}
                       ) if flat.size else []
        if kind in ('nan', 'inf', '-inf', 'huge', '-huge', 'negative', 'zero') and picks:
            new = {'nan': np.nan, 'inf': np.inf, '-inf': -np.inf, 'huge': 1e300,
                   '-huge': -1e300, 'negative': -1.0, 'zero': 0.0}[kind]
            if kind == 'negative':
                flat[picks] = -np.abs(flat[picks]) - 1.0
            else:
                flat[picks] = new
            _put(variables, path, flat.reshape(value.shape))
            notes.append(f'{name}: elements {picks} set to {kind}')
        elif kind in ('back', 'jump') and picks and value.ndim:
            row = flat.reshape(value.shape)
            line = row[0] if row.ndim == 2 else row
            at = rng.randrange(line.size)
            step = float(np.abs(line).max() or 1.0)
            if kind == 'back':
                line[at:] -= rng.choice((1.0, 0.1 * step, 10 * step))
            else:
                line[at:] += rng.choice((1e5, 1e9, 3e5 * 1e4))
            _put(variables, path, row)
            notes.append(f'{name}: values from index {at} moved ({kind})')
        elif kind == 'shape':
            how = rng.choice(('transpose', 'drop_row', 'drop_col', 'empty', 'axis'))
            shaped = np.atleast_2d(value)
            if shaped.shape[1] < 2:
                how = 'empty'
            new = {'transpose': lambda a: a.T, 'drop_row': lambda a: a[:-1],
                   'drop_col': lambda a: a[:, :-1], 'empty': lambda a: a[:0],
                   'axis': lambda a: a[None]}[how](shaped)
            _put(variables, path, new)
            notes.append(f'{name}: shape {value.shape} -> {how} {np.shape(new)}')
        elif kind == 'dtype':
            how = rng.choice(('str', 'bool', 'complex', 'int8', 'uint8'))
            new = {'str': lambda a: 'text', 'bool': lambda a: a.astype(bool),
                   'complex': lambda a: a.astype(np.complex128) + 1j,
                   'int8': lambda a: a.astype(np.float64).astype(np.int8),
                   'uint8': lambda a: a.astype(np.float64).astype(np.uint8)}[how](value)
            _put(variables, path, new)
            notes.append(f'{name}: type {value.dtype} -> {how}')
        elif kind == 'delete':
            _put(variables, path, _DELETE)
            notes.append(f'{name}: deleted')
        else:
            _put(variables, path, np.float64(rng.choice((0.0, -1.0, np.nan))))
            notes.append(f'{name}: replaced by a scalar')

    notes: list[str] = []
    change.notes = notes  # type: ignore[attr-defined]
    return change


def load(paths: list[Path]) -> dict[str, Any]:
    from gyro_ekf.io.sources import load_log
    return summarise_trip(load_log(paths))


class Mat(Target):
    name = 'mat'
    share = 1.0

    def generate(self, rng: random.Random) -> Case:
        vintage = rng.choice(VINTAGES)
        writers = _writers()
        change = change_value(rng)
        blind = rng.random() < 0.1
        with tempfile.TemporaryDirectory(prefix='fuzz-mat-') as tmp:
            folder = Path(tmp)
            writers[vintage](folder, None if blind else change)
            files = {p.name: p.read_bytes() for p in sorted(folder.iterdir())}
        for name in files:
            files[name] = _MAT_HEADER + files[name][116:]
        if blind:
            name = rng.choice(sorted(files))
            files[name], note = mutate_bytes(files[name], rng)
            note = f'{name}: {note}'
        else:
            note = '; '.join(change.notes) or 'unchanged'  # type: ignore[attr-defined]
        return Case(files, f'{vintage}: {note}', {'vintage': vintage})

    def check(self, case: Case, folder: Path, run: bool) -> Verdict:
        verdict = Verdict()
        vintage = case.meta['vintage']
        paths = [folder] if vintage in ('2016', '2021') else [
            folder / n for n in case.files if n.endswith('.mat')]
        outcome = isolate.call(load, paths)
        verdict.account('load_log', outcome)
        if outcome.status == 'ok' and outcome.value['problems']:
            verdict.worse('silent', f"load_log returned: {outcome.value['problems'][0]}")
        return verdict


TARGETS = [Mat()]
