"""A stream read ahead by a background thread (the frame blocks of reconstruct and the map stages): the same items in the
same order, an error raised in its turn, and a loop left early stops the thread."""

import threading

import pytest

from pipeline.prefetch import prefetched


def test_items_come_in_order_from_another_thread():
    seen_in = []

    def items():
        for i in range(20):
            seen_in.append(threading.current_thread().name)
            yield i

    assert list(prefetched(items(), depth=2, name="map-read")) == list(range(20))
    assert set(seen_in) == {"map-read"}


def test_an_error_of_the_reader_is_raised_in_its_turn():
    def items():
        yield 1
        yield 2
        raise OSError("frames.zarr: block 3 unreadable")

    got = []
    with pytest.raises(OSError, match="block 3 unreadable"):
        for item in prefetched(items()):
            got.append(item)
    assert got == [1, 2]


def test_leaving_the_loop_early_stops_the_reader():
    produced = []

    def items():
        for i in range(1000):
            produced.append(i)
            yield i

    before = threading.active_count()
    for item in prefetched(items(), depth=1):
        if item == 3:
            break
    assert threading.active_count() == before and len(produced) < 10
