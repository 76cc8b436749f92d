"""The learned subject's demonstrations recorded: the scripted expert that records
(:class:`~conflictbench.policies.subject.record.RecordingExpert`) played on every base task through the normal
runner. Here, above the runner, not beside the policy: a policy never imports the runner that plays it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import LIBERO_SUITES, Plugins, UserError
from conflictbench.policies.subject.record import FAILED, MANIFEST, RecordingExpert, demonstration_name
from conflictbench.store import EpisodeStore
from conflictbench.tasks.libero.base_tasks import all_base_tasks

from .plan import EpisodeSpec
from .runner import Runner


def record_demonstrations(
    out: Path,
    *,
    init_states: list[int],
    noise: float,
    workers: int = 2,
    progress: bool = True,
    libero_suites: tuple[str, ...] | None = None,
    task_ids: tuple[int, ...] | None = None,
) -> int:
    """Play the expert on every base task at ``init_states`` and write each successful episode under ``out``.

    Episodes already recorded there are skipped (a recording that died goes on where it stopped).
    Returns how many demonstrations ``out`` holds.
    """
    out = Path(out)
    recorder = RecordingExpert(out / "episodes", noise)
    manifest = out / "episodes" / MANIFEST
    settings = {"noise": float(noise)}
    if manifest.exists() and json.loads(manifest.read_text(encoding="utf-8")) != settings:
        raise UserError(
            f"{out} holds demonstrations recorded with {manifest.read_text(encoding='utf-8').strip()}, not {settings}: "
            "choose another --out"
        )
    manifest.write_text(json.dumps(settings) + "\n", encoding="utf-8")

    class Recorder:
        __name__ = "subject-demonstrations"

        @hookimpl
        def conflictbench_register_policies(self, register):
            register("expert-recording", load=lambda cfg: recorder)

    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Recorder()])
    spec = plugins.policy("expert-recording")
    failed = out / "episodes" / FAILED
    done = {p.stem for p in (out / "episodes").glob("*.npz")}
    done |= set(failed.read_text(encoding="utf-8").split()) if failed.exists() else set()
    plan = [
        EpisodeSpec(t.suite, t.task_id, state, "p0", t.language)
        for t in all_base_tasks(tuple(libero_suites or LIBERO_SUITES))
        for state in init_states
        if (task_ids is None or t.task_id in task_ids) and demonstration_name(t.suite, t.task_id, state) not in done
    ]
    if plan:
        # A store of its own, wiped first: a demonstration is written only as its episode ends, so an episode
        # stored by a run that died before writing it must be played again.
        store_dir = out / "store"
        if store_dir.exists():
            shutil.rmtree(store_dir)
        runner = Runner(
            plugins,
            spec,
            spec.make_config(),
            store=EpisodeStore(store_dir),
            workers=workers,
            progress=progress,
            on_episode=recorder.finish,
        )
        runner.run(plan)
    return len(list((out / "episodes").glob("*.npz")))
