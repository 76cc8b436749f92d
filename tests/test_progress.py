"""The live display of a run: what it says, on a terminal (rich) and in a log (plain lines)."""

from __future__ import annotations

import io

import pytest

from conflictbench.sim import progress
from conflictbench.sim.progress import RunProgress, duration


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_line_counts_episodes_successes_errors_and_the_rate_so_far(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: now[0])
    bar = RunProgress(10, "random", enabled=True, stream=io.StringIO())
    now[0] = 190.0
    bar.update(3)  # 3 episodes in 90 s: 120 episodes/h, 7 left: 210 s
    bar.set_postfix(success=2, errors=1)
    line = bar.line()
    assert line.startswith("random: 3/10 episodes | 2 succeeded | 1 with errors | 120 episodes/h")
    assert "about 3 min 30 s left" in line and "1 min 30 s so far" in line


def test_before_the_first_episode_it_says_when_a_rate_will_be_known():
    line = RunProgress(5, "noop", enabled=True, stream=io.StringIO()).line()
    assert "rate: after the first episode" in line and "time left: after the first episode" in line


def test_a_log_gets_plain_lines_and_the_last_state_on_close():
    log = io.StringIO()
    bar = RunProgress(2, "noop", enabled=True, stream=log)
    bar.update(1)  # within LOG_EVERY_S: nothing yet
    assert log.getvalue() == ""
    bar.update(1)
    bar.close()
    assert log.getvalue().strip().startswith("noop: 2/2 episodes")


def test_a_log_line_is_not_repeated_on_close_when_nothing_changed(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: now[0])
    log = io.StringIO()
    bar = RunProgress(2, "noop", enabled=True, stream=log)
    now[0] = progress.LOG_EVERY_S + 1
    bar.update(2)  # the periodic line already says 2/2
    now[0] += 4
    bar.close()
    assert [line.split(" | ")[0] for line in log.getvalue().splitlines()] == ["noop: 2/2 episodes"]


def test_a_terminal_gets_a_rich_line_refreshed_in_place():
    terminal = Terminal()
    bar = RunProgress(4, "pi0", enabled=True, stream=terminal)
    bar.update(3)
    bar.set_postfix(success=3, errors=0, waiting_for_other_jobs=1)
    bar.close()
    shown = terminal.getvalue()
    assert "pi0: 3/4 episodes" in shown and "waiting for 1 episode(s) other jobs are playing" in shown
    assert "\x1b[" in shown  # drawn with terminal control codes, not printed line by line


def test_disabled_shows_nothing():
    log = Terminal()
    bar = RunProgress(3, "noop", enabled=False, stream=log)
    bar.update(3)
    bar.close()
    assert log.getvalue() == ""


@pytest.mark.parametrize("seconds, text", [(12.4, "12 s"), (250, "4 min 10 s"), (3900, "1 h 05 min"), (-3, "0 s")])
def test_durations_read_as_people_write_them(seconds, text):
    assert duration(seconds) == text


def test_the_plan_line_estimates_from_this_runs_stored_episodes_or_says_it_cannot_yet():
    from conflictbench.sim.progress import plan_line

    assert plan_line(8, 4, 13.2, 2) == (
        "conflictbench: 8 episode(s) to play, 4 already stored; about 53 s with 2 worker(s), at the 13.2 s per "
        "episode so far"
    )
    assert plan_line(1, 4, 10.0, 2).endswith("about 10 s with 2 worker(s), at the 10.0 s per episode so far")
    assert plan_line(4, 0, None, 2).endswith("; the time left shows once the first episodes finish")
    assert plan_line(0, 5, 3.0, 2) == "conflictbench: 0 episode(s) to play, 5 already stored"
