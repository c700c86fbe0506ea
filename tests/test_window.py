"""The host's go-back-N window, driven by hand with explicit times."""

import pytest

from fake_marlin.host.cores.queue import is_long_command
from fake_marlin.host.cores.ultimaker import UltimakerCore
from fake_marlin.host.errors import PrinterNotResponding, PrinterReset


def seqs(transmits):
    return [t.seq for t in transmits]


def loaded(n, **options):
    window = UltimakerCore(**options)
    tickets = [window.submit(f"G1 X{i}") for i in range(n)]
    return window, tickets


def test_at_most_window_packets_are_in_flight():
    window, _ = loaded(10, window=3)
    assert seqs(window.transmits(0.0)) == [0, 1, 2]
    assert window.transmits(0.0) == []
    window.on_ack(0, 15, ("data",), 0.0)
    assert seqs(window.transmits(0.0)) == [3]


def test_an_ack_completes_its_packet_and_every_earlier_one():
    window, tickets = loaded(3)
    window.transmits(0.0)
    done = window.on_ack(1, 15, ("T:20",), 0.0)
    assert done == tickets[:2]
    assert tickets[1].response == ("T:20",) and tickets[0].response == ()
    assert all(t.done and t.confirmed for t in tickets[:2])
    assert window.on_ack(1, 15, (), 0.0) == []  # a duplicate changes nothing


def test_a_reject_goes_back_to_its_number_and_ignores_the_echoes_of_the_same_error():
    window, tickets = loaded(3)
    window.transmits(0.0)
    window.on_reject(1, 15, now=0.1)
    assert [(t.seq, t.resend) for t in window.transmits(0.1)] == [(1, True), (2, True)]
    # The printer also rejected packet 2 as it arrived behind the bad packet 1: same `r01`.
    window.on_reject(1, 15, now=0.1)
    assert window.transmits(0.1) == []
    assert window.stats.resends == 2


def test_a_second_real_reject_after_the_echoes_goes_back_again():
    window, _ = loaded(2, window=2)
    window.transmits(0.0)
    window.on_reject(0, 15, now=0.0)
    window.transmits(0.0)
    window.on_reject(0, 15, now=0.0)  # echo for packet 1
    window.on_reject(0, 15, now=0.0)  # the resent 0 was hit too
    assert window.transmits(0.0) == []  # refused twice with no progress: a short pause first
    assert seqs(window.transmits(window.next_deadline())) == [0, 1]


def test_packets_before_a_reject_wait_for_their_ok_without_being_resent():
    window, tickets = loaded(3)
    window.transmits(0.0)
    window.on_reject(3, 15, now=0.0)  # the printer has all three
    assert window.transmits(1.0) == []
    assert window.transmits(5.0) == []  # no resend timeout for packets known to have arrived
    assert window.on_ack(2, 15, (), 0.0) == tickets


def test_a_received_packet_whose_ok_is_lost_completes_unconfirmed():
    window, tickets = loaded(1, timeout=2.0, received_timeout=10.0)
    window.transmits(0.0)
    window.on_reject(1, 15, now=0.5)
    window.transmits(10.4)
    assert not tickets[0].done
    window.transmits(10.6)
    assert tickets[0].done and not tickets[0].confirmed and window.idle
    assert window.take_completed() == tickets and window.take_completed() == []


def test_timeout_resends_the_oldest_unanswered_packet_and_all_after_it():
    window, _ = loaded(3, timeout=2.0)
    window.transmits(0.0)
    window.on_ack(0, 15, (), 0.0)
    assert window.next_deadline() == 2.0
    assert window.transmits(1.9) == []
    assert [(t.seq, t.resend) for t in window.transmits(2.0)] == [(1, True), (2, True)]
    assert window.stats.timeouts == 1


def test_giving_up_after_the_allowed_transmissions():
    window, _ = loaded(1, timeout=1.0, max_transmissions=3)
    now = 0.0
    window.transmits(now)
    with pytest.raises(PrinterNotResponding):
        for _ in range(5):
            now += 1.0
            window.transmits(now)
    assert window.stats.packets_sent == 3


def test_sequence_numbers_wrap_around():
    window, tickets = loaded(600, window=3)
    sent = []
    while not window.idle:
        batch = window.transmits(0.0)
        sent += seqs(batch)
        window.on_ack(batch[-1].seq, 15, (), 0.0)
    assert sent == [n % 255 for n in range(600)]
    assert all(t.done for t in tickets)


def test_a_printer_counting_from_elsewhere_at_connect_gets_renumbered_packets():
    window, _ = loaded(2)
    window.transmits(0.0)
    window.on_reject(37, 15, now=0.0)
    assert seqs(window.transmits(0.0)) == [37, 38]


