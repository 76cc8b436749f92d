"""Asking the policy: one decision for the workers that wait, and the reply each of them gets.

Failures are sorted here. A policy that raises, or answers NaN, inf or the wrong shape, ends its
episode as a failed one (the model's behaviour). An :class:`InfrastructureError` (its server
answered an error) ends the episode for a replay, left out of the measures. A
:class:`ServerUnavailable` is not caught: the run stops.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from conflictbench.core import (
    INFRASTRUCTURE_ERROR_PREFIX,
    ActionContext,
    InfrastructureError,
    PolicyError,
    ServerUnavailable,
    as_action_chunk,
)
from conflictbench.core.plugins import Plugins
from conflictbench.core.policy import batch_outputs

from .messages import Abort, Actions
from .pool import Item


def ask_policy(policy: Any, observations: list[Any], batched: bool) -> list[Any]:
    """The policy's answer to each observation: its raw output, or the error that ends that episode."""
    if batched:
        try:
            return batch_outputs(policy, observations)
        except ServerUnavailable:
            raise
        except Exception as exc:
            return [as_error(exc)] * len(observations)
    outputs: list[Any] = []
    for observation in observations:
        try:
            outputs.append(policy.act(observation))
        except ServerUnavailable:
            raise
        except Exception as exc:
            outputs.append(as_error(exc))
    return outputs


def reply_for(plugins: Plugins, policy: str, item: Item, observation: Any, raw: Any) -> Abort | Actions:
    """What the worker playing ``item`` gets: the chunk to execute (raw and post-processed), or why it stops."""
    if isinstance(raw, InfrastructureError):  # not the model's behaviour: stored apart, replayed next run
        return Abort(f"{INFRASTRUCTURE_ERROR_PREFIX}: {raw}")
    try:
        if isinstance(raw, Exception):  # act_batch may end one episode alone by returning its error
            raise as_error(raw)
        chunk = as_action_chunk(raw)
        job = item.job
        executed = np.stack(
            [
                plugins.postprocess_action(
                    action.copy(),
                    ActionContext(
                        policy=policy,
                        suite=job.suite,
                        task_id=job.task_id,
                        prompt=item.spec.prompt,
                        case_id=item.spec.case_id,
                        step=observation.step + i,
                        chunk_index=i,
                    ),
                )
                for i, action in enumerate(chunk)
            ]
        )
        if not np.all(np.isfinite(executed)):
            raise PolicyError("post-processing produced a non-finite action")
    except PolicyError as exc:
        return Abort(str(exc))
    except Exception as exc:
        return Abort(f"action post-processing raised {type(exc).__name__}: {exc}")
    return Actions(raw=chunk, executed=executed)


def reset_error(exc: Exception) -> str:
    """The ``error`` of an episode whose policy ``reset`` raised."""
    if isinstance(exc, InfrastructureError):
        return f"{INFRASTRUCTURE_ERROR_PREFIX}: {exc}"
    return f"policy reset raised {type(exc).__name__}: {exc}"


def as_error(exc: Exception) -> PolicyError | InfrastructureError:
    if isinstance(exc, (PolicyError, InfrastructureError)):
        return exc
    return PolicyError(f"policy raised {type(exc).__name__}: {exc}")
