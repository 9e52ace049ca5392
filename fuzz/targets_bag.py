"""Bag targets: mutated MCAP files, chunks (CRC kept true), metadata.yaml and the sidecar.

Seeds are bags the project's simulator writes at start-up (a 1 s 'tiny' trip and a 10 s
'full' one, plain and zstd chunks, each also with every CRC filled in). The oracle of a
mutated bag is rosbags: `read_bag_rosbags` (test/io/rosbags_oracle.py) deserialises every
message with rosbags' own Reader. The fast reader is right when it returns what rosbags returns, or
exactly the unmutated trip (the mutation hit something neither uses), or when both refuse;
it is silently wrong when it returns a trip rosbags refuses or one that differs from
rosbags'. A returned trip with implausible values (see oracle.trip_problems) is run
through `gyro-ekf run`; if run accepts it (exit 0), that is silently wrong too.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
import random
import struct
import sys
from typing import Any

import yaml

from fuzz import isolate, mcap
from fuzz.harness import Case, Target, Verdict
from fuzz.oracle import summarise_trip, trip_problems

ORACLE_DIR = Path(__file__).resolve().parent.parent / 'test' / 'io'
"""Where the rosbags oracle lives (a test helper, not part of the package)."""

BAG = 'bag'
MCAP = f'{BAG}/{BAG}.mcap'
META = f'{BAG}/metadata.yaml'
SIDECAR = f'{BAG}.params.yaml'

HUGE = (2 ** 64 - 1, 2 ** 63 - 1, 2 ** 63, 2 ** 62, 2 ** 40, 2 ** 32, 2 ** 31, 10 ** 12)


def tiny_config() -> Any:
    """Return a 1 s trip at low rates: bags of a few tens of KB, quick to read and run."""
    from gyro_ekf.core.simulator import SimulationConfig
    return dataclasses.replace(
        SimulationConfig(), duration_s=1.0, static_s=0.5, imu_rate_hz=20.0,
        speed_rate_hz=10.0, lidar_rate_hz=4.0, truth_rate_hz=4.0, lidar_beams=19,
        lidar_increment_rad=0.17)


def write_seed_bag(folder: Path, tiny: bool, compress: bool, seed: int = 1,
                   storage: str = 'mcap') -> dict[str, bytes]:
    """Simulate a trip and write it as a bag under folder; return its files by case name."""
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io.bag_writer import write_trip_bag
    config = tiny_config() if tiny else dataclasses.replace(SimulationConfig(), duration_s=10.0)
    folder.mkdir(parents=True, exist_ok=True)
    write_trip_bag(simulate_trip(config, seed=seed), folder / BAG, compress=compress,
                   storage=storage)
    names = [f'{BAG}/{p.name}' for p in sorted((folder / BAG).iterdir())] + [SIDECAR]
    return {name: (folder / name).read_bytes() for name in names}


def data_file(files: dict[str, bytes]) -> str:
    """The bag's storage file among a case's files (.mcap or .db3)."""
    return next(n for n in sorted(files) if n.endswith(('.mcap', '.db3')))


# -- calls made in a child (isolate.call) --------------------------------------------


def read_fast(bag: Path) -> dict[str, Any]:
    from gyro_ekf.io.bag_reader import read_bag
    return summarise_trip(read_bag(bag).trip)


def read_reference(bag: Path) -> dict[str, Any]:
    if str(ORACLE_DIR) not in sys.path:
        sys.path.insert(0, str(ORACLE_DIR))
    from rosbags_oracle import read_bag_rosbags
    return summarise_trip(read_bag_rosbags(bag).trip)


def summary(bag: Path) -> int:
    from gyro_ekf.io.bag_info import bag_summary
    return bag_summary(bag).message_count


def sidecar(bag: Path) -> list[str]:
    """Problems of the values read_sidecar returns (non-finite, beyond the limits)."""
    from gyro_ekf.core import validation
    from gyro_ekf.io.sidecar import read_sidecar
    params = read_sidecar(bag)
    if params is None:
        return []
    out = []
    pose = [float(v) for v in params.initial_pose]
    problem = validation.coordinate_problem(pose[:2]) or validation.value_problem(
        pose[2], 1e3, 'rad')
    if problem:
        out.append(f'initial_pose: {problem}')
    for topic, (_, mount) in params.lidars.items():
        problem = validation.mount_problem(mount.x_m, mount.y_m, mount.yaw_rad)
        if problem:
            out.append(f'lidar.{topic}: {problem}')
    if not (0.0 <= params.static_duration_s < 1e6):
        out.append(f'static_duration_s = {params.static_duration_s}')
    return out


def run_cli(bag: Path, output: Path) -> int:
    from gyro_ekf.cli.main import main
    return main(['-q', 'run', str(bag), '-o', str(output), '--no-plots', '--no-bag',
                 '--no-progress'])


# -- the shared check ------------------------------------------------------------------


def check_bag(case: Case, folder: Path, run: bool) -> Verdict:
    """Judge a bag case: see the module docstring."""
    verdict = Verdict()
    bag = folder / BAG
    fast = isolate.call(read_fast, bag)
    verdict.account('read_bag', fast)
    reference = isolate.call(read_reference, bag)
    verdict.account('read_bag_rosbags', reference)
    verdict.account('bag_summary', isolate.call(summary, bag))
    side = isolate.call(sidecar, bag)
    verdict.account('read_sidecar', side)
    if fast.status != 'ok':
        return verdict
    got = fast.value
    if got['fields'] != case.meta.get('original'):
        if reference.status != 'ok':
            verdict.worse('silent', f'read_bag returned a trip; the rosbags path refuses it: '
                                    f'{reference.error}: {reference.message}')
            return verdict
        differ = sorted(k for k in set(got['fields']) | set(reference.value['fields'])
                        if got['fields'].get(k) != reference.value['fields'].get(k))
        if differ:
            verdict.worse('silent', f'read_bag differs from the rosbags path in {differ[:4]}')
            return verdict
    problems = got['problems'] + (side.value if side.status == 'ok' else [])
    if problems or run:
        result = isolate.call(run_cli, bag, folder / 'out')
        verdict.account('run', result)
        if result.status == 'ok' and result.value == 0 and problems:
            verdict.worse('silent', f'read_bag returned and run accepted: {problems[0]}')
        elif result.status == 'ok' and result.value not in (0, 1):
            verdict.worse('uncaught', f'run exited {result.value}')
    return verdict


class _BagTarget(Target):
    """Seeds shared by the bag targets; subclasses mutate them."""

    seeds: dict[str, dict[str, bytes]] = {}
    originals: dict[str, dict[str, str]] = {}

    def setup(self, workdir: Path) -> None:
        if _BagTarget.seeds:
            return
        for tiny in (True, False):
            for compress in (False, True):
                name = ('tiny' if tiny else 'full') + ('z' if compress else '')
                files = write_seed_bag(workdir / name, tiny, compress)
                for crc in (False, True):
                    variant = dict(files)
                    variant[MCAP] = mcap.with_crcs(files[MCAP], crc)
                    label = name + ('+crc' if crc else '')
                    _BagTarget.seeds[label] = variant
                    where = workdir / label
                    Case(variant, label).write(where)
                    outcome = isolate.call(read_fast, where / BAG, timeout_s=60)
                    if outcome.status != 'ok':
                        raise RuntimeError(f'seed {label} does not read: {outcome}')
                    _BagTarget.originals[label] = outcome.value['fields']
        # sqlite3 bags go through rosbags alone; blind byte mutations only.
        for compress in (False, True):
            label = 'tinysql' + ('z' if compress else '')
            files = write_seed_bag(workdir / label, True, compress, storage='sqlite3')
            _BagTarget.seeds[label] = files
            outcome = isolate.call(read_fast, workdir / label / BAG, timeout_s=60)
            if outcome.status != 'ok':
                raise RuntimeError(f'seed {label} does not read: {outcome}')
            _BagTarget.originals[label] = outcome.value['fields']

    def pick(self, rng: random.Random, sqlite: bool = False) -> tuple[str, dict[str, bytes]]:
        mcap_seeds = [k for k in sorted(self.seeds) if 'sql' not in k]
        tiny = [k for k in mcap_seeds if k.startswith('tiny')]
        full = [k for k in mcap_seeds if k.startswith('full')]
        sql = [k for k in sorted(self.seeds) if 'sql' in k]
        draw = rng.random()
        label = rng.choice(sql if sqlite and draw < 0.2 else tiny if draw < 0.84 else full)
        return label, dict(self.seeds[label])

    def case(self, label: str, files: dict[str, bytes], note: str) -> Case:
        return Case(files, f'{label}: {note}', {'original': self.originals[label]})

    def check(self, case: Case, folder: Path, run: bool) -> Verdict:
        return check_bag(case, folder, run)


def mutate_bytes(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """One blind mutation of a byte string: flips, truncation, ranges, huge lengths."""
    buf = bytearray(data)
    n = len(buf)
    kind = rng.choice(('byte', 'bit', 'bit', 'truncate', 'duplicate', 'remove', 'length',
                       'word'))
    if kind == 'byte':
        spots = [rng.randrange(n) for _ in range(rng.randint(1, 4))]
        for spot in spots:
            buf[spot] = rng.randrange(256)
        return bytes(buf), f'bytes at {spots} set at random'
    if kind == 'bit':
        spot, bit = rng.randrange(n), rng.randrange(8)
        buf[spot] ^= 1 << bit
        return bytes(buf), f'bit {bit} of byte {spot} flipped'
    if kind == 'truncate':
        cut = rng.randrange(n)
        return bytes(buf[:cut]), f'truncated to {cut} of {n} bytes'
    a = rng.randrange(n)
    b = min(n, a + rng.choice((1, 8, 9, 64, rng.randrange(1, 4096))))
    if kind == 'duplicate':
        at = rng.randrange(n)
        return bytes(buf[:at] + buf[a:b] + buf[at:]), f'bytes {a}:{b} copied to {at}'
    if kind == 'remove':
        return bytes(buf[:a] + buf[b:]), f'bytes {a}:{b} removed'
    if kind == 'length':
        # Where a record starts in an intact file; else anywhere.
        try:
            records = mcap.split(bytes(buf))
            record = rng.choice(records)
            at = record.offset + 1
        except (ValueError, struct.error, IndexError):
            at = rng.randrange(max(1, n - 8))
        value = rng.choice(HUGE)
        buf[at:at + 8] = struct.pack('<Q', value)[:len(buf[at:at + 8])]
        return bytes(buf), f'u64 at {at} (a record length) set to {value}'
    at = rng.randrange(max(1, n - 4)) & ~3
    value = rng.choice((0, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 1 << 24, 65535))
    buf[at:at + 4] = struct.pack('<I', value)[:len(buf[at:at + 4])]
    return bytes(buf), f'u32 at {at} set to {value:#x}'


class BagBytes(_BagTarget):
    """Blind mutations of the .mcap file (no CRC or offset fixed afterwards)."""

    name = 'bag'
    share = 1.0

    def generate(self, rng: random.Random) -> Case:
        label, files = self.pick(rng, sqlite=True)
        name = data_file(files)
        files[name], note = mutate_bytes(files[name], rng)
        return self.case(label, files, note)


class McapChunk(_BagTarget):
    """Mutations inside a chunk's records, with the file made consistent again.

    The chunk is recompressed and its CRC, sizes, times and the summary's offsets are made
    true, so the readers get past those checks and decode the damaged records.
    """

    name = 'mcap_chunk'
    share = 1.0

    def generate(self, rng: random.Random) -> Case:
        label, files = self.pick(rng)
        data = files[MCAP]
        chunks = mcap.chunks_of(data)
        index = rng.randrange(len(chunks))
        records, note = mutate_records(chunks[index].records, rng)
        retime = rng.random() < 0.9
        files[MCAP] = mcap.replace_chunk(data, index, records, retime=retime)
        return self.case(label, files, f'chunk {index}: {note}'
                         + ('' if retime else ' (chunk times left stale)'))


def mutate_records(records: bytes, rng: random.Random) -> tuple[bytes, str]:
    """One mutation of a chunk's records, aimed at messages."""
    parts = mcap.inner_records(records)
    messages = [p for p in parts if p[1] == mcap.MESSAGE]
    buf = bytearray(records)
    pos, _, size = rng.choice(messages)
    i = messages.index((pos, mcap.MESSAGE, size))
    kind = rng.choice(('payload_byte', 'payload_bit', 'payload_bit', 'payload_word',
                       'log_time', 'log_time', 'channel', 'length', 'duplicate', 'remove',
                       'truncate', 'blind', 'nested', 'unknown', 'publish_time'))
    payload = pos + 31
    end = pos + size
    if kind == 'payload_byte' and end > payload:
        at = rng.randrange(payload, end)
        buf[at] = rng.randrange(256)
        return bytes(buf), f'message {i}: payload byte {at - payload} set at random'
    if kind == 'payload_bit' and end > payload:
        at, bit = rng.randrange(payload, end), rng.randrange(8)
        buf[at] ^= 1 << bit
        return bytes(buf), f'message {i}: bit {bit} of payload byte {at - payload} flipped'
    if kind == 'payload_word' and end - payload >= 8:
        at = payload + (rng.randrange(end - payload - 4) & ~3)
        value = rng.choice((0, 1, 0xFFFFFFFF, 0x7FFFFFFF, 1 << 20, 1000))
        buf[at:at + 4] = struct.pack('<I', value)
        return bytes(buf), f'message {i}: u32 at payload byte {at - payload} set to {value}'
    if kind in ('log_time', 'publish_time'):
        at = pos + (15 if kind == 'log_time' else 23)
        (old,) = struct.unpack_from('<Q', buf, at)
        how = rng.choice(('bit', 'bit', 'zero', 'max', 'back', 'ahead'))
        if how == 'bit':
            bit = rng.randrange(64)
            new, what = old ^ (1 << bit), f'bit {bit} flipped'
        elif how == 'zero':
            new, what = 0, 'set to 0'
        elif how == 'max':
            new = rng.choice((2 ** 64 - 1, 2 ** 63 - 1, 2 ** 63))
            what = f'set to {new}'
        elif how == 'back':
            new, what = max(0, old - 10 * 10 ** 9), 'moved 10 s back'
        else:
            new, what = old + 300_000 * 10 ** 9, 'moved 300000 s ahead'
        struct.pack_into('<Q', buf, at, new % 2 ** 64)
        return bytes(buf), f'message {i}: {kind} {what}'
    if kind == 'channel':
        value = rng.choice((0, 1, 2, 3, 4, 5, 6, 7, 99, 65535))
        struct.pack_into('<H', buf, pos + 9, value)
        return bytes(buf), f'message {i}: channel id set to {value}'
    if kind == 'length':
        value = rng.choice(HUGE + (size - 9 + 1, size - 9 - 1, 0, 21))
        struct.pack_into('<Q', buf, pos + 1, value)
        return bytes(buf), f'message {i}: record length set to {value}'
    if kind == 'duplicate':
        return bytes(buf[:end] + buf[pos:end] + buf[end:]), f'message {i} duplicated'
    if kind == 'remove':
        return bytes(buf[:pos] + buf[end:]), f'message {i} removed'
    if kind == 'truncate':
        cut = rng.randrange(len(buf))
        return bytes(buf[:cut]), f'records truncated to {cut} of {len(buf)} bytes'
    if kind == 'nested':
        inner = struct.pack('<QQQI', 0, 0, 0, 0) + struct.pack('<I', 0) + struct.pack('<Q', 0)
        record = bytes([mcap.CHUNK]) + struct.pack('<Q', len(inner)) + inner
        return bytes(buf[:pos] + record + buf[pos:]), f'a chunk record before message {i}'
    if kind == 'unknown':
        record = bytes([0x80]) + struct.pack('<Q', 3) + b'abc'
        return bytes(buf[:pos] + record + buf[pos:]), f'an unknown record before message {i}'
    mutated, note = mutate_bytes(bytes(buf), rng)
    return mutated, f'records: {note}'


