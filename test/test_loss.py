"""Loss counting from publication sequence numbers (arm_bag.loss, pure)."""

from __future__ import annotations

from arm_bag.loss import GapCounter, missed_before_first


def feed(counter: GapCounter, seqs) -> int:
    return sum(counter.message(s) for s in seqs)


def test_a_gap_in_one_publishers_numbers_is_counted_once_the_numbers_go_on():
    c = GapCounter()
    c.graph(1)
    assert feed(c, [1, 2, 3, 7]) == 0, 'a jump is pending until the numbers go on'
    assert c.message(8) == 3 and c.lost == 3


def test_several_gaps_in_a_row_are_all_counted_by_the_end():
    c = GapCounter()
    c.graph(1)
    feed(c, [1, 5, 9, 20])  # a queue of 1 under a burst: only jumps
    assert c.lost == 0 and c.close() == 3 + 3 + 10 and c.lost == 16


def test_a_second_publisher_not_yet_in_the_graph_counts_nothing():
    c = GapCounter()
    c.graph(1)
    feed(c, [10, 11, 12])
    feed(c, [40])  # the newcomer's first message: looks like a gap of 27
    feed(c, [13, 41, 14, 42])  # then the numbers interleave
    assert c.lost == 0 and c.close() == 0
    c.graph(2)
    assert feed(c, [15, 43, 16, 44]) == 0 and c.close() == 0


def test_a_restarted_publisher_starting_again_at_1_is_not_a_loss():
    c = GapCounter()
    c.graph(1)
    feed(c, [1, 2, 3, 4, 5])
    feed(c, [1, 2, 3])  # restarted: counting waits for the graph
    assert c.lost == 0
    c.graph(1)
    assert feed(c, [4, 6, 7]) == 1 and c.lost == 1


def test_no_publisher_known_or_unknown_numbers_count_nothing():
    c = GapCounter()
    assert feed(c, [1, 5, 9]) == 0 and c.close() == 0, 'no publisher in the graph yet'
    c.graph(1)
    assert feed(c, [0, 0, 0]) == 0, 'an rmw without sequence numbers'


def test_a_publisher_that_appeared_while_recording_counts_what_came_before_its_first():
    assert missed_before_first(41, 1, True) == 40, 'numbers 1..40 never arrived'
    assert missed_before_first(1, 1, True) == 0, 'nothing missed'
    assert missed_before_first(0, 1, True) == 0, 'an rmw without sequence numbers'


def test_what_a_publisher_sent_before_the_recorder_or_whose_it_was_is_unknown_not_lost():
    assert missed_before_first(41, 1, False) == 0, 'it may have sent them before the start'
    assert missed_before_first(41, 2, True) == 0, 'whose number is it?'
    assert missed_before_first(41, 0, True) == 0, 'already gone from the graph'
