"""Large messages to teammates are sent whole and in order (ramps.runtime.bulk)."""

from __future__ import annotations

import threading
import time

from ramps.runtime.bulk import OrderedSender


class SlowLink:
    """A fake Zenoh put: a blocking put of a large message takes a while
    (a slow link making room), and every put is recorded in order."""

    def __init__(self, seconds: float = 0.2) -> None:
        self.seconds = seconds
        self.sent: list[tuple[str, bytes, bool]] = []
        self.gate = threading.Event()
        self.gate.set()

    def put(self, key: str, data: bytes, block: bool) -> None:
        self.gate.wait(5)
        if block:
            time.sleep(self.seconds)
        self.sent.append((key, data, block))


def wait_for(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert cond()


def test_small_messages_are_left_to_the_caller():
    link = SlowLink()
    s = OrderedSender(link.put, large=100)
    assert s.send("a", b"x" * 100) is False
    assert link.sent == []


def test_a_large_message_is_sent_whole_and_what_follows_it_keeps_its_order():
    link = SlowLink(seconds=0.2)
    s = OrderedSender(link.put, large=100)
    big = b"B" * 1000
    t = time.monotonic()
    assert s.send("a", big) is True
    assert time.monotonic() - t < 0.1  # the caller (the driver) never waits for the link
    # a small message to the same teammate waits behind it; one to another does not
    assert s.send("a", b"small") is True
    assert s.send("b", b"other") is False
    wait_for(lambda: len(link.sent) == 2)
    assert link.sent == [("a", big, True), ("a", b"small", False)]
    assert s.sent_whole == 1
    wait_for(lambda: s.waiting("a") == 0)
    # once the queue is empty, small messages go straight again
    assert s.send("a", b"later") is False


def test_a_destination_holds_at_most_max_queued_bytes_and_drops_beyond():
    link = SlowLink()
    link.gate.clear()  # the link takes nothing for now
    s = OrderedSender(link.put, large=100, max_queued=2500)
    for _ in range(3):
        assert s.send("a", b"B" * 1000) is True
    assert s.dropped == 1 and s.waiting("a") == 2000
    link.gate.set()
    wait_for(lambda: len(link.sent) == 2)
    assert s.dropped == 1


def test_a_failing_put_does_not_stop_the_queue():
    sent: list[bytes] = []

    def put(key: str, data: bytes, block: bool) -> None:
        if data.startswith(b"bad"):
            raise RuntimeError("link closed")
        sent.append(data)

    s = OrderedSender(put, large=10)
    s.send("a", b"bad" + b"x" * 20)
    s.send("a", b"good" + b"x" * 20)
    wait_for(lambda: len(sent) == 1)
    assert sent[0].startswith(b"good")


def test_a_queued_message_says_when_it_is_on_its_way_and_when_it_is_through():
    link = SlowLink(seconds=0.2)
    link.gate.clear()
    s = OrderedSender(link.put, large=100)
    said: list[tuple[str, bool, int]] = []
    assert s.send("a", b"B" * 1000, lambda done: said.append(("big", done, len(link.sent)))) is True
    assert s.send("a", b"small", lambda done: said.append(("small", done, len(link.sent)))) is True
    assert said == [("big", False, 0), ("small", False, 0)]  # before any of it is out
    link.gate.set()
    wait_for(lambda: len(said) == 4)
    assert said[2:] == [("big", True, 1), ("small", True, 2)]  # each once it is sent, in order


def test_a_message_whose_put_fails_is_through_too():
    said: list[bool] = []

    def put(key: str, data: bytes, block: bool) -> None:
        raise RuntimeError("link closed")

    s = OrderedSender(put, large=10)
    assert s.send("a", b"x" * 100, said.append) is True
    wait_for(lambda: said == [False, True])
