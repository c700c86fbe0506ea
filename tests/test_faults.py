"""The fault layer: seeded, per direction, and damage of the kinds it names."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fake_marlin.emulator.faults.layer import FaultConfig, FaultLayer, LineFaults, parse_fault


def joined(segments) -> bytes:
    return b"".join(segment.data for segment in segments)


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
    assert joined(layer.to_printer(b"G28\n")) == b"G28\n" and joined(layer.to_host(b"ok\n")) == b"ok\n"


def test_the_same_seed_damages_the_same_way():
    config = FaultConfig(to_printer=LineFaults(bit_error_rate=0.01, drop_rate=0.01), seed=42)
    data = bytes(range(256)) * 20
    assert joined(FaultLayer(config).to_printer(data)) == joined(FaultLayer(config).to_printer(data))
    assert joined(FaultLayer(config).to_printer(data)) != data
    assert joined(FaultLayer(config).to_host(data)) == data  # the other direction is untouched


@given(st.lists(st.text(alphabet="GMXYZEF0123456789. ", min_size=1, max_size=40), min_size=1, max_size=50),
       st.integers(0, 1000))
def test_corrupt_lines_damages_one_character_and_never_a_line_end(lines, seed):
    layer = FaultLayer(FaultConfig(to_printer=LineFaults(line_corruption_rate=0.5), seed=seed))
    sent = "".join(line + "\n" for line in lines).encode()
    # Delivered in arbitrary pieces, as reads split it.
    received = b"".join(joined(layer.to_printer(sent[i:i + 7])) for i in range(0, len(sent), 7))
    got = received.split(b"\n")[:-1]
    assert len(got) == len(lines)
    damaged = 0
    for before, after in zip(lines, got):
        differences = sum(a != b for a, b in zip(before.encode(), after))
        assert len(after) == len(before) and differences <= 1
        damaged += differences
    assert damaged == layer.stats[next(iter(layer.stats))].lines_corrupted


from fake_marlin.emulator.faults.rules import FaultKind, FaultPlan, FaultRule, Trigger  # noqa: E402


def lines_through(layer: FaultLayer, lines: list[str], direction="to_host") -> list[str]:
    send = getattr(layer, direction)
    return b"".join(joined(send(f"{line}\n".encode())) for line in lines).decode().splitlines()


def test_a_pattern_picks_which_units_count():
    rule = FaultRule(FaultKind.DROP, Trigger(pattern=r"^o", every=3), direction="to-host")
    layer = FaultLayer(FaultConfig(rules=(rule,)))
    lines = ["T:20", "o1", "o2", "LOG:x", "o3", "o4", "o5", "o6"]
    assert lines_through(layer, lines) == ["T:20", "o1", "o2", "LOG:x", "o4", "o5"]


@pytest.mark.parametrize(
    "kind, expected",
    [
        (FaultKind.DUPLICATE, ["a", "b", "b", "c"]),
        (FaultKind.DROP, ["a", "c"]),
        (FaultKind.GARBAGE, ["a", "junkb", "c"]),
    ],
)
def test_unit_faults_act_on_whole_lines(kind, expected):
    rule = FaultRule(kind, Trigger(nth=2), direction="to-printer", text="junk")
    layer = FaultLayer(FaultConfig(rules=(rule,)))
    assert lines_through(layer, ["a", "b", "c"], "to_printer") == expected


def test_ultimaker_packets_are_units_however_they_arrive():
    from fake_marlin.wire.ultimaker import encode_packet

    packets = [encode_packet(n, b"G1 X%d" % n) for n in range(5)]
    rule = FaultRule(FaultKind.DROP, Trigger(nth=3), direction="to-printer")
    layer = FaultLayer(FaultConfig(rules=(rule,)))
    stream = b"".join(packets)
    delivered = b"".join(joined(layer.to_printer(stream[i:i + 5])) for i in range(0, len(stream), 5))
    assert delivered == b"".join(packets[:2] + packets[3:])


def test_a_stall_pauses_the_unit_and_everything_after_it():
    rule = FaultRule(FaultKind.STALL, Trigger(nth=2), direction="to-host", seconds=4.0)
    segments = FaultLayer(FaultConfig(rules=(rule,))).to_host(b"a\nb\nc\n")
    assert [(s.data, s.pause) for s in segments] == [(b"a\n", 0.0), (b"b\nc\n", 4.0)]


def test_triggers_reject_nonsense():
    for bad in [dict(), dict(nth=1, every=2), dict(at=1, pattern="x"), dict(nth=0), dict(probability=2)]:
        with pytest.raises(ValueError):
            Trigger(**bad)
    plan = FaultPlan((FaultRule(FaultKind.REBOOT, Trigger(probability=0.5)),), seed=9)
    again = FaultPlan((FaultRule(FaultKind.REBOOT, Trigger(probability=0.5)),), seed=9)
    assert [plan.fires(0, "x") for _ in range(50)] == [again.fires(0, "x") for _ in range(50)]


def test_a_disconnect_lets_its_unit_through_and_nothing_after():
    rule = FaultRule(FaultKind.DISCONNECT, Trigger(nth=2), direction="to-host", seconds=3.0)
    segments = FaultLayer(FaultConfig(rules=(rule,))).to_host(b"a\nb\nc\n")
    assert [(s.data, s.hang_up) for s in segments] == [(b"a\nb\n", 3.0)]
