"""The viewer's HTML: an index of pairs with filters, and one page per pair. Static files that open from disk."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from html import escape
from typing import Any

from conflictbench.core import ConflictCase, EpisodeRecord
from conflictbench.core.words import counted

from .pairs import FILTERS, OUTCOMES, episode_data, play_again_command

EQUAL_PATH_M = 1e-6  # a replay within a micrometre of the stored path shows what happened


def page_html(title: str, body: str, root: str) -> str:
    return (
        '<!doctype html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{escape(title)}</title>"
        f'<link rel="stylesheet" href="{root}assets/viewer.css"></head>\n<body>\n{body}\n'
        f'<script src="{root}assets/viewer.js"></script>\n</body></html>\n'
    )


def script_json(data: Any) -> str:
    """JSON to sit inside a <script> element: "</" would end the element early."""
    return json.dumps(data).replace("</", "<\\/")


def slug(text: str) -> str:
    return "-".join(text.lower().split())


def format_value(value: Any, metric) -> str:
    """A measure as the report shows it: percent for fractions, its unit otherwise, "undefined" for NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return '<span class="undefined">undefined</span>'
    if metric.percent:
        return f"{100 * value:.1f} %"
    return f"{value:.3g}" + (f" {escape(metric.unit)}" if metric.unit else "")


def _outcome(text: str) -> str:
    return f'<span class="outcome {slug(text)}">{escape(text)}</span>'


def episode_words(record: EpisodeRecord) -> str:
    done = "completed the original goal" if record.success else "did not complete the original goal"
    error = f" (ended by: {escape(record.error)})" if record.error else ""
    return f"{done} in {record.steps} steps{error}"


def replay_words(meta: Mapping[str, Any] | None) -> tuple[str, bool]:
    """What the page says of a video's replay, and whether that is a warning."""
    if not meta:
        return "", False
    if meta.get("error"):
        return f"The replay failed: {meta['error']}", True
    deviation = meta.get("deviation_m")
    if deviation is None or not math.isfinite(deviation):
        return "The replay played another number of steps than the stored episode: this video may mislead.", True
    if deviation > EQUAL_PATH_M:
        return (f"The replay's end-effector path differs from the stored one by up to {1000 * deviation:.2f} mm: "
                "this video may not show what happened.", True)  # fmt: skip
    assumed = " (a store from before the warm-up was kept: the usual 10 no-op steps assumed)"
    return (
        "Replayed from the stored actions (same seed and initial state); its end-effector path equals the stored "
        f"one (largest difference {1e6 * deviation:.2g} µm){assumed if meta.get('warmup_assumed') else ''}.",
        False,
    )


def _video(kind: str, record: EpisodeRecord, meta: Mapping[str, Any] | None, hint: str) -> str:
    caption = f'<figcaption><span class="{kind}-mark">{kind.capitalize()}</span>: {episode_words(record)}</figcaption>'
    if meta and not meta.get("error"):
        src = f"../videos/{escape(record.episode_id, quote=True)}.mp4"
        return f'<figure>{caption}<video src="{src}" controls muted playsinline preload="auto"></video></figure>'
    return f'<figure>{caption}<p class="no-video">No video rendered for this episode. {escape(hint)}</p></figure>'


FRAME_OF_REFERENCE = (
    "Directions are LIBERO's own, the agentview camera's (the camera facing the robot across the table): "
    "left and right as in the image (left = -y), front = towards the camera (+x), behind = towards the robot. "
    "The robot's own left is the image's right (the axes are drawn on the path seen from above)."
)


def frame_of_reference(case: ConflictCase) -> str:
    """The convention a spatial case's directions are in, and whether its claims hold either way."""
    independent = case.witness.get("frame_independent")
    either = {
        True: "Its claims are false read from the robot's side too (frame independent).",
        False: "Read from the robot's side, a direction it claims would be TRUE (frame dependent).",
    }.get(independent, "The case does not say whether its claims hold from the robot's side.")
    return f"{escape(FRAME_OF_REFERENCE)} {escape(either)}"


