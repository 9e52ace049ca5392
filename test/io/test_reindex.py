"""`gyro-ekf reindex`: a bag whose recorder was killed is readable again, a fine bag untouched."""

from __future__ import annotations

import functools
import shutil

from mcap.reader import make_reader
from mcap.stream_reader import breakup_chunk, StreamReader
from mcap_layout import chunks, crc_writer, mcap_of, messages_in_chunk
import pytest
from rosbags.rosbag2 import Reader
from synthetic_logs import make_trip

from gyro_ekf.cli.main import main
from gyro_ekf.io.bag_info import bag_summary
from gyro_ekf.io.bag_reader import read_bag
from gyro_ekf.io.bag_writer import write_trip_bag
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.reindex import needs_reindex, reindex

__all__ = ['crc_writer']


@functools.lru_cache(maxsize=1)
def trip():
    """A synthetic trip of a few 1 MiB chunks."""
    return make_trip(n=6000, m=600)


@pytest.fixture(scope='module')
def original(tmp_path_factory):
    """A complete bag to cut copies of (never modified)."""
    return write_trip_bag(trip(), tmp_path_factory.mktemp('orig') / 'rec')


def copy_of(original, tmp_path):
    bag = tmp_path / 'rec'
    shutil.copytree(original, bag)
    return bag


