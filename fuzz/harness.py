"""The fuzzing loop: targets, inputs, verdicts, the report and the failure corpus.

A target (a class in a module `fuzz/targets_*.py`, listed in its module's TARGETS) makes
seed files once (`setup`), turns a seeded `random.Random` into one mutated input (`generate`,
deterministic) and judges an input (`check`), calling the readers through
`isolate.call` so that a hang or a crash costs one child, not the fuzzer. New targets need
no change here: every `targets_*.py` module is imported and its TARGETS collected.

Verdicts, worst first: 'hang' (a call used 10 s of CPU, or ran 60 s), 'uncaught' (a call
raised anything but a GyroEkfError), 'silent' (returned without error but differs from the
oracle or holds values the project should have refused), 'clean' (a GyroEkfError: the
one-line message path), 'correct' (the result equals the oracle).
"""

from __future__ import annotations

from collections import Counter
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
import gzip
import hashlib
import importlib
import io
import json
import logging
import multiprocessing
from pathlib import Path
import pkgutil
import random
import re
import shutil
import tarfile
import tempfile
import time
from typing import Any

from fuzz.isolate import Outcome

KINDS = ('correct', 'clean', 'uncaught', 'hang', 'silent')
FAILING = ('uncaught', 'hang', 'silent')
_RANK = {kind: i for i, kind in enumerate(KINDS)}


@dataclass
class Case:
    """One input: the files to materialise in a fresh folder, and what was done to them.

    Attributes:
        files: relative path -> bytes.
        note: the mutation, in words (e.g. 'tinyz+crc: chunk 0: log_time of record 5 bit 61').
        meta: whatever the check needs besides the files (e.g. the unmutated trip's digest).
    """

    files: dict[str, bytes]
    note: str
    meta: dict[str, Any] = field(default_factory=dict)

    def write(self, folder: Path) -> None:
        for name, data in self.files.items():
            path = folder / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)

    def to_bytes(self) -> bytes:
        """Pack the files plus case.json (note, meta) as a deterministic gzip'd tar."""
        buffer = io.BytesIO()
        with tarfile.open(fileobj=buffer, mode='w', format=tarfile.USTAR_FORMAT) as tar:
            entries = dict(self.files)
            entries['case.json'] = json.dumps({'note': self.note, 'meta': self.meta},
                                              sort_keys=True, indent=1).encode()
            for name in sorted(entries):
                info = tarfile.TarInfo(name)
                info.size = len(entries[name])
                info.mode = 0o644
                tar.addfile(info, io.BytesIO(entries[name]))
        return gzip.compress(buffer.getvalue(), mtime=0)

    @classmethod
    def from_bytes(cls, blob: bytes) -> 'Case':
        files: dict[str, bytes] = {}
        with tarfile.open(fileobj=io.BytesIO(gzip.decompress(blob)), mode='r') as tar:
            for member in tar.getmembers():
                stream = tar.extractfile(member)
                if stream is not None:
                    files[member.name] = stream.read()
        info = json.loads(files.pop('case.json'))
        return cls(files, info['note'], info['meta'])


@dataclass
class Verdict:
    """The judgement of one input.

    Attributes:
        kind: one of KINDS (the worst over the calls).
        detail: why, in one line.
        errors: 'call: ExceptionType' for every uncaught call (and 'call: hang').
        where: innermost gyro_ekf frame of each uncaught exception.
    """

    kind: str = 'correct'
    detail: str = ''
    errors: list[str] = field(default_factory=list)
    where: list[str] = field(default_factory=list)

    def worse(self, kind: str, detail: str) -> None:
        """Raise the verdict to `kind` if that is worse than the current one."""
        if _RANK[kind] > _RANK[self.kind]:
            self.kind, self.detail = kind, detail

    def account(self, name: str, outcome: Outcome) -> None:
        """Fold in one call's outcome: crashes, hangs and foreign exceptions."""
        if outcome.status == 'hang':
            self.errors.append(f'{name}: hang')
            self.worse('hang', f'{name} ran past the time limit')
        elif outcome.status in ('raised', 'crash'):
            self.errors.append(f'{name}: {outcome.error}')
            self.where.append(outcome.where)
            self.worse('uncaught', f'{name}: {outcome.error}: {outcome.message} '
                                   f'[{outcome.where}]')
        elif outcome.status == 'clean':
            self.worse('clean', f'{name}: {outcome.message}')


