"""The backend's episode bookkeeping on real tiny checkpoints in the model environment (``backend_checks.py``):
each episode has its own queue however episodes interleave, a step sent again gets the same answer and one out of
order is refused, the step's seed alone decides a sampled action, and ``n_action_steps`` sets when the queue
refills."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from lerobot_fixtures import LEROBOT, needs_model_env

CHECKS = Path(__file__).parent / "backend_checks.py"


@needs_model_env
@pytest.mark.parametrize("policy_type", ["act", "diffusion"])
def test_episodes_keep_their_own_queue_and_steps_come_once_in_order(policy_type, tiny_lerobot_checkpoints):
    checkpoint = tiny_lerobot_checkpoints[policy_type]
    done = LEROBOT.run([str(CHECKS), str(checkpoint)], checkpoint=checkpoint, timeout=600)
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    assert seen["interleaved_same"] and seen["again_same"]
    assert seen["out_of_order"] == "episode 'again': step 3 came where step 1 was due"
    assert (seen["dtype"], seen["shape"]) == ("float32", [1, 7])
    assert seen["same_seed_same"]
    # ACT samples nothing at inference (its latent is zero); Diffusion's DDPM draws come from the step's seed.
    assert seen["other_seed_differs"] is (policy_type == "diffusion")
    # The queue refills when empty: every n_action_steps-th step, the checkpoint's own or the run's.
    lengths, lengths_n2 = seen["queue_lengths"], seen["queue_lengths_n2"]
    assert lengths_n2 == [1, 0] * 4 and lengths[0] > 1 and lengths[1] == lengths[0] - 1
    # One n_action_steps besides the checkpoint's (each is a whole model more): another is refused.
    assert seen["third_n_action_steps"].startswith("this server plays n_action_steps=2 beside the checkpoint's own")