def messages_of_complete_chunks(mcap, cut: int) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of the chunks wholly before cut, by the mcap package."""
    with open(mcap, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    complete = sum(c.chunk_start_offset + c.chunk_length <= cut
                   for c in summary.chunk_indexes)
    topics = {i: c.topic for i, c in summary.channels.items()}
    found = []
    with open(mcap, 'rb') as stream:
        chunk_records = (r for r in StreamReader(stream, emit_chunks=True).records
                         if type(r).__name__ == 'Chunk')
        for _, chunk in zip(range(complete), chunk_records):
            found += [(topics[r.channel_id], r.log_time, r.data) for r in breakup_chunk(chunk)
                      if type(r).__name__ == 'Message']
    return sorted(found)


def by_rosbags(bag) -> list[tuple[str, int, bytes]]:
    with Reader(bag) as reader:
        return sorted((c.topic, t, bytes(d)) for c, t, d in reader.messages())


@pytest.mark.parametrize('where', [0.3, 0.5, 0.9, 'after a chunk', 'in the summary'])
def test_a_bag_cut_short_without_metadata_is_reindexed(original, tmp_path, capsys, where):
    bag = copy_of(original, tmp_path)
    mcap = mcap_of(bag)
    data = mcap.read_bytes()
    spans = chunks(data)
    assert len(spans) >= 3
    if where == 'after a chunk':
        cut = spans[1].end
    elif where == 'in the summary':
        cut = len(data) - 100
    else:
        cut = int(len(data) * where)
    mcap.write_bytes(data[:cut])
    (bag / 'metadata.yaml').unlink()
    assert needs_reindex(bag) == 'the bag has no metadata.yaml'
    assert main(['info', str(bag)]) == 1
    assert f'run `gyro-ekf reindex {bag}`' in capsys.readouterr().err
    with pytest.raises(BagError, match='reindex'):
        read_bag(bag)

    assert main(['reindex', str(bag)]) == 0
    assert 'wrote a new .mcap and metadata.yaml' in capsys.readouterr().out
    assert needs_reindex(bag) is None
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'rec.mcap']
    want = messages_of_complete_chunks(original / 'rec.mcap', cut)
    assert len(want) > 1000
    assert by_rosbags(bag) == want
    assert main(['info', str(bag)]) == 0
    assert bag_summary(bag).message_count == len(want)
    back = read_bag(bag).trip
    assert len(back.imu.stamp_s) == sum(topic == '/imu' for topic, _, _ in want)
    # Reindexing again changes nothing.
    before = {p.name: p.read_bytes() for p in bag.iterdir()}
    assert main(['reindex', str(bag)]) == 0
    assert 'nothing to do' in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before


def test_a_complete_mcap_without_metadata_keeps_its_bytes(original, tmp_path):
    bag = copy_of(original, tmp_path)
    mcap_bytes = mcap_of(bag).read_bytes()
    (bag / 'metadata.yaml').unlink()
    result = reindex(bag)
    assert result.wrote_metadata and not result.rewrote_mcap and result.dropped_bytes == 0
    assert mcap_of(bag).read_bytes() == mcap_bytes
    assert by_rosbags(bag) == by_rosbags(original)
    assert bag_summary(bag).message_count == bag_summary(original).message_count


def test_a_cut_mcap_with_its_metadata_is_reindexed_and_info_says_so(original, tmp_path,
                                                                    capsys):
    bag = copy_of(original, tmp_path)
    mcap = mcap_of(bag)
    data = mcap.read_bytes()
    cut = chunks(data)[2].offset + 10
    mcap.write_bytes(data[:cut])
    assert main(['info', str(bag)]) == 1
    err = capsys.readouterr().err
    assert 'rec.mcap has no MCAP footer' in err and 'gyro-ekf reindex' in err
    result = reindex(bag)
    assert result.rewrote_mcap and result.dropped_bytes > 0
    assert by_rosbags(bag) == messages_of_complete_chunks(original / 'rec.mcap', cut)


def test_reindexed_bags_carry_crcs_and_a_damaged_chunk_is_dropped(original, tmp_path):
    bag = copy_of(original, tmp_path)
    mcap = mcap_of(bag)
    data = bytearray(mcap.read_bytes())
    spans = chunks(bytes(data))
    cut = spans[2].end - 5
    # The last complete chunk is damaged inside (its zstd-less records, no CRC to catch a
    # value, but a record length to catch): reindex keeps the chunks before it.
    data[spans[1].offset + 9 + 28 + 4 + 8 + 1:spans[1].offset + 9 + 28 + 4 + 8 + 9] = (
        b'\xff' * 8)
    mcap.write_bytes(bytes(data[:cut]))
    (bag / 'metadata.yaml').unlink()
    reindex(bag)
    assert by_rosbags(bag) == messages_of_complete_chunks(original / 'rec.mcap',
                                                          spans[0].end)
    with open(mcap_of(bag), 'rb') as stream:
        assert all(c.uncompressed_crc for c in StreamReader(stream, emit_chunks=True).records
                   if type(c).__name__ == 'Chunk')


def messages_of_chunks(mcap, keep: set[int]) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of the chunks numbered in keep (file order), by mcap."""
    with open(mcap, 'rb') as stream:
        topics = {i: c.topic for i, c in make_reader(stream).get_summary().channels.items()}
    found = []
    with open(mcap, 'rb') as stream:
        chunk_records = (r for r in StreamReader(stream, emit_chunks=True).records
                         if type(r).__name__ == 'Chunk')
        for number, chunk in enumerate(chunk_records):
            if number in keep:
                found += [(topics[r.channel_id], r.log_time, r.data)
                          for r in breakup_chunk(chunk) if type(r).__name__ == 'Message']
    return sorted(found)


def test_a_chunk_whose_crc_fails_is_left_out_alone_and_the_later_ones_kept(
        original, tmp_path, capsys):
    """A helper's find: a bit flipped in one chunk of a bag cut short dropped every chunk
    after it, intact ones included, and was reported as an incomplete tail."""
    bag = copy_of(original, tmp_path)
    mcap = mcap_of(bag)
    data = bytearray(mcap.read_bytes())
    spans = chunks(bytes(data))
    assert len(spans) >= 4
    # One bit of a message's data in chunk 1 (its frame intact, its CRC no longer), and the
    # file cut inside chunk 3: chunks 0 and 2 are whole.
    data[messages_in_chunk(bytes(data), spans[1])[3][0] + 40] ^= 0x10
    mcap.write_bytes(bytes(data[:spans[3].end - 5]))
    (bag / 'metadata.yaml').unlink()
    assert main(['-q', 'reindex', str(bag)]) == 0
    said = capsys.readouterr().out
    assert (f'left out: the damaged chunk at offset {spans[1].offset} '
            f'({spans[1].end - spans[1].offset} bytes: CRC mismatch') in said, said
    assert f'; {spans[3].end - 5 - spans[3].offset} bytes of an incomplete tail' in said, said
    assert by_rosbags(bag) == messages_of_chunks(original / 'rec.mcap', {0, 2})


