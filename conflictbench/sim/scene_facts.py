"""Derive a base task's scene facts from the real simulator (used by ``suite build --facts``).

One LIBERO env per task: reset once (that rebuilds the MuJoCo model), then for each fixed initial
state set it, take the native warm-up (10 no-op steps, as the runner does before the policy's
first observation) and read positions, contacts and LIBERO's predicates. The warm-up matters:
LIBERO's stored states hold objects a little above their supports (a bowl in an open drawer sits
9 cm high), so no contact exists until they settle, and the policy only ever sees the settled scene.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from conflictbench.core.policy import DEFAULT_WARMUP_STEPS
from conflictbench.tasks.libero.base_tasks import BaseTask, load_init_states
from conflictbench.tasks.scene.facts import Entity, TaskFacts, file_sha256, format_scene_facts, states_sha256

# Support surfaces of the scene itself: every object rests on them, so they are not entities.
TABLES = ("main_table", "floor", "kitchen_table", "living_room_table", "study_table", "coffee_table")
UNARY = ("open", "close", "turnon", "turnoff")
NOOP_ACTION = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0])
"""The runner's warm-up action (``conflictbench.sim.worker.NOOP_ACTION``): hold still, gripper open."""


def _entities(task: BaseTask, env) -> dict[str, Entity]:
    problem, inner = task.problem, env.env
    site_names = set(inner.sim.model.site_names)
    out: dict[str, Entity] = {}
    for name, category in problem.objects.items():
        out[name] = Entity(name, category, "object")
    for name, category in problem.fixtures.items():
        if name not in TABLES:
            out[name] = Entity(name, category, "fixture")
    for name, region in problem.regions.items():
        if name in site_names:  # some BDDL files declare regions of fixtures the scene lacks
            out[name] = Entity(name, "region", "region", region.target)
    return out


def _root_of_geoms(env, names: Iterable[str]) -> dict[int, str]:
    """Geom id -> entity name, for the collision geometry of each object and fixture."""
    inner = env.env
    model = inner.sim.model
    root_to_name = {int(model.body_rootid[inner.obj_body_id[n]]): n for n in names}
    out = {}
    for geom in range(model.ngeom):
        root = int(model.body_rootid[model.geom_bodyid[geom]])
        if root in root_to_name:
            out[geom] = root_to_name[root]
    return out


def _footprint(env, name: str, geoms: dict[int, str]) -> tuple[float, float]:
    """Horizontal radius and height of an entity's collision geoms (world AABB of each geom box)."""
    model, data = env.env.sim.model, env.env.sim.data
    centre = data.body_xpos[env.env.obj_body_id[name]]
    corners = []
    for geom, owner in geoms.items():
        if owner != name or model.geom_contype[geom] == 0 and model.geom_conaffinity[geom] == 0:
            continue
        aabb = model.geom_aabb[geom]  # centre (3) and half sizes (3) in the geom frame
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        local = aabb[:3] + signs * aabb[3:]
        corners.append(data.geom_xpos[geom] + local @ data.geom_xmat[geom].reshape(3, 3).T)
    if not corners:
        return 0.0, 0.0
    pts = np.concatenate(corners)
    radius = float(np.max(np.linalg.norm(pts[:, :2] - centre[:2], axis=1)))
    return radius, float(pts[:, 2].max() - pts[:, 2].min())


def _contacts(env, geoms: dict[int, str]) -> set[frozenset]:
    data = env.env.sim.data
    pairs = set()
    for contact in data.contact[: data.ncon]:
        a, b = geoms.get(int(contact.geom1)), geoms.get(int(contact.geom2))
        if a and b and a != b:
            pairs.add(frozenset((a, b)))
    return pairs


def _articulated(env, entities: dict[str, Entity]) -> list[str]:
    """Fixtures and regions with joints: the only ones whose open/close/turnon/turnoff mean something
    (LIBERO answers "closed" for a thing without joints, vacuously)."""
    inner = env.env
    out = []
    for name, entity in entities.items():
        if entity.kind == "fixture" and getattr(inner.get_object(name), "joints", None):
            out.append(name)
        elif entity.kind == "region" and getattr(inner.object_sites_dict.get(name), "joints", None):
            out.append(name)
    return out


def _safe_eval(env, atom: tuple[str, ...]) -> bool:
    try:
        return bool(env.env._eval_predicate(atom))
    except Exception:  # LIBERO raises for combinations it does not define (an object that cannot contain)
        return False