class Target:
    """Base of a fuzz target; subclasses set `name` and implement the three methods."""

    name = ''
    share = 1.0
    """Relative number of inputs this target gets."""

    def setup(self, workdir: Path) -> None:
        """Make seed files under workdir (once, in the parent, before any input)."""

    def generate(self, rng: random.Random) -> Case:
        raise NotImplementedError

    def check(self, case: Case, folder: Path, run: bool) -> Verdict:
        """Judge the case, whose files are written in `folder`.

        `run` asks for the slow end-to-end check (gyro-ekf run) where the target has one.
        """
        raise NotImplementedError


def discover() -> dict[str, Target]:
    """Every target of every fuzz/targets_*.py module, by name."""
    import fuzz
    targets: dict[str, Target] = {}
    for module in sorted(m.name for m in pkgutil.iter_modules(fuzz.__path__)):
        if module.startswith('targets_'):
            for target in importlib.import_module(f'fuzz.{module}').TARGETS:
                targets[target.name] = target
    return targets


def case_rng(seed: int, target: str, index: int) -> random.Random:
    return random.Random(f'{seed}/{target}/{index}')


def judge(target: Target, case: Case, run: bool) -> Verdict:
    """Write the case into a fresh temporary folder and check it there."""
    folder = Path(tempfile.mkdtemp(prefix=f'fuzz-{target.name}-'))
    try:
        case.write(folder)
        return target.check(case, folder, run)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


_TARGETS: dict[str, Target] = {}


def _one(name: str, index: int, seed: int, run: bool) -> tuple[str, int, Verdict, str, bytes]:
    target = _TARGETS[name]
    try:
        case = target.generate(case_rng(seed, name, index))
        verdict = judge(target, case, run)
    except Exception as error:  # noqa: B902 - a bug of the fuzzer, reported as such
        # Not the project's fault, and not to be lost either: its own kind in the report.
        return name, index, Verdict('fuzzer', f'fuzzer error: {error!r}'), '', b''
    blob = case.to_bytes() if verdict.kind in FAILING else b''
    return name, index, verdict, case.note, blob


def _quiet() -> None:
    logging.disable(logging.CRITICAL)


def fuzz(names: list[str], seed: int, inputs: int | dict[str, int], budget_s: float,
         jobs: int, run_every: int, corpus: Path, report: Path, out: Any = print
         ) -> dict[str, Any]:
    """Fuzz the named targets; write the report and the failing inputs; return the report.

    Args:
        names: targets to fuzz (all when empty).
        seed: the seed every input is derived from (input i of target t: seed/t/i).
        inputs: inputs per unit of a target's share, or a count per target name.
        budget_s: stop handing out inputs after this long (the running ones finish).
        jobs: worker processes.
        run_every: every this many inputs (per target) also runs `gyro-ekf run`.
    """
    started = time.monotonic()
    targets = discover()
    unknown = sorted(set(names) - set(targets))
    if unknown:
        raise SystemExit(f'fuzz: unknown target {unknown[0]!r}; known: {sorted(targets)}')
    chosen = [targets[n] for n in (names or sorted(targets))]
    workdir = Path(tempfile.mkdtemp(prefix='fuzz-seeds-'))
    try:
        for target in chosen:
            target.setup(workdir / target.name)
        _TARGETS.clear()
        _TARGETS.update({t.name: t for t in chosen})
        out(f'fuzz: seed {seed}, seeds made in {time.monotonic() - started:.1f} s')
        counts = {t.name: inputs.get(t.name, 0) if isinstance(inputs, dict) else
                  max(1, round(inputs * t.share)) for t in chosen}
        # Round robin, so a budget that runs out leaves every target a fair share.
        order = [(t.name, i) for i in range(max(counts.values())) for t in chosen
                 if i < counts[t.name]]
        results = _dispatch(order, seed, jobs, run_every, started + budget_s)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    summary = _summarise(chosen, results, seed, time.monotonic() - started, budget_s)
    _save(results, corpus)
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text(json.dumps(summary, indent=1) + '\n', encoding='utf-8')
    _print(summary, out)
    return summary


