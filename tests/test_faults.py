"""The fault layer: seeded, per direction, and damage of the kinds it names."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from emulator.faults import FaultConfig, FaultLayer, LineFaults, parse_fault


def test_specs_build_a_configuration_and_bad_ones_say_why():
    config = parse_fault("to-printer:bit-errors=1e-4", FaultConfig(seed=3))
    config = parse_fault("to-host:drop-bytes=0.5", config)
    assert config.to_printer.bit_error_rate == 1e-4 and config.to_host.drop_rate == 0.5
    assert config.seed == 3
    for spec, problem in [
        ("up:bit-errors=1", "direction"),
        ("to-host:melt=1", "kind"),
        ("to-host:drop-bytes=lots", "not a number"),
        ("to-host:drop-bytes=2", "between 0 and 1"),
    ]:
        with pytest.raises(ValueError, match=problem):
            parse_fault(spec, FaultConfig())


def test_no_faults_change_nothing():
    layer = FaultLayer()
    assert layer.to_printer(b"G28\n") == b"G28\n" and layer.to_host(b"ok\n") == b"ok\n"


def test_the_same_seed_damages_the_same_way():
    config = FaultConfig(to_printer=LineFaults(bit_error_rate=0.01, drop_rate=0.01), seed=42)
    data = bytes(range(256)) * 20
    assert FaultLayer(config).to_printer(data) == FaultLayer(config).to_printer(data)
    assert FaultLayer(config).to_printer(data) != data
    assert FaultLayer(config).to_host(data) == data  # the other direction is untouched


@given(st.lists(st.text(alphabet="GMXYZEF0123456789. ", min_size=1, max_size=40), min_size=1, max_size=50),
       st.integers(0, 1000))
def test_corrupt_lines_damages_one_character_and_never_a_line_end(lines, seed):
    layer = FaultLayer(FaultConfig(to_printer=LineFaults(line_corruption_rate=0.5), seed=seed))
    sent = "".join(line + "\n" for line in lines).encode()
    # Delivered in arbitrary pieces, as reads split it.
    received = b"".join(layer.to_printer(sent[i:i + 7]) for i in range(0, len(sent), 7))
    got = received.split(b"\n")[:-1]
    assert len(got) == len(lines)
    damaged = 0
    for before, after in zip(lines, got):
        differences = sum(a != b for a, b in zip(before.encode(), after))
        assert len(after) == len(before) and differences <= 1
        damaged += differences
    assert damaged == layer.stats[next(iter(layer.stats))].lines_corrupted