def _settle(env, init_state) -> None:
    """Set an initial state and let it settle, as an episode does before its first action."""
    env.set_init_state(init_state)
    for _ in range(DEFAULT_WARMUP_STEPS):
        env.step(NOOP_ACTION)


def _true_predicates(env, entities: dict[str, Entity], objects: list[str], unary_targets: list[str]):
    """The predicates LIBERO evaluates true now: ``on``/``in`` of each object on or in another entity, and the
    unary states of the articulated targets (``turn_on`` and the like only for what can be turned)."""
    for a in objects:
        for b in entities:
            if a == b:
                continue
            for relation in ("on", "in"):
                if _safe_eval(env, (relation, a, b)):
                    yield (relation, a, b)
    for target in unary_targets:
        for relation in UNARY:
            if relation.startswith("turn") and not hasattr(env.env.get_object(target), "turn_on"):
                continue
            if _safe_eval(env, (relation, target)):
                yield (relation, target)


def derive_task_facts(task: BaseTask, *, states: Iterable[int] | None = None) -> TaskFacts:
    """Facts of one base task from a fresh simulator (call inside a process configured for LIBERO)."""
    from conflictbench.sim.libero_env import EnvSettings, make_env

    init_states = load_init_states(task.suite, task.task_id)
    chosen = list(range(len(init_states))) if states is None else list(states)
    env = make_env(task.bddl_path, EnvSettings(needs_images=False))
    try:
        env.seed(7)
        env.reset()
        entities = _entities(task, env)
        bodies = [n for n, e in entities.items() if e.kind != "region"]
        geoms = _root_of_geoms(env, bodies)
        positions = {n: np.zeros((len(chosen), 3)) for n in entities}
        contacts: dict[frozenset, set[int]] = {}
        predicates: dict[tuple, set[int]] = {}
        objects = [n for n, e in entities.items() if e.kind == "object"]
        unary_targets = _articulated(env, entities)
        for row, index in enumerate(chosen):
            _settle(env, init_states[index])
            data = env.env.sim.data
            for name, entity in entities.items():
                positions[name][row] = (
                    data.get_site_xpos(name) if entity.kind == "region" else data.body_xpos[env.env.obj_body_id[name]]
                )
            for pair in _contacts(env, geoms):
                contacts.setdefault(pair, set()).add(index)
            for atom in _true_predicates(env, entities, objects, unary_targets):
                predicates.setdefault(atom, set()).add(index)
        _settle(env, init_states[chosen[0]])
        sized = {}
        for name in bodies:
            radius, height = _footprint(env, name, geoms)
            sized[name] = Entity(name, entities[name].category, entities[name].kind, None, radius, height)
        entities.update(sized)
    finally:
        env.close()
    return TaskFacts(
        task.suite,
        task.task_id,
        file_sha256(task.bddl_path),
        states_sha256(init_states),
        len(chosen),
        entities,
        positions,
        {k: frozenset(v) for k, v in contacts.items()},
        {k: frozenset(v) for k, v in predicates.items()},
        frozenset(chosen),
    )


def derive_in_subprocess(suite: str, task_id: int, states: Iterable[int] | None = None) -> TaskFacts:
    """:func:`derive_task_facts` in a fresh 'spawn' process, leaving this process's GL settings
    and imports alone (robosuite binds its GL backend once per process)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_derive_job, suite, task_id, None if states is None else tuple(states)).result()


def _derive_job(suite: str, task_id: int, states: tuple[int, ...] | None) -> TaskFacts:
    from conflictbench.sim.libero_env import EnvSettings, configure_process
    from conflictbench.tasks.libero.base_tasks import base_task

    configure_process(EnvSettings(needs_images=False))
    return derive_task_facts(base_task(suite, task_id), states=states)


def build_scene_facts(
    tasks: Iterable[BaseTask], path: str | Path, progress: Callable[[str], None] | None = None
) -> Path:
    """Derive every task's facts (one simulator at a time) and write the shipped facts file."""
    from conflictbench.sim.libero_env import EnvSettings, configure_process, simulator_versions

    configure_process(EnvSettings(needs_images=False))
    facts = []
    for task in tasks:
        if progress:
            progress(f"scene facts: {task.suite} task {task.task_id}")
        facts.append(derive_task_facts(task))
    path = Path(path)
    versions = simulator_versions()
    provenance = {"libero": versions["libero_version"], "mujoco": versions["mujoco_version"]}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(format_scene_facts(facts, provenance), encoding="utf-8")
    tmp.replace(path)
    return path
