"""`run.backend=ray` on a real Ray cluster of two nodes (Ray's multi-node test cluster, in this machine):
simulator workers as actors spread over the nodes, real LIBERO episodes, a node lost mid-run."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import struct
import threading
import time
from multiprocessing import AuthenticationError
from multiprocessing.connection import Client

import numpy as np
import pytest
from testing_support import reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import LIBERO_SUITES, Plugins
from conflictbench.sim import ray_pool
from conflictbench.sim.runner import Runner
from conflictbench.store import EpisodeStore
from conflictbench.testing import episode_counts, run_cli

pytestmark = [pytest.mark.sim, pytest.mark.cluster]  # Ray actors on this machine
if not os.environ.get("CI"):  # CI installs the cluster extra: there a missing Ray fails
    pytest.importorskip("ray", reason="the cluster extra: pip install -e '.[cluster]'")


def start_cluster(nodes: int, quick_node_death: bool = False):
    from ray.cluster_utils import Cluster

    # The head has no CPU: every actor lands on a worker node, as on a cluster whose driver only drives.
    head = {"num_cpus": 0, "include_dashboard": False}
    if quick_node_death:  # a silent node is declared dead after 2 missed health checks 1 s apart (default 5 x 3 s)
        head["_system_config"] = {"health_check_period_ms": 1000, "health_check_failure_threshold": 2}
    cluster = Cluster(initialize_head=True, head_node_args=head)
    for _ in range(nodes):
        cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    return cluster


@pytest.fixture(scope="module")
def two_nodes():
    cluster = start_cluster(2)
    yield cluster
    cluster.shutdown()


class Still:
    """Stands still for 30 steps; marks each action with its step (dim 3)."""

    needs_images = False
    max_steps = dict.fromkeys(LIBERO_SUITES, 30)

    def __init__(self):
        self.calls = 0

    def reset(self, instruction):
        pass

    def act(self, observation):
        self.calls += 1
        return np.array([0, 0, 0, 0.001 * observation.step, 0, 0, -1.0])


@pytest.mark.parametrize(
    "how",
    [
        "crashed",  # the node's processes die: the actor's connection closes at once
        "silent",  # the machine freezes or its network goes: nothing closes, Ray's word that the node is dead counts
    ],
)
def test_a_node_lost_mid_run_its_episode_is_played_elsewhere_and_each_is_stored_once(tmp_path, capfd, monkeypatch, how):
    class Plugin:
        __name__ = "still"

        @hookimpl
        def conflictbench_register_policies(self, register):
            register("still", load=lambda cfg: Still())

    monkeypatch.setattr(ray_pool, "FREE_CPU_WAIT_S", 1.0)  # no CPU will come back here: do not wait 10 s for one
    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Plugin()])
    spec = plugins.policy("still")
    store = EpisodeStore(tmp_path / "store")
    cluster = start_cluster(2, quick_node_death=True)  # its own: this test takes a node away
    lost: dict = {}
    try:
        runner = Runner(
            plugins,
            spec,
            spec.make_config(),
            store=store,
            workers=2,
            progress=False,
            backend="ray",
            ray_address=cluster.address,
        )

        def lose_a_node() -> None:
            """Once the policy has answered 5 queries, the node of the episode it serves goes: its raylet
            killed, the actor's process killed or frozen."""
            deadline = time.time() + 240
            while time.time() < deadline and not (runner._policy is not None and runner._policy.calls >= 5):
                time.sleep(0.02)
            slot = runner._serving
            handle = slot.process
            lost.update(slot=slot.index, episode=slot.item.job.episode_id, node=handle.node_id)
            node = next(n for n in cluster.list_all_nodes() if n.node_id == handle.node_id)
            lost["pids"] = [handle.pid, *(p.process.pid for p in node.all_processes["raylet"])]
            if how == "silent":
                for pid in lost["pids"]:
                    os.kill(pid, signal.SIGSTOP)
            else:
                os.kill(handle.pid, signal.SIGKILL)
                cluster.remove_node(node, allow_graceful=False)

        threading.Thread(target=lose_a_node, daemon=True).start()
        plan = [reference_spec("libero_object", 4, i) for i in range(4)]
        result = runner.run(plan)
    finally:
        for pid in lost.get("pids", []):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        cluster.shutdown()

    assert lost, "the node was never taken away"
    assert (result.played, result.replayed_after_loss, result.errors) == (4, 1, 0)
    records = store.records()
    assert sorted(r.episode_id for r in records) == sorted(result.episode_ids)  # each once, none missing
    assert all(r.error is None and r.steps == 30 for r in records)
    replayed = next(r for r in records if r.episode_id == lost["episode"])
    np.testing.assert_allclose(replayed.raw_actions[:, 3], 0.001 * np.arange(30))  # whole, from its first step
    assert len({(r.mujoco_version, r.robosuite_version) for r in records}) == 1 and records[0].mujoco_version
    assert runner._pool.slots[lost["slot"]].retired  # no CPU was left for a new actor: the run went on with one
    err = capfd.readouterr().err
    said = re.search(r"the Ray actor on node \S+ was lost \((.+)\); its episode is played again", err)
    assert said
    if how == "silent":  # nothing closed: the run learnt it from Ray
        assert "connection closed" not in said[1] and "Actor" in said[1]


