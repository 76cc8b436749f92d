"""What a run's simulator processes are given and how they are born: a planned episode with its job (:class:`Item`),
the place of one worker (:class:`Slot`), the queue of episodes waiting for them, and :func:`sigint_ignored`.

Below every pool (local or Ray), the stack probe, the replays and the runner, so each of them imports it without
importing another's module.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections import OrderedDict, deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from .messages import EpisodeJob
from .plan import EpisodeSpec

TaskKey = tuple[str, int]


@dataclass
class Item:
    """A planned episode with everything its worker needs."""

    spec: EpisodeSpec
    job: EpisodeJob
    losses: int = 0
    """Times a worker was lost while playing it (it is played again once; see the runner)."""


@dataclass
class Slot:
    """One worker process and what it is doing (``stream`` in observations is its index)."""

    index: int
    process: Any = None
    conn: Any = None
    item: Item | None = None
    task_key: TaskKey | None = None
    started: float = 0.0
    retired: bool = False
    """Its worker was lost and none could take its place (a Ray node gone): it plays no more."""


class EpisodeQueue:
    """Episodes grouped by base task, so a worker can stay on the task whose env it has built."""

    def __init__(self, items: Iterable[Item] = ()):
        self._groups: OrderedDict[TaskKey, deque[Item]] = OrderedDict()
        for item in items:
            self.push(item)

    def push(self, item: Item) -> None:
        self._groups.setdefault(item.spec.task_key, deque()).append(item)

    def __bool__(self) -> bool:
        return bool(self._groups)

    def pop_for(self, current: TaskKey | None, busy: set[TaskKey]) -> Item | None:
        """The next episode: of ``current`` if any, else of a task no worker is busy with, else any."""
        if not self._groups:
            return None
        key = (
            current
            if current in self._groups
            else next((k for k in self._groups if k not in busy), next(iter(self._groups)))
        )
        group = self._groups[key]
        item = group.popleft()
        if not group:
            del self._groups[key]
        return item


@contextlib.contextmanager
def sigint_ignored():
    """SIGINT ignored while child processes start, so they inherit it ignored (a Ctrl-C in a terminal reaches
    the whole process group: workers still importing would each print a KeyboardInterrupt traceback)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:  # a handler not installed from Python reads as None: the default then
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)
