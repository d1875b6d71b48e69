"""Damaged demonstration bags: every reader refuses them in one line, or proves them intact."""

from binascii import crc32
from pathlib import Path
import shutil
import struct
import subprocess
import sys

from mcap.stream_reader import StreamReader
import numpy as np
import pytest
from suture_lfd import bags
from suture_lfd.bags.mcap_check import check_mcap, salvage_messages
from suture_lfd.demos.demo_bag import write_demonstration_bag
from suture_lfd.nodes.segmenter import SegmenterConfig, segment_bag


@pytest.fixture(scope='module')
def clean(experienced_run, tmp_path_factory):
    """A demonstration bag of the real simulation and its segment file."""
    root = tmp_path_factory.mktemp('corruption')
    bag = root / 'clean'
    write_demonstration_bag(bag, experienced_run.demo)
    out = root / 'clean.segments.npz'
    segment_bag(SegmenterConfig(bag=str(bag), output=str(out)))
    return bag, out.read_bytes()


def _copy(clean_bag, where, data):
    shutil.copytree(clean_bag, where)
    (where / f'{clean_bag.name}.mcap').rename(where / f'{where.name}.mcap')
    meta = where / 'metadata.yaml'
    meta.write_text(meta.read_text().replace(f'{clean_bag.name}.mcap', f'{where.name}.mcap'))
    (where / f'{where.name}.mcap').write_bytes(data)
    return where


def _segment_or_refuse(bag, clean_output):
    """'refused' with a one-line BagError, or 'identical' to the clean result; else fail."""
    out = bag.with_name(bag.name + '.segments.npz')
    try:
        segment_bag(SegmenterConfig(bag=str(bag), output=str(out)))
    except bags.BagError as exc:
        text = str(exc)
        assert '\n' not in text and str(bag) in text, text
        return 'refused'
    assert out.read_bytes() == clean_output, f'{bag}: a different segment file, not refused'
    return 'identical'


def test_written_bags_carry_chunk_data_and_summary_crcs_that_mcap_verifies(clean):
    bag, _ = clean
    data = (bag / 'clean.mcap').read_bytes()
    facts = check_mcap(data)
    assert facts.intact and facts.chunk_crcs == facts.chunks > 1
    with open(bag / 'clean.mcap', 'rb') as handle:   # the mcap library's own CRC checks
        records = list(StreamReader(handle, validate_crcs=True).records)
    assert len(records) > facts.chunks
    # the footer's summary CRC covers the summary up to the footer's last offset field
    footer = len(data) - 8 - 29
    _, _, start, _, crc = struct.unpack_from('<BQQQI', data, footer)
    assert crc == crc32(data[start:footer + 25]) != 0


def test_50_flipped_and_20_truncated_copies_are_refused_in_one_line_or_read_identically(
        clean, tmp_path):
    bag, clean_output = clean
    data = (bag / 'clean.mcap').read_bytes()
    rng = np.random.default_rng(18)
    outcomes = []
    for k in range(50):
        damaged = bytearray(data)
        for at in rng.integers(0, len(data), int(rng.integers(1, 9))):
            damaged[at] ^= int(rng.integers(1, 256))
        copy = _copy(bag, tmp_path / f'flipped{k}', bytes(damaged))
        outcomes.append(_segment_or_refuse(copy, clean_output))
    for k, cut in enumerate(rng.integers(1, len(data), 20)):
        copy = _copy(bag, tmp_path / f'truncated{k}', data[:cut])
        outcomes.append(_segment_or_refuse(copy, clean_output))
    # every byte of the file is under a CRC or fixed by the format: nothing damaged is read
    assert outcomes == ['refused'] * 70


