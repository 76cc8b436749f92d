"""Running a policy server in the foreground until the process is asked to stop."""

from __future__ import annotations

import asyncio
import signal
from collections.abc import Callable
from typing import Protocol


class Server(Protocol):
    async def run(
        self, host: str, port: int, stop: asyncio.Event, on_ready: Callable[[str, int], None] | None = None
    ) -> None:
        """Serve on ``host:port`` (``port`` 0: any free one) until ``stop`` is set; ``on_ready(host, port)`` once
        the socket is bound."""


def serve_until_stopped(server: Server, host: str, port: int, on_ready=None) -> None:
    """Run ``server`` until SIGTERM or SIGINT, then return normally (call from the main thread)."""

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(signum, stop.set)
        await server.run(host, port, stop, on_ready)

    asyncio.run(main())
