"""Reading ahead: the next items of a stream produced by a background thread while the caller works on this one.

Zarr's decompression, blosc and the image codecs release the GIL, so reconstruct reads and prepares frame block
k+1 while it fuses block k, and the map stages read and decode a chunk's next block while the encoder runs.
"""

from __future__ import annotations

import queue
import threading
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")


def prefetched(items: Iterable[T], depth: int = 1, *, name: str = "prefetch") -> Iterator[T]:
    """The items of ``items`` in order, the next ``depth`` of them produced meanwhile by a background thread named
    ``name`` (iterating ``items`` runs there: a generator's reading and preparing too). An exception of ``items``
    is raised here, in its turn; leaving the loop early stops the thread."""
    queue_: queue.Queue = queue.Queue(maxsize=depth)
    done, stop = object(), threading.Event()

    def produce() -> None:
        try:
            for item in items:
                if stop.is_set():
                    return
                queue_.put((True, item))
            queue_.put((True, done))
        except BaseException as err:  # noqa: BLE001 (handed to the consumer, raised there)
            queue_.put((False, err))

    thread = threading.Thread(target=produce, name=name, daemon=True)
    thread.start()
    try:
        while True:
            ok, item = queue_.get()
            if not ok:
                raise item
            if item is done:
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # unblock a producer waiting on a full queue
            try:
                queue_.get(timeout=0.05)
            except queue.Empty:
                pass
        thread.join()