def test_damage_is_named_by_byte_offset_and_topic(clean, tmp_path):
    bag, _ = clean
    data = bytearray((bag / 'clean.mcap').read_bytes())
    salvage, _ = salvage_messages(bytes(data))
    assert not salvage.dropped and not salvage.stop
    facts = check_mcap(bytes(data))
    # a byte in the middle of the second chunk's records
    at = 8
    starts = []
    while data[at] != 0x0F:
        op, length = struct.unpack_from('<BQ', data, at)
        if op == 0x06:
            starts.append((at, length))
        at += 9 + length
    chunk, length = starts[1]
    data[chunk + 9 + length // 2] ^= 0x40
    copy = _copy(bag, tmp_path / 'named', bytes(data))
    with pytest.raises(bags.BagError) as err:
        bags.open_bag(copy)
    text = str(err.value)
    assert f'chunk fails its CRC at byte {chunk}' in text and '/PSM1/measured_cp' in text
    assert 'bag recover' in text
    assert facts.message_count > 0


def test_recover_keeps_the_chunks_that_check_out_and_says_what_it_dropped(clean, tmp_path):
    bag, _ = clean
    data = bytearray((bag / 'clean.mcap').read_bytes())
    total = bags.bag_summary(bag).message_count
    at, starts = 8, []
    while data[at] != 0x0F:
        op, length = struct.unpack_from('<BQ', data, at)
        if op == 0x06:
            starts.append((at, length))
        at += 9 + length
    chunk, length = starts[2]
    data[chunk + 9 + length - 5] ^= 0x01
    copy = _copy(bag, tmp_path / 'flipped', bytes(data))
    cli = Path(sys.executable).parent / 'suture-lfd'
    result = subprocess.run([cli, 'bag', 'recover', copy, '--out', tmp_path / 'kept'],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert f'dropped the chunk at byte {chunk}' in result.stderr
    assert 'Traceback' not in result.stderr
    kept = bags.bag_summary(tmp_path / 'kept').message_count
    assert 0 < kept < total
    with bags.open_bag(tmp_path / 'kept') as reader:   # what was kept reads and checks out
        assert sum(1 for _ in reader) == kept


def test_recover_names_the_topics_of_later_chunks_from_the_summary_when_the_first_is_lost(
        clean, tmp_path):
    bag, _ = clean
    data = bytearray((bag / 'clean.mcap').read_bytes())
    total = bags.bag_summary(bag).message_count
    first = 8 + 9 + struct.unpack_from('<Q', data, 8 + 1)[0]   # after the header record
    assert data[first] == 0x06
    data[first + 200] ^= 0xFF    # in the first chunk, which holds the schemas and channels
    copy = _copy(bag, tmp_path / 'first', bytes(data))
    summary = bags.recover_bag(copy)
    assert 0 < summary.message_count < total
    assert '/PSM1/measured_cp' in summary.topics


@pytest.mark.parametrize('damage', ['flip', 'truncate', 'metadata'])
def test_the_cli_the_segmenter_and_the_player_refuse_a_damaged_bag_in_one_line(
        clean, tmp_path, launch, damage):
    bag, _ = clean
    data = bytearray((bag / 'clean.mcap').read_bytes())
    if damage == 'flip':
        data[len(data) // 3] ^= 0x10
    elif damage == 'truncate':
        data = data[:len(data) * 2 // 3]
    copy = _copy(bag, tmp_path / damage, bytes(data))
    if damage == 'metadata':   # a duration in metadata.yaml that the MCAP summary contradicts
        meta = copy / 'metadata.yaml'
        text = meta.read_text()
        at = text.index('nanoseconds: ') + len('nanoseconds: ')
        meta.write_text(text[:at] + '9' + text[at:])
    cli = Path(sys.executable).parent / 'suture-lfd'
    result = subprocess.run([cli, 'bag', 'info', copy], capture_output=True, text=True)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(copy) in lines[0], result.stderr
    proc = launch('segmenter', '--ros-args', '-p', f'bag:={copy}')
    assert proc.popen.wait(120) == 1
    log = proc.log()
    assert str(copy) in log and 'Traceback' not in log
    player = launch('player', '--ros-args', '-p', f'bag:={copy}')
    assert player.popen.wait(120) not in (0, None)
    log = player.log()
    assert str(copy) in log and 'Traceback' not in log, log
