"""Helpers for a model plugin's own tests.

- real runs of the ``conflictbench`` command on a small selection (:data:`ONE_CASE`: one physical-feasibility L1
  case of libero_spatial and its reference episode, at the first initial state: two real LIBERO episodes, about
  half a minute each on a CPU; needs the simulator, mark such tests ``@pytest.mark.sim`` and ``e2e``)::

      out = run_cli(tmp_path, "model=mymodel", "model.server=...", "model.max_steps=16")
      assert out.returncode == 0 and episode_counts(out.stderr) == (2, 0, 0)

  and two checks a served model's plugin can run against its own servers: :func:`check_failed_episode_is_replayed`
  and :func:`check_killed_server_run_resumes` (conflictbench runs both end to end with a served test plugin);
- observations as a worker sends them (:func:`camera_observation`; :func:`worker_observation` of a LIBERO
  observation dict, with :func:`edge_quaternion` for the quaternions where conversions branch) and actions pinned
  bit for bit (:func:`check_pinned_actions`: what a refactor must not change);
- the plugin's model environment (:class:`ModelEnvironment`): its processes, marks and tiny-checkpoint fixtures;
- a stand-in of an upstream server started on a free port (:func:`start_script_server`).

Tests only: no module of conflictbench imports these, and importing them needs no pytest (a helper that uses it
imports it when called), so a command never needs pytest installed.
"""

from .model_env import BASE_ENV, ModelEnvironment
from .observations import (
    EDGE_QUATERNION_W,
    RECORD_PINNED_ACTIONS,
    camera_observation,
    check_pinned_actions,
    edge_quaternion,
    pinned_observations,
    worker_observation,
)
from .runs import (
    ONE_CASE,
    check_failed_episode_is_replayed,
    check_killed_server_run_resumes,
    episode_counts,
    planned_conflict_instruction,
    run_cli,
    shipped_cases_file,
    start_script_server,
)

__all__ = [
    "BASE_ENV",
    "EDGE_QUATERNION_W",
    "ONE_CASE",
    "RECORD_PINNED_ACTIONS",
    "ModelEnvironment",
    "camera_observation",
    "check_failed_episode_is_replayed",
    "check_killed_server_run_resumes",
    "check_pinned_actions",
    "edge_quaternion",
    "episode_counts",
    "pinned_observations",
    "planned_conflict_instruction",
    "run_cli",
    "shipped_cases_file",
    "start_script_server",
    "worker_observation",
]
