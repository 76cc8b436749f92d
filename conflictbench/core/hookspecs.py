"""Hook specifications: the whole contract between conflictbench and its plugins.

A plugin is any module or object with functions decorated by :data:`conflictbench.hookimpl`
whose names match the specs below. Third-party plugins are found through the entry-point group
``conflictbench``; the built-in policies and metrics register through these same hooks.
"""

from __future__ import annotations

import pluggy

PROJECT_NAME = "conflictbench"

hookspec = pluggy.HookspecMarker(PROJECT_NAME)
hookimpl = pluggy.HookimplMarker(PROJECT_NAME)


@hookspec
def conflictbench_register_policies(register):
    """Declare policies.

    Call ``register(name, load=..., config=...)`` once per policy:

    - ``name``: the Hydra ``model`` option (``conflictbench model=<name>``);
    - ``load(cfg) -> policy``: builds the policy from an instance of ``config``;
    - ``config``: a dataclass whose fields become the overrides ``model.<field>=...``
      (optional; a policy without settings may omit it);
    - ``format_prompt(instruction, condition) -> str | None`` (optional): the model's own P0/P1
      text (its native template); ``None`` falls back to the core's default;
    - ``postprocess(action, context) -> ndarray | None`` (optional): the model's own action
      post-processing, applied to each (7,) action before any global post-processor; ``None``
      leaves the action unchanged.

    ``format_prompt`` and ``postprocess`` belong to the policy they are registered with: they
    never touch another model's episodes, and the registering distribution's version is part of
    every episode's identity, so upgrading the plugin plays its episodes again.

    The policy returned by ``load`` has ``reset(instruction: str) -> None`` and
    ``act(observation) -> ndarray`` of shape ``(7,)`` or a chunk ``(k, 7)`` executed open-loop.
    It may also declare (defaults in brackets; [none]: a method it may leave out; the one list is
    ``conflictbench.core.policy.POLICY_DECLARATIONS``): ``act_batch`` [none]
    (``act_batch(observations) -> list[ndarray]``; an exception in place of one result ends that episode
    alone), ``start`` [none] (called once before the first episode the run plays, never when everything
    is stored already: where to start a model server), ``close`` [none] (called whenever the run ends,
    started or not), ``identity`` [{}] (what the settings do not say about the model, e.g. a checkpoint's
    fingerprint: part of every episode's identity), ``concurrent_requests`` [False] (True: ``act_batch``
    may run in several threads at once, one observation each, so every worker's query goes out as soon
    as it comes: what a served policy declares), ``needs_images`` [True], ``needs_privileged`` [False]
    (simulator truth, the goal and the case: experts and oracles only), ``needs_scene_state`` [False]
    (object poses, regions and scene joints, nothing about the task: :class:`SceneState`),
    ``image_size`` [256], ``warmup_steps`` [10], ``max_steps`` [220/280/300/520] (a mapping LIBERO
    suite -> steps), ``control_mode`` [relative] (or ``absolute``: a target pose after the warm-up).

    A run loads the policy once, whatever ``run.workers`` is, and how it is called depends on
    ``act_batch``:

    - without it, the policy serves one episode at a time: ``reset`` right before that episode's
      first ``act``, then ``act`` for its observations until it ends (other workers meanwhile
      prepare their next episodes). Per-episode state may live in the instance.
    - with it, the policy serves every worker's episodes at once, so observations of different
      episodes interleave. ``reset`` still announces each episode, but cannot say which one:
      keep per-episode state per ``observation.stream``, started afresh when that stream's
      ``observation.episode_id`` changes (:class:`conflictbench.PerEpisode` does exactly this).

    A policy that samples (flow-matching noise, token sampling) draws from
    ``conflictbench.rng_for(observation, own_seed)``, which depends only on the episode's identity
    and step: batched or not, one worker or several, the same episode gets the same actions.
    """


@hookspec(firstresult=True)
def conflictbench_format_prompt(instruction, condition, policy):
    """Return the text a policy receives for ``instruction`` under prompt ``condition``.

    ``condition`` is ``"p0"`` (standard task text) or ``"p1"`` (the task text after the fixed
    premise-check preamble); ``policy`` is the policy's registered name. The first non-``None``
    result wins. This global hook is for deliberate cross-cutting plugins (a lab's prompt style
    for every model): it runs for every policy and overrides a policy's own ``format_prompt``. A
    model's native template belongs in its registration instead (``register(..., format_prompt=)``).
    Where every implementation returns ``None``: the policy's own, else the core's default.
    """