def test_the_command_line_plays_on_the_cluster(tmp_path, two_nodes):
    out = run_cli(tmp_path, "model=noop", "run.backend=ray", f"run.ray_address={two_nodes.address}")
    assert out.returncode == 0, out.stderr[-3000:]
    assert episode_counts(out.stderr) == (2, 0, 0)
    records = EpisodeStore(tmp_path / "results").records()
    assert len(records) == 2 and all(r.error is None for r in records)


def test_more_workers_than_the_cluster_has_cpus_is_a_clear_error(tmp_path, two_nodes):
    # 4 episodes: 3 workers wanted (a run never starts more workers than it has episodes)
    address = f"run.ray_address={two_nodes.address}"
    out = run_cli(tmp_path, "model=noop", "run.init_states=2", "run.backend=ray", "run.workers=3", address)
    assert out.returncode == 2
    assert "run.workers=3 needs 3 CPUs in the Ray cluster; it has 2" in out.stderr
    assert "Traceback" not in out.stderr


@pytest.fixture
def on_the_cluster(two_nodes):
    """This process connected to the two-node cluster (a pool then uses it and leaves it connected)."""
    import ray

    ray.init(address=two_nodes.address, include_dashboard=False)
    yield ray
    ray.shutdown()


def test_strangers_on_the_listener_neither_block_the_actors_nor_the_end_of_the_run(on_the_cluster):
    """A connection that resets, one that stays silent and one without the key: the actor still connects,
    and stopping the pool returns at once."""
    from conflictbench.sim.libero_env import EnvSettings
    from conflictbench.sim.pool import STOP_TIMEOUT_S
    from conflictbench.sim.ray_pool import RayWorkerPool

    pool = RayWorkerPool(EnvSettings(needs_images=False), size=1)
    try:
        reset = socket.create_connection(pool._address)
        reset.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        reset.close()  # RST
        silent = socket.create_connection(pool._address)  # says nothing, stays open
        with pytest.raises((AuthenticationError, EOFError, OSError)):
            Client(pool._address, authkey=b"not the key")
        pool.start_all()
        assert pool.versions["mujoco_version"]
        started = time.monotonic()
    finally:
        pool.stop()
    # Not held up until the actors' stop limit (STOP_TIMEOUT_S, 10 s); 5 s was close for Ray actors leaving on 2
    # busy cores.
    assert time.monotonic() - started < STOP_TIMEOUT_S - 1
    silent.close()


def test_a_message_stalled_part_way_is_a_lost_worker_not_a_hang(on_the_cluster, monkeypatch):
    """A node that freezes while sending: the run's read gives up after the message timeout."""
    from conflictbench.sim import ray_pool
    from conflictbench.sim.libero_env import EnvSettings

    monkeypatch.setattr(ray_pool, "MESSAGE_TIMEOUT_S", 1.0)
    pool = ray_pool.RayWorkerPool(EnvSettings(needs_images=False), size=1)
    try:
        handle = ray_pool.ActorHandle(on_the_cluster, None, "token")
        pool._expected["token"] = handle
        client = Client(pool._address, authkey=pool._authkey)
        client.send(("token", "node", "127.0.0.1", os.getpid()))
        assert handle.arrived.wait(5)
        client.send_bytes(b"x" * 100)  # a whole message, then the header of one that never comes whole
        assert handle.conn.recv_bytes() == b"x" * 100
        client._send(struct.pack("!i", 400_000) + b"y" * 10)
        started = time.monotonic()
        with pytest.raises(OSError):
            handle.conn.recv_bytes()
        assert time.monotonic() - started < 5
        client.close()
    finally:
        pool.stop()


def test_an_address_nobody_answers_is_one_line_at_once(tmp_path):
    out = run_cli(tmp_path, "model=noop", "run.backend=ray", "run.ray_address=127.0.0.1:1", timeout=60)
    assert out.returncode == 3, out.stderr[-3000:]
    assert "cannot reach the Ray cluster at '127.0.0.1:1'" in out.stderr and "Traceback" not in out.stderr