def _dispatch(order: list[tuple[str, int]], seed: int, jobs: int, run_every: int,
              deadline: float) -> list[tuple[str, int, Verdict, str, bytes]]:
    results = []
    context = multiprocessing.get_context('fork')
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context,
                             initializer=_quiet) as pool:
        pending: set[Future] = set()
        queue = iter(order)
        exhausted = False
        while True:
            while not exhausted and len(pending) < 2 * jobs and time.monotonic() < deadline:
                item = next(queue, None)
                if item is None:
                    exhausted = True
                    break
                name, index = item
                pending.add(pool.submit(_one, name, index, seed, index % run_every == 0))
            if not pending:
                break
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            results.extend(f.result() for f in done)
    return sorted(results, key=lambda r: (r[0], r[1]))


def _summarise(targets: list[Target], results: list, seed: int, elapsed: float,
               budget_s: float) -> dict[str, Any]:
    per: dict[str, Any] = {}
    for target in targets:
        mine = [r for r in results if r[0] == target.name]
        kinds = Counter(r[2].kind for r in mine)
        errors = Counter(e for r in mine for e in r[2].errors)
        where = Counter(w for r in mine for w in r[2].where if w)
        failures = [{'index': r[1], 'kind': r[2].kind, 'note': r[3], 'detail': r[2].detail,
                     'sha1': hashlib.sha1(r[4]).hexdigest()}
                    for r in mine if r[2].kind in FAILING]
        per[target.name] = {
            'inputs': len(mine), **{k: kinds.get(k, 0) for k in KINDS},
            'fuzzer_errors': [r[2].detail for r in mine if r[2].kind == 'fuzzer'],
            'exceptions': dict(errors.most_common()), 'where': dict(where.most_common()),
            'failures': failures}
    total = {k: sum(p[k] for p in per.values()) for k in ('inputs', *KINDS)}
    total['fuzzer_errors'] = sum(len(p['fuzzer_errors']) for p in per.values())
    return {'seed': seed, 'elapsed_s': round(elapsed, 1), 'budget_s': budget_s,
            'total': total, 'targets': per}


def _save(results: list, corpus: Path) -> None:
    for name, _, verdict, note, blob in results:
        if verdict.kind in FAILING:
            folder = corpus / name
            folder.mkdir(parents=True, exist_ok=True)
            digest = hashlib.sha1(blob).hexdigest()
            (folder / f'{digest}.bin').write_bytes(blob)
            (folder / f'{digest}.txt').write_text(
                f'{verdict.kind}: {note}\n{verdict.detail}\n', encoding='utf-8')


def _kind_of(detail: str) -> str:
    """The class of a silently wrong detail: its first two parts, numbers left out."""
    head = ': '.join(detail.split(': ')[:2])
    head = re.sub(r'/tmp/\S+', 'BAG', head)
    return re.sub(r'[-+]?\d[\d.e+]*', '#', head)[:90]


def _print(summary: dict[str, Any], out: Any) -> None:
    out(f"{'target':<12} {'inputs':>6} {'correct':>7} {'clean':>6} {'uncaught':>8} "
        f"{'hang':>5} {'silent':>6}")
    for name, p in summary['targets'].items():
        out(f"{name:<12} {p['inputs']:>6} {p['correct']:>7} {p['clean']:>6} "
            f"{p['uncaught']:>8} {p['hang']:>5} {p['silent']:>6}")
    t = summary['total']
    out(f"{'total':<12} {t['inputs']:>6} {t['correct']:>7} {t['clean']:>6} "
        f"{t['uncaught']:>8} {t['hang']:>5} {t['silent']:>6}   ({summary['elapsed_s']} s)")
    for name, p in summary['targets'].items():
        if p['fuzzer_errors']:
            out(f"{name}: {len(p['fuzzer_errors'])} inputs not judged (a fuzzer bug): "
                f"{p['fuzzer_errors'][0]}")
        if p['exceptions']:
            out(f'{name}: ' + ', '.join(f'{k} x{v}' for k, v in p['exceptions'].items()))
        silent = Counter(_kind_of(f['detail']) for f in p['failures'] if f['kind'] == 'silent')
        if silent:
            out(f'{name}: silently wrong: ' + ', '.join(f'{k} x{v}' for k, v in
                                                        silent.most_common()))
