"""Typed records between the simulator, the runner and the store: scene geometry, worker outcomes,
the measured simulation time."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import pyarrow.parquet as pq
import pytest
from testing_support import episode_record, reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import (
    LIBERO_SUITES,
    EpisodeRecord,
    JointInfo,
    OrientedBoxes,
    Plugins,
    SceneGeometry,
    SiteInfo,
)
from conflictbench.sim.messages import EpisodeOutcome
from conflictbench.sim.runner import Runner
from conflictbench.store import EpisodeStore
from conflictbench.store.schema import SCHEMA, records_to_table
from conflictbench.tasks.libero.base_tasks import base_task


def test_every_outcome_field_lands_in_a_store_column_of_the_same_name():
    outcome = {f.name for f in dataclasses.fields(EpisodeOutcome)}
    assert outcome <= {f.name for f in dataclasses.fields(EpisodeRecord)} and outcome <= set(SCHEMA.names)
    assert "sim_time_s" in outcome and "wall_time_s" in SCHEMA.names


def test_episodes_stored_before_the_sim_time_column_still_read(tmp_path):
    store = EpisodeStore(tmp_path)
    record = episode_record(policy="noop", episode_id="old", wall_time_s=2.0)
    path = store.path_for("noop", "old")
    path.parent.mkdir(parents=True)
    pq.write_table(records_to_table([record]).drop_columns(["sim_time_s", "code_versions"]), path)
    (read,) = store.records()
    assert read.episode_id == "old" and read.wall_time_s == 2.0 and read.sim_time_s is None and read.code_versions == ()


def test_progress_off_shows_nothing(plugins, tmp_path):
    spec = plugins.policy("noop")
    runner = Runner(plugins, spec, spec.make_config(), store=EpisodeStore(tmp_path), progress=False)
    assert runner._bar.enabled is False


THINK_S = 0.05


@dataclass
class SlowConfig:
    pass


class SlowExpert:
    """Privileged, thinks THINK_S per decision, keeps every observation."""

    needs_images = False
    needs_privileged = True
    max_steps = {suite: 12 for suite in LIBERO_SUITES}
    warmup_steps = 4
    seen: list = []
    stamps: list = []
    claims = None

    def __init__(self, cfg):
        SlowExpert.seen = []

    def reset(self, instruction):
        pass

    def act(self, obs):
        SlowExpert.seen.append(obs)
        claim = SlowExpert.claims / f"{obs.episode_id}.claim"  # the runner's claim on this episode, as it is now
        SlowExpert.stamps.append(claim.read_text().split()[2])  # a new token at every renewal
        time.sleep(THINK_S)
        return np.array([0.0, 0.3, 0.0, 0.0, 0.0, 0.0, -1.0])


class Plugin:
    @hookimpl
    def conflictbench_register_policies(self, register):
        register("slow", load=SlowExpert, config=SlowConfig)


@pytest.mark.sim
def test_privileged_geometry_is_typed_and_the_simulation_time_is_stored(tmp_path):
    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Plugin()])
    spec = plugins.policy("slow")
    store = EpisodeStore(tmp_path)
    store.claim_refresh_s = 0.2  # refreshes within the episode's 12 decisions of 0.05 s
    SlowExpert.claims, SlowExpert.stamps = store.claims_dir, []
    result = Runner(plugins, spec, spec.make_config(), store=store, progress=False).run(
        [reference_spec("libero_goal", 3)]
    )
    assert result.played == 1 and result.errors == 0
    (record,) = store.records()
    assert record.warmup_steps == 4  # what a replay of the episode must play again
    assert SlowExpert.stamps[-1] != SlowExpert.stamps[0]  # the claim was kept fresh while it played
    # the worker's own measure leaves out the time spent waiting for the policy
    assert 0 < record.sim_time_s < record.wall_time_s - 12 * THINK_S

    first = SlowExpert.seen[0]
    assert first.episode_id == record.episode_id and [o.step for o in SlowExpert.seen] == list(range(12))
    geo = first.privileged.geometry
    assert isinstance(geo, SceneGeometry)
    assert geo.goal_holds == (False,) * len(base_task("libero_goal", 3).goal)
    drawer = geo.joints["wooden_cabinet_1_top_level"]
    assert isinstance(drawer, JointInfo) and drawer.kind == "slide" and drawer.body in geo.aabb
    assert drawer.qpos == first.privileged.joint_positions["wooden_cabinet_1_top_level"]
    assert {j.kind for j in geo.joints.values()} <= {"slide", "hinge"}
    region = geo.sites["wooden_cabinet_1_top_region"]
    assert isinstance(region, SiteInfo) and region.joints and region.xmat.shape == (3, 3)
    np.testing.assert_array_equal(region.pos, first.privileged.site_positions["wooden_cabinet_1_top_region"])
    bowl = geo.geom_frames["akita_black_bowl_1"]
    n = len(geo.geom_boxes["akita_black_bowl_1"])
    assert isinstance(bowl, OrientedBoxes) and n > 0
    assert bowl.centers.shape == (n, 3) and bowl.rotations.shape == (n, 3, 3) and bowl.half_sizes.shape == (n, 3)
    lo, hi = geo.aabb["akita_black_bowl_1"]
    assert np.all(lo < hi) and "akita_black_bowl_1" in geo.objects and "wooden_cabinet_1" in geo.fixtures