def test_a_damaged_chunk_in_a_whole_bag_is_named_and_left_out_only_when_asked(
        original, tmp_path, capsys):
    """A helper's find: a flipped byte in a bag with its footer was "nothing to do" for
    reindex while info and run refused the bag: no way out was said."""
    bag = copy_of(original, tmp_path)
    mcap = mcap_of(bag)
    data = bytearray(mcap.read_bytes())
    spans = chunks(bytes(data))
    data[messages_in_chunk(bytes(data), spans[1])[3][0] + 40] ^= 0x10
    mcap.write_bytes(bytes(data))
    before = {p.name: p.read_bytes() for p in bag.iterdir()}
    assert main(['-q', 'reindex', str(bag)]) == 1
    error = capsys.readouterr().err
    assert f'chunk at offset {spans[1].offset}: CRC mismatch' in error, error
    assert '`gyro-ekf reindex --drop-damaged` rebuilds it without the damaged chunk' in error
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before  # left as it was
    assert main(['-q', 'reindex', str(bag), '--drop-damaged']) == 0
    said = capsys.readouterr().out
    assert said.endswith(f'left out: the damaged chunk at offset {spans[1].offset} '
                         f'({spans[1].end - spans[1].offset} bytes: CRC mismatch (stored '
                         f'{said.split("(stored ")[1].split(")")[0]}))\n'), said
    assert 'incomplete tail' not in said
    assert by_rosbags(bag) == messages_of_chunks(original / 'rec.mcap',
                                                 set(range(len(spans))) - {1})
    assert main(['-q', 'reindex', str(bag)]) == 0
    assert 'every chunk reads whole' in capsys.readouterr().out


def test_a_fine_bag_is_never_modified(original, tmp_path):
    bag = copy_of(original, tmp_path)
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in bag.iterdir()}
    assert needs_reindex(bag) is None
    assert not reindex(bag).wrote_metadata
    assert {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in bag.iterdir()} == before


def test_what_reindex_cannot_help_is_a_clear_error(tmp_path, original):
    with pytest.raises(BagError, match='not a bag folder'):
        reindex(tmp_path / 'nothing')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagError, match='expected one .mcap file to reindex, found 0'):
        reindex(tmp_path / 'empty')
    bag = copy_of(original, tmp_path)
    (bag / 'metadata.yaml').unlink()
    mcap = mcap_of(bag)
    mcap.write_bytes(b'not an mcap file at all')
    with pytest.raises(BagError, match='bad leading magic'):
        reindex(bag)
    assert not any(p.name.startswith('.reindex') for p in bag.iterdir())


@pytest.mark.parametrize('keep', [0, 5, 10, 'into the first chunk'])
@pytest.mark.parametrize('with_metadata', [True, False], ids=['metadata', 'no metadata'])
def test_a_file_with_no_message_to_recover_is_refused_and_the_bag_left_as_it_was(
        original, tmp_path, capsys, keep, with_metadata):
    # An empty .mcap used to get "bad leading magic"; 10 bytes a bag of 0 messages, exit 0,
    # its metadata.yaml and the topics it listed replaced without a word.
    bag = copy_of(original, tmp_path)
    mcap = mcap_of(bag)
    data = mcap.read_bytes()
    if keep == 'into the first chunk':
        keep = chunks(data)[0].end - 10
    mcap.write_bytes(data[:keep])
    if not with_metadata:
        (bag / 'metadata.yaml').unlink()
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in bag.iterdir()}
    assert main(['reindex', str(bag)]) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert captured.out == '' and len(lines) == 1 and 'Traceback' not in captured.err
    assert lines[0].startswith(f'gyro-ekf reindex: error: {mcap}: '), lines
    assert lines[0].endswith(': reindex has no message to recover, so it wrote nothing and '
                             'the bag is as it was'), lines
    assert ('the file is empty' in lines[0]) == (keep == 0)
    assert {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in bag.iterdir()} == before
    # info and run, which read the bag first, sent the user here for an empty file.
    assert (needs_reindex(bag) is None) == (keep == 0 and with_metadata)