def test_a_sequence_restart_mid_session_is_a_reset_not_a_renumbering():
    window, _ = loaded(4, window=2)
    window.transmits(0.0)
    window.on_ack(0, 15, (), 0.0)
    window.transmits(0.0)
    with pytest.raises(PrinterReset):
        window.on_reject(100, 15, now=0.0)


def test_a_late_reject_about_settled_packets_is_ignored():
    window, _ = loaded(6, window=3)
    window.transmits(0.0)
    window.on_ack(2, 15, (), 0.0)
    window.transmits(0.0)
    window.on_reject(1, 15, now=0.0)
    assert window.transmits(0.0) == []


def test_timeouts_count_silence_not_age():
    window, _ = loaded(3, timeout=2.0)
    window.transmits(0.0)
    window.on_ack(0, 15, (), 1.5)  # the printer is working through the queue
    assert window.transmits(2.0) == []
    assert window.next_deadline() == 3.5
    assert seqs(window.transmits(3.5)) == [1, 2]


def test_a_full_planner_buys_patience_until_room_is_reported_again():
    window, _ = loaded(4, timeout=2.0, long_timeout=60.0, received_timeout=10.0)
    window.transmits(0.0)
    window.on_ack(0, 0, (), 0.0)  # planner full: the next o comes when a move finishes
    window.transmits(0.0)
    assert window.transmits(9.0) == []  # not the 2 s of a printer with room
    window.heard(9.0, room=1)  # the q frame
    assert window.next_deadline() == 11.0
    assert seqs(window.transmits(11.0)) == [1, 2, 3]


def test_a_full_planner_is_probed_and_given_up_on_only_after_long_silence():
    # The o or q that said the planner had room again may be the frame that got damaged.
    window, _ = loaded(4, timeout=2.0, long_timeout=100.0, received_timeout=10.0, max_transmissions=2)
    window.transmits(0.0)
    window.on_ack(0, 0, (), 0.0)
    window.transmits(0.0)
    assert window.next_deadline() == 30.0  # three received_timeouts: longer than a slow move
    for probe in (30.0, 60.0, 90.0):  # past max_transmissions: still only probes
        assert seqs(window.transmits(probe)) == [1, 2, 3]
    with pytest.raises(PrinterNotResponding):
        window.transmits(120.0)


def test_a_long_command_at_the_head_buys_patience():
    window = UltimakerCore(timeout=2.0, long_timeout=60.0)
    window.submit("G28")
    window.submit("G1 X1")
    window.transmits(0.0)
    assert window.transmits(59.0) == []
    assert seqs(window.transmits(60.0)) == [0, 1]


@pytest.mark.parametrize(
    "text, long",
    [("G28", True), ("g28 X", True), ("G028", True), ("M109 S200", True), ("M400", True),
     ("G1 X1", False), ("M105", False), ("G2", False), ("M1090", False), ("", False)],
)
def test_which_commands_are_long(text, long):
    assert is_long_command(text) is long


def test_a_packet_refused_again_and_again_backs_off_until_progress():
    window, tickets = loaded(2, timeout=2.0)
    window.transmits(0.0)
    window.on_reject(0, 15, now=0.0)  # buffer full
    assert seqs(window.transmits(0.0)) == [0, 1]
    waits = []
    now = 0.0
    for _ in range(10):
        window.on_reject(0, 15, now=now)  # still full (the echo of packet 1 is ignored)
        window.on_reject(0, 15, now=now)
        assert window.transmits(now) == []
        now = window.next_deadline()
        waits.append(round(now - (waits and sum(waits) or 0.0), 3))
        assert seqs(window.transmits(now)) == [0, 1]
    assert waits[:3] == [0.02, 0.04, 0.08] and max(waits) == 2.0
    window.on_ack(0, 15, (), now)  # room again: back to full speed
    window.on_reject(1, 15, now=now)
    assert seqs(window.transmits(now)) == [1]


def test_a_printer_that_refuses_forever_is_given_up_on():
    window, _ = loaded(1, max_transmissions=2)
    now = 0.0
    window.transmits(now)
    with pytest.raises(PrinterNotResponding, match="refused"):
        for _ in range(100):
            window.on_reject(0, 15, now=now)
            now = window.next_deadline() or now
            window.transmits(now)


def test_a_full_planner_of_slow_moves_is_probed_only_after_three_moves_time():
    window, _ = loaded(4, timeout=2.0, received_timeout=10.0)
    window.transmits(0.0)
    window.on_ack(0, 0, (), 0.0)
    window.transmits(0.0)
    window.on_ack(1, 0, (), 40.0)  # a move takes 40 s
    assert window.next_deadline() == 40.0 + 3 * 40.0