class BagMeta(_BagTarget):
    """Mutations of metadata.yaml and of the params sidecar beside the bag."""

    name = 'bag_meta'
    share = 0.6

    def generate(self, rng: random.Random) -> Case:
        label, files = self.pick(rng, sqlite=True)
        if rng.random() < 0.5:
            files[META], note = mutate_metadata(files[META], rng)
        else:
            files[SIDECAR], note = mutate_sidecar(files[SIDECAR], rng)
        return self.case(label, files, note)


def mutate_metadata(text: bytes, rng: random.Random) -> tuple[bytes, str]:
    tree = yaml.safe_load(text)
    info = tree['rosbag2_bagfile_information']
    topics = info['topics_with_message_count']
    kind = rng.choice(('count', 'count', 'type', 'type', 'topic', 'drop_topic', 'storage',
                       'files', 'compression', 'times', 'total', 'text'))
    if kind == 'count':
        entry = rng.choice(topics)
        value = rng.choice((0, -1, 10 ** 12, 2 ** 63 - 1, 2 ** 64, entry['message_count'] + 1,
                            max(0, entry['message_count'] - 1), 'many', None, 1.5))
        entry['message_count'] = value
        note = f"count of {entry['topic_metadata']['name']} set to {value!r}"
    elif kind == 'type':
        entry = rng.choice(topics)
        value = rng.choice(('sensor_msgs/msg/Imu', 'nav_msgs/msg/Odometry',
                            'sensor_msgs/msg/LaserScan', 'geometry_msgs/msg/PoseArray',
                            'std_msgs/msg/String', 'no/such/Type', ''))
        entry['topic_metadata']['type'] = value
        note = f"type of {entry['topic_metadata']['name']} set to {value!r}"
    elif kind == 'topic':
        entry = rng.choice(topics)
        value = rng.choice(('/imu', '/odom', '/scan', '/scan2', 'imu', ''))
        note = f"topic {entry['topic_metadata']['name']} renamed {value!r}"
        entry['topic_metadata']['name'] = value
    elif kind == 'drop_topic':
        entry = topics.pop(rng.randrange(len(topics)))
        note = f"topic {entry['topic_metadata']['name']} left out"
    elif kind == 'storage':
        info['storage_identifier'] = value = rng.choice(('sqlite3', 'foo', '', None))
        note = f'storage_identifier set to {value!r}'
    elif kind == 'files':
        info['relative_file_paths'] = value = rng.choice(
            ([], ['nothing.mcap'], ['bag.mcap', 'bag.mcap'], ['../bag/bag.mcap'], 'bag.mcap'))
        note = f'relative_file_paths set to {value!r}'
    elif kind == 'compression':
        info['compression_mode'] = rng.choice(('file', 'message'))
        info['compression_format'] = rng.choice(('zstd', 'lz4', ''))
        note = f"compression {info['compression_mode']}/{info['compression_format']}"
    elif kind == 'times':
        value = rng.choice((-1, 0, 2 ** 63, 10 ** 30, 'now'))
        info['starting_time']['nanoseconds_since_epoch'] = value
        info['duration']['nanoseconds'] = rng.choice((-5, 0, value))
        note = f'starting_time set to {value!r}'
    elif kind == 'total':
        info['message_count'] = value = rng.choice((0, -1, 10 ** 12))
        note = f'message_count set to {value}'
    else:
        data, note = mutate_bytes(text, rng)
        return data, f'metadata text: {note}'
    return yaml.safe_dump(tree, sort_keys=False).encode(), f'metadata: {note}'


