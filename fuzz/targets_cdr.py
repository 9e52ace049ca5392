"""CDR target: mutated message payloads through `fast_cdr.decode_columns` vs rosbags.

Seeds are real payloads (Imu, Odometry, LaserScan, PoseWithCovarianceStamped) taken from a
bag the simulator writes. A batch of one to five messages of one type, one of them mutated,
goes through the fast decoder and, message by message, through rosbags' deserializer. The
fast decoder is right when it returns rosbags' values for every field, or when it raises
its own CdrDecodeError (which bag_sinks turns into a BagError); it is silently wrong when
it returns values rosbags would not (rosbags refuses the message, or its values differ).
"""

from __future__ import annotations

from pathlib import Path
import random
import struct
from typing import Any

import numpy as np

from fuzz import isolate
from fuzz.harness import Case, Target, Verdict
from fuzz.targets_bag import BAG, write_seed_bag

TYPES = ('sensor_msgs/msg/Imu', 'nav_msgs/msg/Odometry', 'sensor_msgs/msg/LaserScan',
         'geometry_msgs/msg/PoseWithCovarianceStamped')


def numeric_fields(msgtype: str) -> list[str]:
    from gyro_ekf.io.fast_cdr import LAYOUTS
    return [f.name for f in LAYOUTS[msgtype] if f.kind != 'string']


def fast_values(datas: list[bytes], msgtype: str) -> dict[str, Any]:
    from gyro_ekf.io import fast_cdr, messages
    columns = fast_cdr.decode_columns(datas, msgtype, numeric_fields(msgtype),
                                      messages.TYPESTORE)
    return {'values': {k: np.asarray(v, dtype=np.float64) for k, v in columns.values.items()},
            'counts': {k: np.asarray(v) for k, v in columns.counts.items()}}


def _field(message: Any, name: str) -> np.ndarray:
    value = message
    for part in name.split('.'):
        value = getattr(value, part)
    if isinstance(value, np.ndarray):
        return value.astype(np.float64)
    if hasattr(value, 'x'):
        parts = [value.x, value.y, value.z] + ([value.w] if hasattr(value, 'w') else [])
        return np.array(parts, dtype=np.float64)
    return np.array([float(value)])


def rosbags_values(datas: list[bytes], msgtype: str) -> dict[str, Any]:
    from gyro_ekf.io import messages
    messages_ = [messages.TYPESTORE.deserialize_cdr(d, msgtype) for d in datas]
    rows = {name: [_field(m, name) for m in messages_] for name in numeric_fields(msgtype)}
    return {'rows': rows}


def compare(fast: dict[str, Any], reference: dict[str, Any]) -> list[str]:
    """Fields whose fast values differ from rosbags' (NaN equal to NaN)."""
    differ = []
    for name, rows in reference['rows'].items():
        if name in fast['counts']:
            counts = fast['counts'][name]
            if [len(r) for r in rows] != counts.tolist():
                differ.append(f'{name} (count)')
                continue
            if name not in fast['values']:
                continue  # widths vary: the decoder leaves the values out, as documented
        got = fast['values'].get(name)
        want = np.array([r for r in rows]).reshape(len(rows), -1) if rows else None
        if got is None or want is None:
            continue
        if got.reshape(len(rows), -1).shape != want.shape or not np.array_equal(
                got.reshape(len(rows), -1), want, equal_nan=True):
            differ.append(name)
    return differ


class Cdr(Target):
    name = 'cdr'
    share = 1.0
    seeds: dict[str, list[bytes]] = {}

    def setup(self, workdir: Path) -> None:
        from rosbags.rosbag2 import Reader
        write_seed_bag(workdir, tiny=True, compress=False, seed=2)
        with Reader(workdir / BAG) as reader:
            for connection, _, data in reader.messages():
                if connection.msgtype in TYPES:
                    self.seeds.setdefault(connection.msgtype, [])
                    if len(self.seeds[connection.msgtype]) < 4:
                        self.seeds[connection.msgtype].append(bytes(data))

    def generate(self, rng: random.Random) -> Case:
        msgtype = rng.choice(sorted(self.seeds))
        pool = self.seeds[msgtype]
        batch = [rng.choice(pool) for _ in range(rng.randint(1, 5))]
        which = rng.randrange(len(batch))
        batch[which], note = mutate_payload(batch[which], rng)
        files = {f'{i}.cdr': data for i, data in enumerate(batch)}
        return Case(files, f'{msgtype}: message {which} of {len(batch)}: {note}',
                    {'msgtype': msgtype, 'count': len(batch)})

    def check(self, case: Case, folder: Path, run: bool) -> Verdict:
        msgtype = case.meta['msgtype']
        datas = [case.files[f'{i}.cdr'] for i in range(case.meta['count'])]
        verdict = Verdict()
        fast = isolate.call(fast_values, datas, msgtype)
        reference = isolate.call(rosbags_values, datas, msgtype)
        if fast.status == 'raised' and fast.error == 'gyro_ekf.io.fast_cdr.CdrDecodeError':
            fast.status = 'clean'  # the decoder's own error; bag_sinks makes it a BagError
        verdict.account('decode_columns', fast)
        if reference.status in ('hang', 'crash'):
            verdict.account('rosbags deserialize_cdr', reference)
        if fast.status != 'ok':
            return verdict
        if reference.status != 'ok':
            verdict.worse('silent', f'decode_columns returned values; rosbags refuses: '
                                    f'{reference.error}: {reference.message}')
            return verdict
        differ = compare(fast.value, reference.value)
        if differ:
            verdict.worse('silent', f'decode_columns differs from rosbags in {differ[:4]}')
        return verdict


def mutate_payload(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    buf = bytearray(data)
    n = len(buf)
    kind = rng.choice(('byte', 'bit', 'bit', 'word', 'word', 'truncate', 'extend', 'header',
                       'big_endian'))
    if kind == 'byte':
        at = rng.randrange(n)
        buf[at] = rng.randrange(256)
        return bytes(buf), f'byte {at} set at random'
    if kind == 'bit':
        at, bit = rng.randrange(n), rng.randrange(8)
        buf[at] ^= 1 << bit
        return bytes(buf), f'bit {bit} of byte {at} flipped'
    if kind == 'word':
        at = 4 + (rng.randrange(max(1, n - 8)) & ~3)
        value = rng.choice((0, 1, 3, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 1 << 20, 361, 362))
        buf[at:at + 4] = struct.pack('<I', value)
        return bytes(buf[:n]), f'u32 at {at} set to {value}'
    if kind == 'truncate':
        cut = rng.randrange(n)
        return bytes(buf[:cut]), f'truncated to {cut} of {n} bytes'
    if kind == 'extend':
        extra = bytes(rng.randrange(256) for _ in range(rng.choice((1, 2, 3, 4, 8, 64))))
        return bytes(buf) + extra, f'{len(extra)} bytes appended'
    if kind == 'header':
        buf[:4] = bytes(rng.randrange(256) for _ in range(4))
        return bytes(buf), f'encapsulation header set to {bytes(buf[:4]).hex()}'
    # A big-endian header on little-endian data: every number reads byte-swapped.
    buf[:2] = b'\x00\x00'
    return bytes(buf), 'encapsulation header says big-endian'


TARGETS = [Cdr()]