@hookspec
def conflictbench_postprocess_action(action, context):
    """Transform one action before it reaches the environment.

    ``action`` is a float64 array of shape ``(7,)``; ``context`` an :class:`ActionContext`.
    This global hook is for deliberate cross-cutting plugins (clip every action): it runs for every
    policy, after the policy's own ``postprocess``. A model's own post-processing belongs in its
    registration instead (``register(..., postprocess=)``). Implementations are chained: each
    receives the action returned by the one before, in pluggy's call order (``tryfirst``
    implementations first, then the most recently registered first, ``trylast`` ones last); a
    ``wrapper=True`` implementation wraps each link. Returning ``None`` leaves the action
    unchanged. The store keeps both what the policy returned (``raw_actions``) and what was
    executed (``actions``). Every installed plugin implementing this hook is part of every
    episode's identity.
    """


@hookspec
def conflictbench_register_metrics(register):
    """Declare per-pair metrics.

    Call ``register(name, compute=..., description="", label=None, unit="", higher_is_better=None,
    compute_many=None, bounds=None)`` once per metric:

    - ``compute(pair) -> float | None`` gets a :class:`Pair` (``pair.reference`` and
      ``pair.conflict`` are :class:`EpisodeRecord`) and returns ``None`` where the measure is
      undefined for that pair;
    - ``compute_many(references, conflicts) -> sequence of float | None`` (optional): the batched
      form over aligned lists of episodes; used instead of ``compute`` where given (one of the two
      is required);
    - ``label``: the column title in tables and figures (default: the name); ``unit``: ``"%"`` for a
      fraction in [0, 1] shown as a percentage, other text (``"m"``) shown after the value;
      ``higher_is_better``: which way reports mark the most favourable value (``None``: unmarked);
    - ``bounds``: ``(low, high)``, the range every value lies in (a ``"%"`` metric's is [0, 1] unless given).
      Reports give every mean a 95 % interval; with a range it is a score interval that stays inside it and
      does not collapse where every pair gives the same value (and is the whole range where the pairs come from
      one base task), without one a t interval (none in those two cases).
      Give the range values can really take (a loose one widens the intervals); a value outside it stops the
      report with one line naming the metric.

    A metric is averaged over the pairs where it is defined and appears in every report and CSV,
    shown only as its registration says. The built-in TAR, TS, Early20 TS and AMS register through
    this same hook with the same arguments.
    """


@hookspec
def conflictbench_register_conflict_operators(register):
    """Declare conflict operators: generators of premise-conflict cases, per family.

    Call ``register(name, family=..., generate=..., levels=("L1", "L2", "L3", "L4"),
    witness_type=None, check=None, description="")`` once per operator:

    - ``family``: one of ``instruction``, ``grounding``, ``spatial``, ``physical``, or a new family
      name (then ``witness_type`` and ``check`` are required, since no built-in rule knows it);
    - ``generate(model, level, rng)``: yields drafts for one base task and level. ``model`` is the
      base task as the suite builder sees it (``model.task`` the LIBERO task with ``language`` and
      ``goal``, ``model.names`` entity -> noun phrase, ``model.steps`` its subgoals,
      ``model.facts`` what holds in its 50 initial states); ``rng`` a seeded ``random.Random``
      (use only it, so builds stay deterministic). A draft is a dict with ``instruction``,
      ``factors`` (list of str), ``premise``, ``witness`` (dict with a ``type``) and optionally
      ``init_states``;
    - ``check(case, model) -> list[str]``: the validation rule for ``witness_type``, returning the
      reasons a case breaks it (empty when valid).

    ``conflictbench suite build`` runs every registered operator; ``suite validate`` applies every
    registered check. The built-in operators register through this same hook.
    """


@hookspec
def conflictbench_register_published_results(register):
    """Declare what the authors of a model published for its official checkpoints on LIBERO.

    Call ``register(name, policy=..., checkpoint=..., success={suite: percent}, protocol={...}, source=...,
    url=..., date=..., paper_model=None, status="primary", caveats=(), counts=None)`` once per entry:

    - ``name``: what a user declares with ``model.published=<name>`` (short: ``pi05-libero``);
    - ``policy``: the registered policy that plays this checkpoint (``pi05``);
    - ``checkpoint``: where the checkpoint is published (a Hub id, a bucket path);
    - ``success``: LIBERO suite -> published success in percent, exactly as the source prints it;
    - ``protocol``: how the figure was measured: ``episodes_per_suite`` (int), ``trials_per_task`` (int, where
      the source says), ``seeds`` (int, optional),
      ``init_states`` (text), ``max_steps`` (suite -> steps, optional), ``warmup_steps`` (optional),
      ``actions_per_query`` (optional), ``notes`` (text, optional);
    - ``source``, ``url``, ``date``: the citation (paper or model card, its address, the date or commit);
    - ``paper_model``: the row of the ConflictVLA-Bench paper's tables this checkpoint is, or ``None``;
    - ``status``: ``primary`` (read in the source) or ``secondary`` (only third-party copies could be read);
    - ``caveats``: what a reader must know (figures disagree, another harness);
    - ``counts``: suite -> ``"k/n"`` where the source also prints counts.

    ``conflictbench reproduce`` compares a declared checkpoint's measured success with these figures. Nothing
    can check offline that a checkpoint is the one named: the user's declaration says so.
    """
