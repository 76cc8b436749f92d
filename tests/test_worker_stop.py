"""A worker told to stop while its episode waits for actions leaves at once, cleanly."""

from __future__ import annotations

import pytest

from conflictbench.sim.libero_env import EnvSettings
from conflictbench.sim.messages import EpisodeJob, Play, Query, Stop
from conflictbench.sim.pool import WorkerPool
from conflictbench.tasks.libero.base_tasks import base_task

pytestmark = pytest.mark.sim


def test_stop_mid_episode_ends_the_worker_without_a_reply_or_a_traceback(capfd):
    task = base_task("libero_spatial", 0)
    job = EpisodeJob(
        episode_id="stop-test",
        suite=task.suite,
        task_id=task.task_id,
        bddl_path=task.bddl_path,
        init_state=0,
        seed=7,
        instruction=task.language,
        goal=task.goal,
        targets=task.targets,
        warmup_steps=2,
        max_steps=5,
        needs_privileged=False,
    )
    pool = WorkerPool(EnvSettings(needs_images=False), size=1)
    pool.start_all()
    slot = pool.slots[0]
    try:
        slot.conn.send(Play(job))
        assert slot.conn.poll(120) and isinstance(slot.conn.recv(), Query)
        slot.conn.send(Stop())
        slot.process.join(timeout=5)
        assert not slot.process.is_alive() and slot.process.exitcode == 0
        with pytest.raises(EOFError):  # no Done for an episode cut off mid-play: the pipe just closes
            slot.conn.recv()
    finally:
        if slot.process.is_alive():
            slot.process.kill()
    assert "Traceback" not in capfd.readouterr().err
