"""The link's own thread and event loop, apart from the web server's.

Goal: a poll never waits for web traffic.  The link loop (the operator's
master, and in the demo the channel emulator and the ROV node too) runs in
an asyncio loop of its own, in a thread of its own; uvicorn and viser have
theirs.  A 200 MB request body, hundreds of WebSocket readers or a slow
handler can then delay a poll only by what they take of the CPU, never by
holding the loop the poll is sent from (issue 11 measured polls delayed long
enough to trip the ROV's failsafe when the two shared a loop).

The operator is already safe to call from other threads (its master sits
behind a lock, and its subscribers post to their own loops with
call_soon_threadsafe), so nothing crosses between the loops but calls to it
and the events it publishes.

Use: `link = LinkThread().start()`, then `await link.call(coro)` from any
other loop (or `link.call_sync(coro)` from plain code) runs `coro` on the
link loop and returns its result; `link.spawn(coro)` starts a task there
that runs until `await link.stop()` cancels it.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import threading
from collections.abc import Coroutine
from typing import Any

log = logging.getLogger("rovlink.console.link")


class LinkThread:
    def __init__(self, name: str = "rovlink-link") -> None:
        self.name = name
        self.loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._tasks: list[asyncio.Task] = []
        self._ready = threading.Event()

    def start(self) -> "LinkThread":
        if self._thread is not None:
            raise RuntimeError("the link thread is already running")
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()
        self._ready.wait()
        return self

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self.loop = loop
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _submit(self, coro: Coroutine) -> concurrent.futures.Future:
        if not self.running or self.loop is None:
            coro.close()
            raise RuntimeError("the link thread is not running")
        return asyncio.run_coroutine_threadsafe(coro, self.loop)

    async def call(self, coro: Coroutine) -> Any:
        """Run `coro` on the link loop; await its result from another loop."""
        return await asyncio.wrap_future(self._submit(coro))

    def call_sync(self, coro: Coroutine, timeout_s: float | None = None) -> Any:
        """Run `coro` on the link loop and wait for it in this (non-loop) thread."""
        return self._submit(coro).result(timeout_s)

    def spawn(self, coro: Coroutine, name: str | None = None) -> None:
        """Start `coro` as a task of the link loop, cancelled by `stop()`.

        A task that ends with an error is logged (and the link loop goes on):
        the caller watches what it cares about through the operator."""

        async def start() -> None:
            task = asyncio.get_running_loop().create_task(coro, name=name)
            task.add_done_callback(self._task_done)
            self._tasks.append(task)

        self.call_sync(start(), timeout_s=10)

    @staticmethod
    def _task_done(task: asyncio.Task) -> None:
        if not task.cancelled() and task.exception() is not None:
            log.error("link task %s failed", task.get_name(), exc_info=task.exception())

    async def _cancel_tasks(self) -> None:
        tasks, self._tasks = self._tasks, []
        for task in reversed(tasks):
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    def failed(self) -> BaseException | None:
        """The first error a spawned task ended with, if any."""
        for task in list(self._tasks):
            if task.done() and not task.cancelled() and task.exception() is not None:
                return task.exception()
        return None

    async def stop(self, teardown: Coroutine | None = None) -> None:
        """Cancel the spawned tasks, run `teardown` on the link loop, end the thread."""
        await asyncio.to_thread(self.stop_sync, teardown)

    def stop_sync(self, teardown: Coroutine | None = None) -> None:
        if not self.running or self.loop is None:
            if teardown is not None:
                teardown.close()
            return
        try:
            self.call_sync(self._cancel_tasks(), timeout_s=10)
            if teardown is not None:
                self.call_sync(teardown, timeout_s=30)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(timeout=10)
            self._thread = None