def _leaves(tree: Any, prefix: tuple = ()) -> list[tuple]:
    if isinstance(tree, dict):
        return [p for k, v in tree.items() for p in _leaves(v, prefix + (k,))] or [prefix]
    if isinstance(tree, list):
        return [prefix] + [p for i, v in enumerate(tree) for p in _leaves(v, prefix + (i,))]
    return [prefix]


def _set(tree: Any, path: tuple, value: Any) -> None:
    for key in path[:-1]:
        tree = tree[key]
    tree[path[-1]] = value


def _delete(tree: Any, path: tuple) -> None:
    for key in path[:-1]:
        tree = tree[key]
    del tree[path[-1]]


BAD_VALUES = (float('nan'), float('inf'), float('-inf'), 1e308, -1e308, 1e30, -1.0, 0,
              10 ** 30, 'abc', None, True, [], [1.0, 2.0], {'a': 1})


def mutate_yaml_values(text: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Set a leaf of a YAML document to a bad value, delete it, or damage the text."""
    tree = yaml.safe_load(text)
    leaves = [p for p in _leaves(tree) if p]
    path = rng.choice(leaves)
    kind = rng.random()
    if kind < 0.75:
        value = rng.choice(BAD_VALUES)
        _set(tree, path, value)
        note = f'{".".join(map(str, path))} set to {value!r}'
    elif kind < 0.9:
        _delete(tree, path)
        note = f'{".".join(map(str, path))} deleted'
    else:
        data, note = mutate_bytes(text, rng)
        return data, f'text: {note}'
    return yaml.safe_dump(tree, sort_keys=False).encode(), note


def mutate_sidecar(text: bytes, rng: random.Random) -> tuple[bytes, str]:
    data, note = mutate_yaml_values(text, rng)
    return data, f'sidecar: {note}'


TARGETS = [BagBytes(), McapChunk(), BagMeta()]
__all__ = ['TARGETS', 'check_bag', 'trip_problems', 'write_seed_bag']
