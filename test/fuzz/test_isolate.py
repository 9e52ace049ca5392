"""isolate.call: a hang is a child that used its CPU limit, or waited 6 times as long.

A child merely waiting for a core on a busy machine is no hang (the fuzz slice of the test
suite had called two tiny bags' reads hangs, beside a second copy of the suite): the limit
is the child's own CPU time, and wall time only bounds a child that is blocked.
"""

import time

from fuzz import isolate


def _spin() -> None:
    while True:
        pass


def _blocked() -> None:
    time.sleep(3600)


def test_a_child_that_keeps_the_cpu_busy_is_a_hang():
    outcome = isolate.call(_spin, timeout_s=0.5)
    assert outcome.status == 'hang'
    assert 'of CPU' in outcome.message


def test_a_blocked_child_is_a_hang_after_its_wall_time():
    outcome = isolate.call(_blocked, timeout_s=0.2)
    assert outcome.status == 'hang'
    # Killed for its wall time: it used next to no CPU.
    assert outcome.seconds >= isolate.WALL_FACTOR * 0.2


def test_a_call_that_returns_is_its_value():
    outcome = isolate.call(sum, [1, 2, 3])
    assert (outcome.status, outcome.value) == ('ok', 6)
