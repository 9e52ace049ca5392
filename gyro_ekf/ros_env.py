"""A private ROS 2 environment for the project's own processes (no ROS import).

The one home of the ROS environment and of child-process handling: every process the
project starts for a test, a benchmark, `make demo` or `make docs` that creates ROS nodes
runs with loopback-only discovery (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``), its own log
directory and an explicit DDS domain (`child_env`), and is started and stopped the same way
(`ChildProcesses`: output to a log file each, SIGINT, then a kill after a timeout). Tests,
benchmarks and `make docs` claim a domain that no other run on this machine uses at the same
time (`claim_domain`); `make demo` uses the fixed, documented 42 unless told otherwise.

A domain is claimed with an exclusive ``flock`` on ``/tmp/gyro_ekf-ros-domain-<N>.lock``:
the kernel drops the lock when the holder exits, even when it is killed, so no stale claim
outlives a crashed run. A domain whose Fast DDS ports are bound (a process started by hand,
or a node of a finished run still shutting down) is passed over as well.

A private network namespace per run (``unshare -rn``) would not be enough on its own: Fast
DDS' shared-memory transport names its segments after the port numbers in ``/dev/shm``,
which a network namespace does not separate.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
import errno
import fcntl
import itertools
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

# Fast DDS maps domains 0-232 onto UDP ports; 0 is every ROS install's default and 42 the
# domain of `make demo` (Makefile), so neither is handed out.
DOMAIN_IDS = tuple(d for d in range(1, 233) if d != 42)
# Fixed, not tempfile.gettempdir(): every process on the machine must see the same locks,
# whatever its TMPDIR.
LOCK_DIR = Path('/tmp')
LOCK_PREFIX = 'gyro_ekf-ros-domain-'

# RTPS well-known ports (DDSI-RTPS 9.6.1.1, Fast DDS defaults): PB + DG * domain, and each
# domain owns the DG ports above that (participants are numbered within the block).
_PORT_BASE = 7400
_DOMAIN_GAIN = 250
_PROC_NET = ('/proc/net/udp', '/proc/net/udp6')

# Each process walks the domains from its own starting point onwards, so a domain it has
# just released (whose nodes may still be exiting) is the last it comes back to.
_order = itertools.count(os.getpid())


class DomainUnavailableError(RuntimeError):
    """Every domain is claimed by another run or has its ports in use."""


class DomainLease:
    """An exclusive claim on one DDS domain, held until release() or process exit."""

    def __init__(self, domain_id: int, fd: int):
        self.domain_id = domain_id
        self._fd: int | None = fd

    def release(self) -> None:
        """Drop the claim (closing the lock file releases the flock); idempotent."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> DomainLease:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()


def lock_path(domain_id: int) -> Path:
    """Return the lock file of a domain."""
    return LOCK_DIR / f'{LOCK_PREFIX}{domain_id}.lock'


def bound_udp_ports() -> set[int]:
    """Local UDP ports bound on this machine (network namespace), from /proc/net."""
    ports: set[int] = set()
    for table in _PROC_NET:
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            local = line.split()[1]  # "0100007F:1CE8": address:port in hex
            ports.add(int(local.rsplit(':', 1)[1], 16))
    return ports


def domain_ports_in_use(domain_id: int, bound: set[int] | None = None) -> bool:
    """Whether any process here has a DDS port of this domain bound."""
    first = _PORT_BASE + _DOMAIN_GAIN * domain_id
    ports = bound_udp_ports() if bound is None else bound
    return any(first <= port < first + _DOMAIN_GAIN for port in ports)


def try_claim(domain_id: int) -> DomainLease | None:
    """Claim this domain if no other holder has it (ports are not looked at); else None."""
    path = lock_path(domain_id)
    try:
        # Read-only is enough for flock and works on a lock file another user created.
        fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o666)
    except PermissionError:
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as error:
        os.close(fd)
        if error.errno in (errno.EWOULDBLOCK, errno.EACCES):
            return None
        raise
    return DomainLease(domain_id, fd)


def claim_domain() -> DomainLease:
    """Claim a DDS domain no other run on this machine holds or has ports bound in.

    Raises:
        DomainUnavailableError: all of DOMAIN_IDS are taken.
    """
    bound = bound_udp_ports()
    start = next(_order)
    for step in range(len(DOMAIN_IDS)):
        domain = DOMAIN_IDS[(start + step) % len(DOMAIN_IDS)]
        if domain_ports_in_use(domain, bound):
            continue
        lease = try_claim(domain)
        if lease is None:
            continue
        # Ports could have been bound between the scan and the lock by a process that
        # takes no lock; look again now that the claim is ours.
        if domain_ports_in_use(domain):
            lease.release()
            continue
        for _ in range(step):  # the next claim of this process starts after this one
            next(_order)
        return lease
    raise DomainUnavailableError(
        f'no free ROS domain among {len(DOMAIN_IDS)}: every {lock_path(0).parent}/'
        f'{LOCK_PREFIX}<N>.lock is held or the domain has DDS ports bound')


def ros_env_values(domain_id: int, log_dir: Path | str) -> dict[str, str]:
    """Return the environment variables of a private, loopback-only ROS process."""
    return {
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'ROS_DOMAIN_ID': str(domain_id),
        'ROS_LOG_DIR': str(log_dir),
        'PYTHONUNBUFFERED': '1',
    }


def child_env(domain_id: int, log_dir: Path | str, base: Mapping[str, str] | None = None
              ) -> dict[str, str]:
    """Return the whole environment of a child: base (os.environ) plus ros_env_values.

    The folder holding the gyro_ekf package goes first on PYTHONPATH, so `python -m
    gyro_ekf...` in the child runs this copy of the package, installed or not.
    """
    env = dict(os.environ if base is None else base)
    env.update(ros_env_values(domain_id, log_dir))
    package_root = str(Path(__file__).resolve().parents[1])
    env['PYTHONPATH'] = os.pathsep.join(p for p in (package_root, env.get('PYTHONPATH')) if p)
    return env


class ChildProcesses:
    """Children run as `python -m MODULE ...`, each with its output in <log_dir>/<name>.log.

    `stop_all` sends SIGINT to every child still running (the nodes shut down cleanly on
    it), waits up to a timeout for all of them together, and kills what has not stopped.
    """

    def __init__(self, env: Mapping[str, str], log_dir: Path | str,
                 cwd: Path | str | None = None):
        self.env = dict(env)
        self.log_dir = Path(log_dir)
        self.cwd = cwd
        self.started: list[tuple[str, subprocess.Popen]] = []

    def start(self, name: str, *args: str) -> subprocess.Popen:
        """Start `python -m <args...>` with its output in <log_dir>/<name>.log."""
        with self.log_path(name).open('w') as out:
            child = subprocess.Popen([sys.executable, '-m', *args], env=self.env, stdout=out,
                                     stderr=subprocess.STDOUT, cwd=self.cwd)
        self.started.append((name, child))
        return child

    def log_path(self, name: str) -> Path:
        """Return the log file of a child."""
        return self.log_dir / f'{name}.log'

    def log(self, name: str) -> str:
        """Return the output of a started child so far."""
        return self.log_path(name).read_text()

    def stop_all(self, timeout_s: float = 10.0,
                 on_kill: Callable[[str], None] | None = None) -> None:
        """SIGINT every child still running, wait, kill what does not stop (on_kill(name))."""
        for _, child in self.started:
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for name, child in self.started:
            try:
                child.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                if on_kill is not None:
                    on_kill(name)
                child.kill()
                child.wait()
