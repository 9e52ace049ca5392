"""Run one call in a forked child with a hard time limit and a memory ceiling.

A reader that loops forever or asks for terabytes must not take the fuzzer with it: the
child is killed once it has used `timeout_s` of CPU time (a hang) and its address space is
capped, so a runaway allocation fails as MemoryError inside the child instead of swapping
the machine. CPU time, not wall time: on a busy machine (the test suite's slice beside a
second copy of the suite and a benchmark) a child waiting for a core took more than 10 s of
wall time to read a tiny bag and was called a hang. A child that waits without using the
CPU (blocked) is killed after `WALL_FACTOR` times `timeout_s` of wall time.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
import pickle
import resource
import select
import signal
import sys
import time
import traceback
from typing import Any, Callable

from gyro_ekf.errors import GyroEkfError

TIMEOUT_S = 10.0
MEMORY_HEADROOM_BYTES = 3 << 30
"""Address space a child may add to what it inherited."""
WALL_FACTOR = 6.0
"""A child is killed after this many times its CPU limit of wall time, CPU used or not."""
_POLL_S = 0.25
_TICKS_PER_S = os.sysconf('SC_CLK_TCK')


def _cpu_seconds(pid: int) -> float | None:
    """CPU time (user + system) a live child has used, s; None where /proc does not say."""
    try:
        with open(f'/proc/{pid}/stat', 'rb') as stat:
            # Fields after the command name (which may hold spaces, in parentheses).
            fields = stat.read().rsplit(b')', 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / _TICKS_PER_S


@dataclass
class Outcome:
    """What a call did.

    Attributes:
        status: 'ok' (returned), 'clean' (raised a GyroEkfError), 'raised' (any other
            exception), 'hang' (killed after the time limit) or 'crash' (died by a signal).
        value: the return value when 'ok'.
        error: exception type name ('MemoryError', 'zstd.ZstdError', 'signal 11', ...).
        message: the exception text, first line, shortened.
        where: innermost gyro_ekf frame of the traceback, 'path:line in function'.
    """

    status: str
    value: Any = None
    error: str = ''
    message: str = ''
    where: str = ''
    seconds: float = 0.0


def _type_name(error: BaseException) -> str:
    kind = type(error)
    module = kind.__module__
    return kind.__qualname__ if module in ('builtins', '') else f'{module}.{kind.__qualname__}'


def _where(error: BaseException) -> str:
    """'gyro_ekf/...:line in f', plus the innermost frame when that lies outside gyro_ekf."""
    frames = traceback.extract_tb(error.__traceback__)
    if not frames:
        return ''

    def show(frame: traceback.FrameSummary) -> str:
        name = frame.filename
        for marker in ('/gyro_ekf/', '/site-packages/', '/fuzz/'):
            cut = name.rfind(marker)
            if cut >= 0:
                name = name[cut + 1:].replace('site-packages/', '')
                break
        return f'{name}:{frame.lineno} in {frame.name}'

    mine = [f for f in frames if '/gyro_ekf/' in f.filename]
    text = show(mine[-1]) if mine else show(frames[-1])
    if mine and mine[-1] is not frames[-1]:
        text += f' -> {show(frames[-1])}'
    return text


def _vm_bytes() -> int:
    try:
        with open('/proc/self/statm', encoding='ascii') as stream:
            return int(stream.read().split()[0]) * os.sysconf('SC_PAGE_SIZE')
    except (OSError, ValueError):
        return 0


def call(function: Callable[..., Any], *args: Any, timeout_s: float = TIMEOUT_S) -> Outcome:
    """Run function(*args) in a forked child; see Outcome for the possible results."""
    read_end, write_end = os.pipe()
    started = time.monotonic()
    pid = os.fork()
    if pid == 0:  # the child
        os.close(read_end)
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            # Also the Python-level streams: pytest replaces them with its own capture.
            sys.stdout = sys.stderr = open(os.devnull, 'w', encoding='utf-8')
            limit = _vm_bytes() + MEMORY_HEADROOM_BYTES
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
            try:
                result: tuple = ('ok', function(*args))
            except GyroEkfError as error:
                result = ('clean', _type_name(error), _first_line(error), _where(error))
            except BaseException as error:  # noqa: B902 - classifying every failure is the point
                result = ('raised', _type_name(error), _first_line(error), _where(error))
            try:
                payload = pickle.dumps(result)
            except Exception as error:  # noqa: B902
                payload = pickle.dumps(('raised', 'pickle:' + _type_name(error), str(error), ''))
            view = memoryview(payload)
            while view:
                view = view[os.write(write_end, view):]
        finally:
            os._exit(0)
    os.close(write_end)
    chunks = []
    deadline = started + WALL_FACTOR * timeout_s
    hung = False
    try:
        while True:
            now = time.monotonic()
            used = _cpu_seconds(pid) if now - started > timeout_s else 0.0
            if now >= deadline or (used if used is not None else now - started) > timeout_s:
                hung = True
                break
            ready, _, _ = select.select([read_end], [], [], min(_POLL_S, deadline - now))
            if not ready:
                continue
            data = os.read(read_end, 1 << 20)
            if not data:
                break
            chunks.append(data)
    finally:
        os.close(read_end)
        if hung:
            os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
    seconds = time.monotonic() - started
    if hung:
        return Outcome('hang', error='hang', message=f'killed after {timeout_s:g} s of CPU '
                       f'(or {WALL_FACTOR * timeout_s:g} s of wall time)', seconds=seconds)
    if not chunks:
        signal_number = os.WTERMSIG(status) if os.WIFSIGNALED(status) else 0
        return Outcome('crash', error=f'signal {signal_number}',
                       message=f'child died (status {status})', seconds=seconds)
    result = pickle.loads(b''.join(chunks))
    if result[0] == 'ok':
        return Outcome('ok', value=result[1], seconds=seconds)
    return Outcome(result[0], error=result[1], message=result[2], where=result[3],
                   seconds=seconds)


def _first_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return (text[0] if text else '')[:300]
