"""The studio's background jobs: fits and renders run in a worker thread, one at a time, newest first.

A newer preview supersedes an older one: a stale request that has not started yet is dropped and a stale result
is discarded (both raise :class:`Superseded`, answered with 409), so the latest edit runs next instead of
queueing behind outdated ones.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

import anyio.to_thread

__all__ = ["LatestOnly", "Superseded", "run_in_worker", "in_thread"]

T = TypeVar("T")


class Superseded(Exception):
    """A newer request of the same kind arrived: this one's result is not wanted any more."""


class LatestOnly:
    """Runs jobs one at a time; on a channel, only the newest job's result counts.

    ``run(channel, fn)`` numbers the request. It waits for the single worker slot; if a newer request on the
    same channel arrived meanwhile it raises :class:`Superseded` without running ``fn``, and if one arrived
    while ``fn`` ran the result is discarded the same way. So a burst of edits runs the first and the last,
    never the ones in between. ``channel=None`` (exports) is never superseded.
    """

    def __init__(self) -> None:
        self._slot = threading.Lock()  # at most one fit at a time
        self._mutex = threading.Lock()
        self._latest: dict[str, int] = {}

    def ticket(self, channel: str) -> int:
        with self._mutex:
            self._latest[channel] = self._latest.get(channel, 0) + 1
            return self._latest[channel]

    def current(self, channel: str) -> int:
        with self._mutex:
            return self._latest.get(channel, 0)

    def run(self, channel: str | None, fn: Callable[[], T], ticket: int | None = None) -> tuple[int, T]:
        """Run ``fn`` in the worker slot: ``(ticket, result)``. Call from a worker thread.

        Raises:
            Superseded: a newer request on ``channel`` arrived before or while ``fn`` ran.
        """
        if channel is None:
            with self._slot:
                return 0, fn()
        gen = self.ticket(channel) if ticket is None else ticket
        with self._slot:
            if gen != self.current(channel):
                raise Superseded
            result = fn()
        if gen != self.current(channel):
            raise Superseded
        return gen, result


async def run_in_worker(
    worker: LatestOnly, channel: str | None, fn: Callable[[], T], ticket: int | None = None
) -> tuple[int, T]:
    """:meth:`LatestOnly.run` from a request handler, in a worker thread so the server keeps answering."""
    return await anyio.to_thread.run_sync(lambda: worker.run(channel, fn, ticket))


async def in_thread(fn: Callable[[], T]) -> T:
    """``fn()`` in a worker thread outside the fit slot (decoding, encoding a preview frame)."""
    return await anyio.to_thread.run_sync(fn)
