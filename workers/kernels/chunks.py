"""Chunked loops on two threads: while one chunk's rays are made (numba, without the GIL) another's are cast.

The light stage's per-hit passes (cage visibility, near-field occlusion, direct light) each loop over chunks of
hits: build the chunk's rays in a single-threaded kernel, then cast them on the caster's threads. One after the
other, one core idles while the rays are made (living-room's light stage: 31 of its 43 s on one thread).
:func:`map_chunks` runs the chunks :data:`CHUNK_THREADS` at a time; each chunk's result depends only on its own
range, so the results are those of the serial loop, in chunk order.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Callable, TypeVar

__all__ = ["CHUNK_THREADS", "map_chunks"]

T = TypeVar("T")

CHUNK_THREADS = 2
"""Chunks in flight at once (this machine's cores; the caster's own threads share them)."""


def map_chunks(fn: Callable[[int, int], T], n: int, size: int, threads: int = CHUNK_THREADS) -> list[T]:
    """``[fn(a, e) for each chunk [a, e) of [0, n) of ``size`` items]``, up to ``threads`` chunks at a time.

    ``fn`` must touch only its own range of any shared output (it may write ``out[a:e]``). Results come back
    in chunk order; the first exception is raised.
    """
    size = max(1, int(size))
    bounds = [(s, min(n, s + size)) for s in range(0, int(n), size)]
    if threads <= 1 or len(bounds) <= 1:
        return [fn(a, e) for a, e in bounds]
    with ThreadPoolExecutor(min(int(threads), len(bounds)), thread_name_prefix="kiln-chunk") as pool:
        return list(pool.map(lambda b: fn(*b), bounds))
