"""The results page, ``docs/results.md``: one section per entry of the catalogue ``conf/results.yaml``,
rendered from the snapshots alone (no run folder is read; rendering twice gives the same bytes).

Each section: its short title, the entry's note as one paragraph, the facts of its runs as a list
(the command that re-runs it, when and where the runs ran, the generated differences from the
thesis as a list of at most :data:`MAX_DIFFERENCES` lines), its table with the line saying what the
numbers are, and its plots. A report kind draws its own table where the generic one does not fit
(:func:`with_table`). Prose is wrapped at :data:`WIDTH` characters (code spans and links whole); a
command too long for one line is a shell block with continuation lines.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from aslexp.files import atomic_write_text
from aslexp.results.catalogue import command_overrides, load_catalogue, uncovered_overrides, unrun_values
from aslexp.results.kinds import report_kind
from aslexp.results.provenance import utc
from aslexp.results.snapshots import read_snapshot, snapshot_path, update

PAGE = Path("docs") / "results.md"
WIDTH = 120  # prose lines are wrapped here; a table row is one line, however long
MAX_DIFFERENCES = 12  # the generated differences from the thesis, one short line each
COMMAND_LINE = 200  # a longer command is a shell block with continuation lines


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _number(value: float | None, percent: bool) -> str:
    if value is None:
        return "-"
    return f"{100 * value:.1f}" if percent else f"{value:.3f}"


def _learned(learned: dict[str, Any], percent: bool, planned: bool = False) -> str:
    if learned.get("cell"):  # a recognition row, rendered by aslexp.results.recognition
        return learned["cell"]
    if learned.get("mean") is None:
        return "- (nothing trained: a planner's ceiling)" if planned else "pending (no trained run)"
    text = _number(learned["mean"], percent)
    one_seed = learned.get("n") == 1 and learned.get("spread") == 0  # a population std of one value
    if learned.get("spread") is not None and not one_seed:
        text += f" ± {_number(learned['spread'], percent)}"
    model = f"{learned['model']}, " if learned.get("model") else ""
    diverged = f"; {learned['diverged']} episode(s) diverged" if learned.get("diverged") else ""
    return f"{text} ({model}n={learned['n']}{diverged})"


def _ceiling_cell(ceiling: dict[str, Any] | None) -> str:
    if not ceiling:
        return "-"
    seeds = f" ± {ceiling['spread']:.3f}" if ceiling["n"] > 1 else ""
    diverged = f"; {ceiling['diverged']} episode(s) diverged" if ceiling.get("diverged") else ""
    diverged += f"; {ceiling['fell']} episode(s) fell" if ceiling.get("fell") else ""
    return (f"{ceiling['mean']:.3f}{seeds} (n={ceiling['n']}; its controller alone {ceiling['controller_alone']:.4f}, "
            f"{ceiling['gain']:+.4f}{', saturated' if ceiling['saturated'] else ''}; "
            f"{ceiling['seconds_per_step']:.3f} s per control step{diverged})")


def _baseline_cell(baseline: dict[str, Any] | None, percent: bool) -> str:
    if baseline is None:
        return "-"
    text = _number(baseline.get("value"), percent)
    extra = ", ".join(x for x in (baseline.get("name"), baseline.get("note")) if x)
    return f"{text} ({extra})" if extra else text


def _steps(steps: list[int] | None) -> str:
    if not steps:
        return "-"
    low, high = steps
    return f"{low:,}" if low == high else f"{low:,}-{high:,}"


def _when(snapshot: dict[str, Any]) -> str:
    start, end = utc(snapshot.get("started")), utc(snapshot.get("finished"))
    if not start or not end:
        return "not recorded"
    if start.date() == end.date():
        return f"{start:%Y-%m-%d %H:%M}-{end:%H:%M} UTC"
    return f"{start:%Y-%m-%d %H:%M} to {end:%Y-%m-%d %H:%M} UTC"


def _machine(snapshot: dict[str, Any]) -> str:
    parts = []
    if snapshot.get("machine_label"):
        parts.append(snapshot["machine_label"])
    recorded = []
    if snapshot.get("hosts"):
        recorded.append(f"host {', '.join(snapshot['hosts'])}")
    if snapshot.get("platforms"):
        recorded.append(", ".join(snapshot["platforms"]))
    if snapshot.get("devices"):
        recorded.append(f"device {', '.join(snapshot['devices'])}")
    versions = snapshot.get("versions") or {}
    if versions.get("python") or versions.get("torch"):
        recorded.append("Python " + "/".join(versions.get("python") or ["?"]) + ", torch "
                        + "/".join(versions.get("torch") or ["?"]))
    if recorded:
        resumed = snapshot.get("resumed")
        parts.append("run.json: " + "; ".join(recorded)
                     + (f" ({resumed} of the runs resumed another run's checkpoint: its machine is listed too)"
                        if resumed else ""))
    return ". ".join(parts) if parts else "not recorded"


def _link(earlier: dict[str, str], page_dir: Path = PAGE.parent) -> str:
    """A link from the page to ``earlier``: {link: a repository path with an optional #anchor, section}."""
    path, _, anchor = earlier["link"].partition("#")
    relative = Path(path).relative_to(page_dir) if Path(path).is_relative_to(page_dir) else Path("..") / path
    section = f', "{earlier["section"]}"' if earlier.get("section") else ""
    return f"[{path}{section}]({relative.as_posix()}{'#' + anchor if anchor else ''})"


def _engine_reward(entry: dict[str, Any]) -> str:
    if entry["engine"] is None and entry["reward"] is None:
        metric = (entry.get("options") or {}).get("metric")
        return "no engine or reward (recognition" + (f"; the metric: test {metric})" if metric else ")")
    return f"engine `engine={entry['engine']}`, reward `reward={entry['reward']}`"


def _status(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> str:
    if snapshot is None:
        return "not run on this machine yet"
    return f"{snapshot['runs']} runs, {_when(snapshot)}"


def _thesis_cell(entry: dict[str, Any], row: dict[str, Any]) -> str:
    """The thesis' number for a row: the snapshot's (imitation), else the catalogue's per-row value."""
    if row.get("thesis") not in (None, "-"):
        return str(row["thesis"])
    rows = (entry.get("thesis") or {}).get("rows") or {}
    known = rows.get(row["key"])
    if not known:
        return "-"
    baseline = f"; thesis baseline {known['baseline']}" if known.get("baseline") else ""
    return f"{known['value']} ({known['model']}{baseline})"


def run_fact_lines(entry: dict[str, Any], snapshot: dict[str, Any]) -> list[str]:
    """What the snapshot's runs were: when, where, from which commit, how they differ from the command
    and from the thesis' setting, and where the entry is explained."""
    lines: list[str] = []
    ran_engine = ", ".join(snapshot.get("engine") or []) or "-"
    ran_reward = ", ".join(snapshot.get("reward") or []) or "-"
    differs = []
    if entry["engine"] is not None and snapshot.get("engine") != [entry["engine"]]:
        differs.append(f"engine {ran_engine}")
    if entry["reward"] is not None and snapshot.get("reward") != [entry["reward"]]:
        differs.append(f"reward {ran_reward}")
    uncovered = uncovered_overrides(entry["command"], snapshot.get("overrides") or {})
    steps = [r["steps"] for r in snapshot["rows"] if r.get("steps")]
    budget = f"; {_steps([min(s[0] for s in steps), max(s[1] for s in steps)])} steps per trained run" if steps else ""
    skipped = snapshot.get("skipped") or {}
    left = f"; left out: {', '.join(f'{n} ({why})' for why, n in skipped.items())}" if skipped else ""
    commits = ", ".join(snapshot.get("git") or ["-"])
    dirty = " (+: with uncommitted changes)" if "+" in commits else ""
    lines += [f"- **Ran**: {snapshot['runs']} runs, {_when(snapshot)}{budget}; git {commits}{dirty}{left}",
              f"- **Machine**: {_machine(snapshot)}",
              f"- **Run folders**: {', '.join('outputs/' + f for f in snapshot['folders'])} "
              f"(snapshot [docs/results/{entry['id']}.json](results/{entry['id']}.json))"]
    labels = {row["key"]: row["label"] for row in snapshot["rows"]}
    for group in snapshot.get("earlier_rows") or []:  # options.keep_earlier_rows: rows whose runs are elsewhere
        lines.append(f"- **Rows from earlier runs** ({', '.join(labels.get(k, k) for k in group['keys'])}): "
                     f"{_when(group)}; git {', '.join(group.get('git') or ['-'])}; "
                     f"{', '.join('outputs/' + f for f in group.get('folders') or [])} in the checkout that ran them "
                     f"({group.get('machine_label') or 'machine not recorded'}), not here: kept from the snapshot")
    if differs or uncovered:
        lines.append(f"- **The runs differ from the command**: {'; '.join(differs + uncovered)}")
    if snapshot.get("differences"):  # computed when the snapshot was made (aslexp.results.differences)
        source = f"; {snapshot['differences_source']}" if snapshot.get("differences_source") else ""
        lines += difference_lines(f"**Differences from the thesis' setting** (`{snapshot['differences_from']}` "
                                  f"composed alone; generated from the runs' configs{source})",
                                  snapshot["differences"])
    unrun = unrun_values(entry["command"], entry["overlay"], snapshot.get("overrides") or {})
    if unrun:
        lines.append(f"- **Not run of what the command sweeps**: {', '.join(unrun)} (the numbers below "
                     f"are of the runs that were)")
    lines.append(f"- **How it was run, and what it shows**: {_link(entry['earlier'])}")
    lines.append("")
    return lines


def baseline_columns(snapshot: dict[str, Any]) -> list[tuple[str, str]]:
    """The (kind, label) of every baseline the snapshot's rows hold, in their order."""
    return list(dict.fromkeys((b["kind"], b["label"]) for r in snapshot["rows"] for b in r["baselines"]))


def generic_table_lines(snapshot: dict[str, Any], entry: dict[str, Any], percent: bool) -> list[str]:
    """The generic table: a row per snapshot row (the thesis, each baseline, aslexp's number, extras,
    the ceiling, the steps)."""
    lines: list[str] = []
    columns = baseline_columns(snapshot)
    extras = list(dict.fromkeys(k for r in snapshot["rows"] for k in (r.get("extra") or {})))
    learned = [r["learned"] for r in snapshot["rows"] if r.get("learned")]
    whats = sorted({str(x.get("what")) for x in learned})
    kinds = sorted({str(x.get("spread_kind")) for x in learned})
    what = (f"aslexp, {whats[0] if len(whats) == 1 else 'per row'} "
            f"(mean ± {kinds[0] if len(kinds) == 1 else 'spread: ' + '; '.join(kinds)})")
    what = next((x["header"] for x in learned if x.get("header")), what)  # recognition: aslexp.results.recognition
    header = [snapshot.get("row_name") or "", "thesis", *[f"{kind}: {label}" for kind, label in columns], f"**{what}**",
              *extras]
    ceiling = next((r["ceiling"]["label"] for r in snapshot["rows"] if r.get("ceiling")), None)
    if ceiling:
        header.append(f"ceiling: {ceiling}")
    has_steps = any(r.get("steps") for r in snapshot["rows"])
    if has_steps:
        header.append("steps")
    lines += ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    for row in snapshot["rows"]:
        by_label = {(b["kind"], b["label"]): b for b in row["baselines"]}
        cells = [row["label"], _thesis_cell(entry, row), *[_baseline_cell(by_label.get(c), percent) for c in columns],
                 f"**{_learned(row['learned'], percent, planned=bool(row.get('ceiling')))}**",
                 *[_number((row.get("extra") or {}).get(k), percent) for k in extras]]
        if ceiling:
            cells.append(_ceiling_cell(row.get("ceiling")))
        if has_steps:
            cells.append(_steps(row.get("steps")))
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return lines


def render_entry(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> list[str]:
    """An entry's section: title, note, the facts of its runs, the generic table (one row per snapshot
    row: the thesis, each baseline, aslexp's number, extras, the ceiling, the steps), the seeds above
    each baseline, the scores under other rewards and the figures."""
    options = entry.get("options") or {}
    percent = bool(options.get("percent"))
    beside = "T" + entry["beside"][1:] if entry["beside"].startswith("thesis") else entry["beside"]
    lines = [f'<a id="{entry["id"]}"></a>', "", f"## {beside}: {entry['title']}", ""]
    if snapshot is not None and entry.get("note"):  # what the folders cannot say, e.g. a default changed since
        lines += [f"**Note**: {entry['note']}", ""]
    thesis = (entry.get("thesis") or {}).get("source", "-")
    job, _ = command_overrides(entry["command"])
    overlay = f"`experiment={entry['overlay']}`" if entry["overlay"] else "no overlay (the job's defaults)"
    lines += [f"- **Beside**: {entry['beside']}; the thesis' number: {thesis}",
              f"- **Overlay, engine, reward**: {overlay} (`aslexp {job}`), {_engine_reward(entry)}",
              *command_lines(entry["command"])]
    if snapshot is None:
        lines += [f"- **Not run on this machine yet**: no run folders under outputs/ "
                  f"({', '.join('outputs/' + f for alt in entry['runs'] for f in alt['folders'])}) and no snapshot. "
                  f"Earlier numbers, typed before this page: {_link(entry['earlier'])}", ""]
        return lines
    lines += run_fact_lines(entry, snapshot)
    lines += generic_table_lines(snapshot, entry, percent)
    columns = baseline_columns(snapshot)
    quantity = snapshot.get("quantity") or ""
    lines += ["", f"Numbers: {quantity}{' in %' if percent else ''}; the thesis' in its own units.", ""]
    lines += _seeds_above(snapshot, columns)
    lines += _score_tables(snapshot, columns, percent)
    for figure in entry.get("figures") or []:  # drawn from the same run folders (its caption says how)
        lines += figure_lines(figure)
    return lines


def figure_lines(figure: dict[str, str]) -> list[str]:
    """A plot and its caption: the image (its alt text the caption's first clause) and, below it, the
    whole caption as a paragraph, which the page shows where an alt text is not."""
    alt = figure["caption"].split(";")[0].strip()
    return [f"![{alt}]({_relative_to_page(figure['path'])})", "", f"*Plot*: {figure['caption']}", ""]


def command_lines(command: str) -> list[str]:
    """The entry's command as its list item: inline, or a shell block of lines joined by ``\\`` where it
    is longer than :data:`COMMAND_LINE` (the shell reads the same words)."""
    said = "- **Command** (re-runs it into the folder this page reads first):"
    if len(command) <= COMMAND_LINE:
        return [f"{said} `{command}`"]
    lines, current = [], ""
    for word in _shell_words(command):
        if current and len(current) + 1 + len(word) > WIDTH - 8:
            lines.append(current)
            current = word
        else:
            current = f"{current} {word}" if current else word
    lines.append(current)
    ends = [" \\"] * (len(lines) - 1) + [""]
    body = [f"  {'' if i == 0 else '  '}{line}{end}" for i, (line, end) in enumerate(zip(lines, ends))]
    return [said, "  ```sh", *body, "  ```"]


def _shell_words(command: str) -> list[str]:
    """The command's words as typed: split at spaces outside quotes, the quotes kept."""
    words, current, quote = [], "", ""
    for char in command:
        if quote:
            quote = "" if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char == " ":
            if current:
                words.append(current)
            current = ""
            continue
        current += char
    return words + ([current] if current else [])


def difference_lines(heading: str, differences: list[str]) -> list[str]:
    """A list item ``heading`` with one sub-item per difference, at most :data:`MAX_DIFFERENCES` of them
    (the rest counted in the last: the snapshot holds them all)."""
    shown = list(differences)
    if len(shown) > MAX_DIFFERENCES:
        rest = len(shown) - MAX_DIFFERENCES + 1
        shown = shown[:MAX_DIFFERENCES - 1] + [f"and {rest} more (the snapshot lists them all)"]
    return [f"- {heading}:", *[f"  - {line}" for line in shown]]


def with_table(entry: dict[str, Any], snapshot: dict[str, Any] | None, table: list[str],
               legend: list[str]) -> list[str]:
    """:func:`render_entry`'s lines with ``table`` and ``legend`` in place of its generic table and its
    line of numbers (a report kind's own table)."""
    lines = render_entry(entry, snapshot)
    if snapshot is None:
        return lines
    start = next((i for i, line in enumerate(lines) if line.startswith("| ")), None)
    end = next((i for i, line in enumerate(lines) if line.startswith("Numbers:")), None)
    if start is None or end is None:
        return lines
    return lines[:start] + table + [""] + legend + lines[end + 2:]


def _seeds_above(snapshot: dict[str, Any], columns: list[tuple[str, str]]) -> list[str]:
    """Per row and baseline, how many seeds' last evaluations end above it (k/n): which baselines
    the learned policies pass, and which they fall below, seed by seed."""
    rows = [r for r in snapshot["rows"] if (r.get("learned") or {}).get("values")]
    if not rows or not columns:
        return []
    header = [snapshot.get("row_name") or "", *[f"{kind}: {label}" for kind, label in columns]]
    lines = ["Seeds whose last evaluation ends above each baseline:", "",
             "| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        values = [v for v in row["learned"]["values"] if v is not None]
        by_label = {(b["kind"], b["label"]): b for b in row["baselines"]}
        cells = [row["label"]]
        for column in columns:
            base = (by_label.get(column) or {}).get("value")
            cells.append("-" if base is None else f"{sum(v > base for v in values)}/{len(values)}")
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return lines + [""]


def _score_tables(snapshot: dict[str, Any], columns: list[tuple[str, str]], percent: bool) -> list[str]:
    """The same rows scored under each other reward the runs also scored (``report.score_rewards``:
    the same episodes, e.g. under the authors' code weights beside Table 5.2)."""
    names = list(dict.fromkeys(k for r in snapshot["rows"] for k in (r["learned"].get("scores") or {})))
    lines = []
    for name in names:
        header = [snapshot.get("row_name") or "", *[f"{kind}: {label}" for kind, label in columns],
                  f"**aslexp, last evaluation under `reward={name}` (mean ± std over seeds)**"]
        lines += [f"The same episodes scored under `reward={name}`:", "",
                  "| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
        for row in snapshot["rows"]:
            by_label = {(b["kind"], b["label"]): b for b in row["baselines"]}
            score = (row["learned"].get("scores") or {}).get(name)
            cells = [row["label"], *[_number((by_label.get(c) or {}).get("scores", {}).get(name), percent) for c in columns],
                     f"**{_learned(score, percent)}**" if score else "-"]
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
        lines.append("")
    return lines


def _relative_to_page(path: str, page_dir: Path = PAGE.parent) -> str:
    """A repository path (docs/img/x.png) as the page links it (img/x.png)."""
    import os

    return Path(os.path.relpath(path, page_dir)).as_posix()


HEADER = """# Results

<!-- Generated by `aslexp report --results`: do not edit (edit conf/results.yaml or the generator). -->

This page is generated, not typed: `aslexp report --results` (src/aslexp/results/)
reads the catalogue [conf/results.yaml](../conf/results.yaml), summarises every result whose run folders
are under `outputs/` into a snapshot `docs/results/<id>.json` (numbers, the folders, when and where they
ran), keeps the snapshots of results whose folders are not here, and renders this page from the
snapshots alone (`aslexp report --results --render-only` renders it again, byte for byte). Per result:
the thesis' number, the no-learning and simple baselines under the same reward or metric, aslexp's
number (the LAST evaluation of each trained policy, mean ± spread over seeds; for recognition the
model chosen by validation, over splits or seeds), the engine and reward, the one command that re-runs
it, and when and on what it ran. A result not run on this machine says so and links the numbers typed
before this page.
"""


# A word that would start a block of its own at the head of a line (a list item, a heading, a quote,
# a table row, a fence, HTML, a setext underline): never the first word of a wrapped line.
_BLOCK_START = re.compile(r"([-+*]|\d{1,9}[.)]|#{1,6}|>.*|\|.*|=+|-+|`{3,}.*|~{3,}.*|<.*)")
_WHOLE = re.compile(r"`[^`]*`|!?\[[^\]]*\]\([^)\s]*\)")  # a code span, a link or an image: never broken
_ITEM = re.compile(r"(\s*)([-*+] |\d{1,9}[.)] )?")


def _words(text: str) -> list[str]:
    """``text`` split at spaces, code spans and links kept whole."""
    words, current, at = [], "", 0
    while at < len(text):
        whole = _WHOLE.match(text, at)
        if whole:
            current += whole.group(0)
            at = whole.end()
        elif text[at] == " ":
            if current:
                words.append(current)
            current = ""
            at += 1
        else:
            current += text[at]
            at += 1
    return words + ([current] if current else [])


def _wrap_line(line: str, width: int) -> list[str]:
    head = _ITEM.match(line)
    prefix = head.group(0)
    indent = " " * len(prefix) if head.group(2) else head.group(1)  # a list item's text column
    lines, length = [[]], len(prefix)
    for word in _words(line[len(prefix):]):
        if lines[-1] and length + 1 + len(word) > width:
            lines.append([word])
            length = len(indent) + len(word)
        else:
            length += (1 if lines[-1] else 0) + len(word)
            lines[-1].append(word)
    for before, after in zip(lines, lines[1:]):  # a wrapped line must not read as the start of another block
        while _BLOCK_START.fullmatch(after[0]) and len(before) > 1:
            after.insert(0, before.pop())
    return [prefix + " ".join(lines[0])] + [indent + " ".join(words) for words in lines[1:]]


def wrap(lines: list[str], width: int = WIDTH) -> list[str]:
    """The page's prose wrapped at ``width`` (list items continue under their text); headings, tables,
    HTML and fenced blocks as they are."""
    out, fenced = [], False
    for line in lines:
        if line.lstrip().startswith("```"):
            fenced = not fenced
        if fenced or line.lstrip().startswith("```") or len(line) <= width or line.startswith(("|", "#", "<")):
            out.append(line)
        else:
            out += _wrap_line(line, width)
    return out


def render(catalogue: list[dict[str, Any]], snapshots: Path) -> str:
    """The page from the catalogue and the snapshots (no run folder is read), each entry drawn by its
    report kind."""
    found = {entry["id"]: read_snapshot(snapshot_path(snapshots, entry["id"])) for entry in catalogue}
    lines = [HEADER, "| result | beside | overlay | engine | reward | ran |", "|---|---|---|---|---|---|"]
    for entry in catalogue:
        snapshot = found[entry["id"]]
        lines.append(f"| [{_cell(entry['title'])}](#{entry['id']}) | {_cell(entry['beside'])} | "
                     f"{f'`{o}`' if (o := entry['overlay']) else '-'} | {entry['engine'] or '-'} | {entry['reward'] or '-'} | "
                     f"{_cell(_status(entry, snapshot))} |")
    lines.append("")
    for entry in catalogue:
        own = report_kind(entry["report"]).render or render_entry
        lines += own(entry, found[entry["id"]])
    return "\n".join(wrap("\n".join(lines).split("\n"))).rstrip("\n") + "\n"


def write_results(catalogue_path: Path, outputs: Path, snapshots: Path, page: Path,
                  render_only: bool = False) -> dict[str, Any]:
    """Update the snapshots from ``outputs`` (unless ``render_only``) and write the page."""
    catalogue = load_catalogue(catalogue_path)
    done = {} if render_only else update(catalogue, outputs, snapshots)
    text = render(catalogue, snapshots)
    atomic_write_text(page, text)
    return {"entries": done, "page": str(page), "text": text}