def pair_page(
    row: Mapping[str, Any],
    reference: EpisodeRecord,
    conflict: EpisodeRecord,
    case: ConflictCase | None,
    metrics: Sequence,
    videos: Mapping[str, Mapping[str, Any]],
    neighbours: tuple[str | None, str | None],
    hint: str,
) -> str:
    """One pair: texts, the two rollouts as videos, paths, distances, actions and measures."""
    previous, following = neighbours
    nav = ['<a href="../index.html">All pairs</a>']
    nav += [f'<a href="{escape(previous)}.html">&larr; previous</a>'] if previous else []
    nav += [f'<a href="{escape(following)}.html">next &rarr;</a>'] if following else []
    premise = escape(case.premise) if case and case.premise else '<span class="undefined">not given</span>'
    witness = (
        "<details><summary>machine-checkable form</summary>"
        f"<pre>{escape(json.dumps(dict(case.witness), indent=2, default=str))}</pre></details>"
        if case
        else '<span class="undefined">the case is not in the suite file read</span>'
    )
    texts = [
        ("Original instruction", escape(reference.instruction)),
        ("Conflict instruction", f"<strong>{escape(conflict.instruction)}</strong>"),
        ("Why its premise fails", premise),
        *([("Frame of reference", frame_of_reference(case))] if case and case.family == "spatial" else []),
        ("Witness", witness),
        ("Text the policy received", f"<pre>{escape(conflict.prompt_text or conflict.instruction)}</pre>"),
        (
            "Base task",
            escape(
                f"{conflict.suite} task {conflict.task_id}, initial state {conflict.init_state}, seed {conflict.seed}"
            ),
        ),  # fmt: skip
        ("Case", escape(conflict.case_id or "")),
        ("Episodes", escape(f"reference {reference.episode_id}, conflict {conflict.episode_id}")),
        (
            "Play it again",
            f"<pre class='command'>{escape(play_again_command(conflict))}</pre>"
            "(add <code>run.out=</code> another store: in this one both episodes are stored, and nothing plays)",
        ),
    ]
    words = [replay_words(videos.get(r.episode_id)) for r in (reference, conflict)]
    replay = "".join(
        f'<p class="replay{" warning" if warning else ""}">{escape(kind)}: {escape(text)}</p>'
        for kind, (text, warning) in zip(("Reference", "Conflict"), words, strict=True)
        if text
    )
    both = (
        '<p><button id="play-both" type="button">Play both from the start</button></p>'
        if all(videos.get(r.episode_id) and not videos[r.episode_id].get("error") for r in (reference, conflict))
        else ""
    )
    measures = "".join(
        f"<tr><td>{escape(m.label or m.name)}</td><td class='num'>{format_value(row.get(m.name), m)}</td>"
        f"<td>{escape(m.description)}</td></tr>"
        for m in metrics
    )
    data = {
        "reference": episode_data(reference),
        "conflict": episode_data(conflict),
        "target_names": list(reference.target_names),
    }
    title = f"{row['model']} · {row['family']} {row['level']} · {row['prompt']}"
    body = f"""<nav>{" ".join(nav)}</nav>
<h1>{escape(title)} {_outcome(row["outcome"])}</h1>
<dl class="texts">{"".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in texts)}</dl>
<h2>Rollouts</h2>
<div class="videos">{_video("reference", reference, videos.get(reference.episode_id), hint)}
{_video("conflict", conflict, videos.get(conflict.episode_id), hint)}</div>
{both}{replay}
<h2>Paths</h2>
<div class="plots"><div id="plot-top"></div><div id="plot-side"></div><div id="plot-distance"></div></div>
<h2>Actions sent to the environment</h2>
<div class="plots" id="plot-actions"></div>
<h2>Measures of this pair</h2>
<table><thead><tr><th>measure</th><th>value</th><th>what it measures</th></tr></thead><tbody>{measures}</tbody></table>
<script type="application/json" id="pair-data">{script_json(data)}</script>"""
    return page_html(title, body, "../")


