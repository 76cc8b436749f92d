"""The live display of a run: episodes done of planned, successes, errors, episodes per hour and the time left.

Rendered with rich on a terminal (one line, refreshed in place); where stderr is no terminal (a log file, a
batch scheduler) it prints a plain line every ``LOG_EVERY_S`` seconds and at the end instead. The runner talks
to it as to a tqdm bar (``update``, ``set_postfix``, ``close``).
"""

from __future__ import annotations

import sys
import time
from typing import Any

LOG_EVERY_S = 60.0


class RunProgress:
    """Episodes done of ``total`` for policy ``name``; ``set_postfix(success=, errors=)`` keeps the counts."""

    def __init__(self, total: int, name: str, enabled: bool = True, stream: Any = None):
        self.total, self.name, self.enabled = total, name, enabled and total > 0
        self.stream = stream or sys.stderr
        self.done, self.counts = 0, {"success": 0, "errors": 0}
        self.note = ""
        self.started = time.monotonic()
        self._last_log = self.started
        self._logged: tuple | None = None
        self._live = None
        if self.enabled and getattr(self.stream, "isatty", lambda: False)():
            self._start_live()

    # tqdm's interface ------------------------------------------------------------------------------
    def update(self, n: int = 1) -> None:
        self.done += n
        self._refresh()

    def set_postfix(self, **values: Any) -> None:
        waiting = values.pop("waiting_for_other_jobs", None)
        self.note = f"waiting for {waiting} episode(s) other jobs are playing" if waiting else ""
        self.counts.update({k: int(v) for k, v in values.items() if k in self.counts})
        self._refresh()

    def close(self) -> None:
        if self._live is not None:
            self._refresh()
            self._live.stop()
            self._live = None
        elif self.enabled and self._logged != (self.done, dict(self.counts)):  # not what the last log line said
            print(self.line(), file=self.stream, flush=True)
        self.enabled = False

    # what it shows ---------------------------------------------------------------------------------
    def rate_per_hour(self) -> float | None:
        elapsed = time.monotonic() - self.started
        return self.done / elapsed * 3600 if self.done and elapsed > 0 else None

    def remaining_s(self) -> float | None:
        rate = self.rate_per_hour()
        return (self.total - self.done) / rate * 3600 if rate else None

    def line(self) -> str:
        rate, left = self.rate_per_hour(), self.remaining_s()
        parts = [
            f"{self.name}: {self.done}/{self.total} episodes",
            *([self.note] if self.note else []),  # before the rest: a narrow terminal cuts the line's end
            f"{self.counts['success']} succeeded",
            f"{self.counts['errors']} with errors",
            f"{rate:.0f} episodes/h" if rate else "rate: after the first episode",
            f"about {duration(left)} left" if left is not None else "time left: after the first episode",
            f"{duration(time.monotonic() - self.started)} so far",
        ]
        return " | ".join(parts)

    def _start_live(self) -> None:
        from rich.console import Console
        from rich.live import Live

        self._live = Live(self._renderable(), console=Console(file=self.stream), refresh_per_second=2, transient=False)
        self._live.start()

    def _renderable(self):
        from rich.progress_bar import ProgressBar
        from rich.table import Table

        grid = Table.grid(padding=(0, 1))
        grid.add_column(no_wrap=True)
        grid.add_column(no_wrap=True, overflow="ellipsis")  # one line at any width: cut, never wrapped
        grid.add_row(ProgressBar(total=max(self.total, 1), completed=self.done, width=20), self.line())
        return grid

    def _refresh(self) -> None:
        if self._live is not None:
            self._live.update(self._renderable())
        elif self.enabled and time.monotonic() - self._last_log >= LOG_EVERY_S:
            self._last_log = time.monotonic()
            self._logged = (self.done, dict(self.counts))
            print(self.line(), file=self.stream, flush=True)


class CountProgress(RunProgress):
    """The same display for other long work (replays, files): ``what`` done of ``total``, failures if counted."""

    def __init__(self, total: int, what: str, enabled: bool = True, stream: Any = None, failures: bool = False):
        super().__init__(total, what, enabled, stream)
        self.failures = failures

    def line(self) -> str:
        left = self.remaining_s()
        return " | ".join(
            [
                f"{self.name}: {self.done}/{self.total}",
                *([f"{self.counts['errors']} failed"] if self.failures else []),
                f"about {duration(left)} left" if left is not None else "time left: after the first one",
                f"{duration(time.monotonic() - self.started)} so far",
            ]
        )


def plan_line(to_play: int, stored: int, seconds_each: float | None, workers: int, basis: str = "so far") -> str:
    """What a run is about to do, and how long it may take: from the wall time of this run's episodes already
    stored (a resumed run) or of the policy's earlier ones (``basis`` says which), else said to be unknown until
    the first ones finish."""
    text = f"conflictbench: {to_play} episode(s) to play, {stored} already stored"
    if not to_play:
        return text
    if seconds_each is None:
        return text + "; the time left shows once the first episodes finish"
    total = to_play * seconds_each / max(1, min(workers, to_play))
    return text + f"; about {duration(total)} with {workers} worker(s), at the {seconds_each:.1f} s per episode {basis}"


def duration(seconds: float) -> str:
    """``1 h 05 min``, ``4 min 10 s``, ``12 s``."""
    seconds = max(0, int(round(seconds)))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours} h {minutes:02d} min"
    return f"{minutes} min {secs:02d} s" if minutes else f"{secs} s"


def run_progress(total: int, name: str, enabled: bool) -> RunProgress:
    """A run's bar over its episodes (``enabled=False``: silent)."""
    return RunProgress(total, name, enabled=enabled)
