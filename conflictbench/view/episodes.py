"""The viewer's reference episodes, each on a page of its own: what ``conflictbench reproduce`` plays (LIBERO's
standard evaluation, the original instructions, no conflict) and every reference a pair uses, openable by itself.

A reference is listed where the filters given could name it (model and prompt; a family, level or outcome names
pairs only) and where no infrastructure failure ended it (what the report leaves out is not shown as the model's).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from html import escape
from typing import Any

import pandas as pd

from conflictbench.core import EpisodeRecord
from conflictbench.metrics.aggregate import sort_groups, with_model
from conflictbench.report.from_store import light_records
from conflictbench.store import EpisodeStore

from .pairs import Selection
from .site import episode_words, page_html, replay_words


def reference_episodes(store: EpisodeStore, selection: Selection) -> list[tuple[str, EpisodeRecord]]:
    """(model label, episode) of every usable reference episode the filters allow, in the report's order."""
    if selection.family or selection.level or selection.outcome:
        return []
    records = [r for r in light_records(store) if r.case_id is None and not r.infrastructure_failed]
    if not records:
        return []
    rows = pd.DataFrame(
        {
            "policy": [r.policy for r in records],
            "config_hash": [r.config_hash for r in records],
            "policy_settings": [r.policy_settings for r in records],
            "prompt": [r.prompt for r in records],
            "suite": [r.suite for r in records],
            "task_id": [r.task_id for r in records],
            "init_state": [r.init_state for r in records],
            "position": range(len(records)),
        }
    )
    rows = with_model(rows)
    keep = pd.Series(True, index=rows.index)
    if selection.model:
        keep &= rows["model"].astype(str).isin(selection.model)
    if selection.prompt:
        keep &= rows["prompt"].astype(str).isin(selection.prompt)
    rows = sort_groups(rows[keep], ["model", "prompt", "suite", "task_id", "init_state"])
    return [(str(label), records[i]) for label, i in zip(rows["model"], rows["position"], strict=True)]


def episode_page(label: str, record: EpisodeRecord, meta: Mapping[str, Any] | None, hint: str) -> str:
    """One reference episode: its texts and its video (by replay), or the command that renders it."""
    outcome = "succeeded" if record.success else "failed"
    texts = [
        ("Instruction", escape(record.instruction)),
        ("Text the policy received", f"<pre>{escape(record.prompt_text or record.instruction)}</pre>"),
        (
            "Base task",
            escape(f"{record.suite} task {record.task_id}, initial state {record.init_state}, seed {record.seed}"),
        ),  # fmt: skip
        ("Episode", escape(record.episode_id)),
    ]
    if meta and not meta.get("error"):
        src = f"../videos/{escape(record.episode_id, quote=True)}.mp4"
        video = f'<video src="{src}" controls muted playsinline preload="auto"></video>'
    else:
        video = f'<p class="no-video">No video rendered for this episode. {escape(hint)}</p>'
    words, warning = replay_words(meta)
    replay = f'<p class="replay{" warning" if warning else ""}">{escape(words)}</p>' if words else ""
    title = f"{label} · reference · {record.prompt}"
    body = f"""<nav><a href="../index.html">All pairs and episodes</a></nav>
<h1>{escape(title)} <span class="outcome {outcome}">{outcome}</span></h1>
<dl class="texts">{"".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in texts)}</dl>
<h2>Rollout</h2>
<figure><figcaption>{episode_words(record)}</figcaption>{video}</figure>
{replay}"""
    return page_html(title, body, "../")


def references_section(episodes: Sequence[tuple[str, EpisodeRecord]], videos: set[str]) -> str:
    """The index's table of reference episodes, each linking to its page."""
    if not episodes:
        return ""
    head = "".join(f"<th>{h}</th>" for h in ("model", "prompt", "LIBERO task", "initial state", "outcome", "steps",
                                            "video"))  # fmt: skip
    rows = []
    for label, record in episodes:
        page = f"episodes/{escape(record.episode_id, quote=True)}.html"
        task = f'<a href="{page}">{escape(f"{record.suite} {record.task_id}")}</a>'
        cells = [escape(label), escape(record.prompt), task, str(record.init_state),
                 "succeeded" if record.success else "failed", str(record.steps),
                 "yes" if record.episode_id in videos else ""]  # fmt: skip
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return f"""<h2>Reference episodes: {len(episodes)}</h2>
<p>Rollouts of the original instruction (what <code>conflictbench reproduce</code> plays, and each pair's
reference), each on a page of its own.</p>
<table id="references"><thead><tr>{head}</tr></thead><tbody>
{chr(10).join(rows)}
</tbody></table>"""