def paper_section(frame, metrics: Sequence, paper: Mapping[tuple[str, str], str]) -> str:
    """Table 1 of this store's pairs with the paper's rows beside the P0 rows of the models declared to be its
    checkpoints (``conflictbench.report.paper``), and its note; empty where no model of the store is declared."""
    from tabulate import tabulate

    from conflictbench.metrics.aggregate import GROUPINGS, aggregate, with_model
    from conflictbench.metrics.measures import metric_ranges
    from conflictbench.report.paper import declared_labels
    from conflictbench.report.tables import INTERVAL_NOTE, paper_note, paper_tables, table_header, table_rows

    frame = with_model(frame)
    declared = declared_labels(frame, paper)
    if not declared:
        return ""
    spec = paper_tables(metrics)[0]
    table = aggregate(frame, GROUPINGS[spec.grouping], [m.name for m in metrics], metric_ranges(metrics))
    rows = [
        keys + [" ".join(p for p in (value, interval, counts) if p) for value, interval, counts, _ in cells]
        for keys, cells in table_rows(table, spec, declared)
    ]
    html = tabulate(rows, table_header(spec), tablefmt="html", disable_numparse=True)
    note = "".join(f"<p class='note'>{escape(n)}</p>" for n in [f"In %, {INTERVAL_NOTE}.", *paper_note(spec, declared)])
    return f"<h2>Beside the paper (P0)</h2>\n{html}\n{note}"


def index_page(
    rows: Sequence[Mapping[str, Any]],
    metrics: Sequence,
    source: str,
    videos: set[str],
    beside: str = "",
    references: str = "",
) -> str:
    """Every pair in one table, filtered in the page by model, family, level, prompt and outcome; ``beside``:
    the paper's figures beside this store's (:func:`paper_section`), where a model is declared as the paper's;
    ``references``: the table of reference episodes after the pairs' (``episodes.references_section``)."""
    options = {name: sorted({str(r[name]) for r in rows}) for name in FILTERS}
    options["outcome"] = [o for o in OUTCOMES.values() if o in options["outcome"]]  # in the order of OUTCOMES
    filters = "".join(
        f'<label>{name}<select name="{name}"><option value="">all</option>'
        + "".join(f'<option value="{escape(v, quote=True)}">{escape(v)}</option>' for v in values)
        + "</select></label>"
        for name, values in options.items()
    )
    head = "".join(f"<th>{escape(h)}</th>" for h in ("model", "family", "level", "prompt", "conflict instruction",
                                                       "outcome"))  # fmt: skip
    head += "".join(f"<th>{escape(m.label or m.name)}</th>" for m in metrics) + "<th>video</th>"
    body_rows = []
    for r in rows:
        attrs = " ".join(f'data-{name}="{escape(str(r[name]), quote=True)}"' for name in FILTERS)
        page = f"pairs/{escape(r['conflict_episode'])}.html"
        cells = [escape(str(r[k])) for k in ("model", "family", "level", "prompt")]
        cells.append(f'<a href="{page}">{escape(r["instruction"])}</a>')
        cells.append(_outcome(r["outcome"]))
        tds = "".join(f"<td>{c}</td>" for c in cells)
        tds += "".join(f"<td class='num'>{format_value(r.get(m.name), m)}</td>" for m in metrics)
        tds += f"<td>{'yes' if r['conflict_episode'] in videos else ''}</td>"
        body_rows.append(f"<tr {attrs}>{tds}</tr>")
    body = f"""<h1>conflictbench: {counted(len(rows), "pair")}</h1>
<p>From the episode store <code>{escape(source)}</code>. Each pair is a conflict rollout and the reference
rollout by the same policy, base task, initial state, prompt condition and seed.</p>
{beside}
<form id="filters">{filters}</form>
<p id="count">{counted(len(rows), "pair")}</p>
<table id="pairs"><thead><tr>{head}</tr></thead><tbody>
{chr(10).join(body_rows)}
</tbody></table>
{references}"""
    return page_html("conflictbench pairs", body, "")
