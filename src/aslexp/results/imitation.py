"""The imitation entries of the results page (``report: thesis``, ``scratch``, ``residual``): per
motion, the thesis' number, the no-learning and simple baselines, the learned policies' last
evaluation over seeds, the planner's ceiling where one ran, and the generated differences from
the thesis' setting. The baselines per report:

* ``thesis``: every no-learning baseline of the overlay's ``report.baselines``
  (:func:`aslexp.reports.thesis_report.motion_baselines`, cached beside the runs as the thesis report
  caches them; aslexp's own controllers are the simple baselines) and the thesis' number
  (:func:`aslexp.reports.thesis_report.thesis_number`);
* ``scratch``: the baselines each run measured (metrics.json ``baselines``);
* ``residual``: the comparison rows of :func:`aslexp.reports.residual_report.measured_rows` (the
  controller and the same on a pinned base; the best smoothed reference and constant random
  corrections as simple baselines).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.results.catalogue import command_overrides
from aslexp.results.kinds import ReportKind, register_report
from aslexp.results.snapshots import number
from aslexp.runfile import RUN_FILE
from aslexp.runs.completed import read_json

log = logging.getLogger(__name__)


def _imitation_runs(folders: list[Path]) -> tuple[dict[str, list[dict[str, Any]]], dict[str, int]]:
    """Completed imitation runs under ``folders`` by motion (:func:`aslexp.reports.report.read_runs`),
    and what was left out."""
    from aslexp.reports.report import read_runs

    runs: dict[str, list[dict[str, Any]]] = {}
    skipped: dict[str, int] = {}
    for folder in folders:
        try:
            found = read_runs(folder)
        except FileNotFoundError:
            continue
        for motion, items in found.items():
            for metrics in items:
                info = read_json(Path(metrics["run_dir"]) / RUN_FILE) or {}
                if info.get("status") != "completed":
                    reason = f"status {info.get('status', 'unknown')}"
                    skipped[reason] = skipped.get(reason, 0) + 1
                    continue
                runs.setdefault(motion, []).append(metrics)
    return dict(sorted(runs.items())), skipped


def _thesis_baselines(entry, cfg, motion, items, cache) -> tuple[list[dict[str, Any]], str, float | None]:
    from aslexp.reports.report import ended_early
    from aslexp.reports.thesis_report import baseline_column, motion_baselines, thesis_number

    rows = motion_baselines(cfg, cache, items)
    baselines = [{"label": re.sub(r"^aslexp: ", "aslexp's ", baseline_column(b)),
                  "kind": "simple" if b["aslexp"] else "no-learning",
                  "value": number(b["reward"]), **({"note": ended_early(b)} if ended_early(b) else {}),
                  **({"scores": {k: number(v) for k, v in b["scores"].items()}} if b.get("scores") else {})}
                 for b in rows]
    text, value = thesis_number((cfg.get("report") or {}).get("thesis", "letters"), motion)
    return baselines, text, value


def _scratch_baselines(entry, cfg, motion, items, cache) -> tuple[list[dict[str, Any]], str, float | None]:
    labels = (entry.get("options") or {}).get("baselines") or {}
    names = list(dict.fromkeys(k for m in items for k in m.get("baselines", {})))
    baselines = [{"label": labels.get(k, k), "kind": "no-learning",
                  "value": number(np.mean([m["baselines"][k] for m in items if k in m["baselines"]]))} for k in names]
    return baselines, "-", None


def _residual_baselines(entry, cfg, motion, items, cache) -> tuple[list[dict[str, Any]], str, float | None]:
    from aslexp.reports.residual_report import measured_rows

    base = measured_rows(motion, items, cache)
    settings = (cfg.get("report") or {}).get("residual") or {}
    rows = [{"label": "controller (zero correction)", "kind": "no-learning", "value": number(base["controller"])}]
    if base.get("compare") is not None:
        rows.append({"label": f"same controller, {settings.get('compare_label', 'pinned base')} (nothing slips)",
                     "kind": "no-learning", "value": number(base["compare"])})
    smoothed = base.get("smoothed") or {}
    if smoothed:
        alpha = max(smoothed, key=smoothed.get)
        rows.append({"label": "smoothed reference, best alpha", "kind": "simple", "value": number(smoothed[alpha]),
                     "name": f"alpha {alpha}"})
    chance = base.get("random_corrections")
    if chance:
        rows.append({"label": "constant random corrections, mean", "kind": "simple",
                     "value": number(np.mean(chance["scores"])),
                     "name": f"RMS {chance['rms']:g}, n={len(chance['scores'])}"})
    return rows, "-", None


_BASELINES = {"thesis": _thesis_baselines, "scratch": _scratch_baselines, "residual": _residual_baselines}


def imitation_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """Per motion: the thesis' number, the baselines of the entry's report (see the module docstring) and the learned
    policies' last evaluation, mean ± std over seeds (population std, as the imitation reports);
    the steps of the trained runs. Baselines are cached in ``<folder>/baselines/<motion>.json`` as
    the thesis and residual reports cache theirs."""
    from aslexp.reports.report import learned, run_config
    from aslexp.reports.thesis_report import GLOSSES

    runs, skipped = _imitation_runs(folders)
    # A planner's runs (aslexp.control.mpc) give each motion its ceiling: this entry's own, and those
    # of the folders its options name (options.ceiling_folders: the same reward, controller and rate)
    options = entry.get("options") or {}
    ceilings = _imitation_runs([Path(f) for f in options.get("ceiling_folders") or []])[0]
    # The policies trained on each motion alone (options.per_motion_folders), beside a policy of many
    # motions scored on a motion it never saw (experiment=letters_unseen): the column it is measured against
    per_motion = _imitation_runs([Path(f) for f in options.get("per_motion_folders") or []])[0]
    rows, run_dirs, configs = [], [], []
    for motion, items in runs.items():
        run_dirs += [Path(m["run_dir"]) for m in items]
        configs += [run_config(Path(m["run_dir"])) for m in items]
        first = Path(items[0]["run_dir"])
        folder = next(f for f in folders if first.resolve().is_relative_to(f.resolve()))
        cfg = run_config(first)
        baselines, thesis, thesis_value = _BASELINES[entry["report"]](entry, cfg, motion, items,
                                                                     folder / "baselines" / f"{motion}.json")
        trained = sorted((m for m in items if learned(m)), key=lambda m: (m.get("seed") is None, m.get("seed")))
        last = [float(m["last_eval"]) for m in trained if m.get("last_eval") is not None]
        # The policies before any update (ppo.eval_at_start: the curve's step 0): the level learning starts from.
        untrained = [float(p["eval_reward"]) for m in trained for p in m.get("progress") or []
                     if p.get("step") == 0 and p.get("eval_reward") is not None]
        if untrained:
            baselines = [{"label": "the untrained policy (step 0 of these runs, mean over seeds)", "kind": "no-learning",
                          "value": number(np.mean(untrained))}, *baselines]
        own = [float(m["last_eval"]) for m in per_motion.get(motion, []) if learned(m) and m.get("last_eval") is not None]
        if own:
            baselines.append({"label": options.get("per_motion_label", "the policy trained on this motion alone"),
                              "kind": "learned", "value": number(np.mean(own)),
                              "name": f"± {np.std(own):.4f}, n={len(own)}" if len(own) > 1 else "n=1"})
        names = list(dict.fromkeys(k for m in trained for k in m.get("last_eval_scores") or {}))
        scores = {name: [float(m["last_eval_scores"][name]) for m in trained if name in (m.get("last_eval_scores") or {})]
                  for name in names}
        rows.append({
            "key": motion, "label": f"{motion} ({GLOSSES[motion]})" if motion in GLOSSES else motion,
            "thesis": thesis, "thesis_value": number(thesis_value),
            "baselines": baselines,
            "learned": {"what": "last evaluation", "mean": number(np.mean(last)) if last else None,
                        "spread": number(np.std(last)) if last else None, "spread_kind": "std over seeds",
                        "n": len(last), "unit": "seeds", "values": [number(v) for v in last],
                        "seeds": [m.get("seed") for m in trained],
                        # the last evaluations' episodes that blew up, summed over seeds (None: not recorded)
                        "diverged": (sum(int(m["last_eval_diverged"]) for m in trained)
                                     if trained and all("last_eval_diverged" in m for m in trained) else None),
                        **({"scores": {name: {"mean": number(np.mean(v)), "spread": number(np.std(v)), "n": len(v)}
                                       for name, v in scores.items()}} if scores else {})},
            "steps": [int(min(m["steps"] for m in trained)), int(max(m["steps"] for m in trained))] if trained else None,
            **({"ceiling": ceiling_summary(planned)} if (planned := [m for m in items + ceilings.get(motion, [])
                                                                      if m.get("planner")]) else
               {"ceiling": options["ceiling_rows"][motion]} if motion in (options.get("ceiling_rows") or {}) else {}),
        })
    return {"rows": rows, "run_dirs": run_dirs, "skipped": skipped, "quantity": "mean reward per step",
            "row_name": "motion", **thesis_differences(entry, configs, [m for items in runs.values() for m in items])}


def ceiling_summary(planned: list[dict[str, Any]]) -> dict[str, Any]:
    """A motion's ceiling (:func:`aslexp.reports.thesis_report.ceiling`) as a snapshot stores it,
    labelled with the planner and the controller it plans on."""
    from aslexp.reports.report import run_config
    from aslexp.reports.thesis_report import ceiling

    found = ceiling(planned)
    spec = found["spec"]
    controller = (run_config(Path(planned[0]["run_dir"])).get("controller") or {}).get("name", "?")
    return {"label": f"MPC ({spec['method'].replace('_', ' ')}, horizon {spec['horizon']}, {spec['samples']} "
                     f"samples) on {controller}",
            "mean": number(found["mean"]), "spread": number(found["spread"]), "n": found["n"],
            "controller_alone": number(found["controller_alone"]), "gain": number(found["gain"]),
            "saturated": bool(found["saturated"]), "seconds_per_step": number(found["seconds_per_step"]),
            "diverged": found["diverged"], **({"fell": found["fell"]} if found["fell"] else {})}


def thesis_differences(entry: dict[str, Any], configs: list[dict[str, Any]], metrics: list[dict[str, Any]],
                       runs: dict[str, Any] | None = None) -> dict[str, Any]:
    """The snapshot's ``differences``: how the runs differ from the thesis' setting the catalogue
    names (``thesis.setting``: the overlay that composes it; ``thesis.seeds``), from their composed
    configs (:mod:`aslexp.results.differences`). Empty for an entry that names no setting."""
    from aslexp.results import differences

    thesis = entry.get("thesis") or {}
    if not thesis.get("setting") or not configs:
        return {}
    reference = differences.compose_overlay(command_overrides(entry["command"])[0],
                                            [f"experiment={thesis['setting']}"])
    runs = runs if runs is not None else differences.run_facts(metrics)
    return {"differences": differences.imitation_differences(configs, reference, runs, thesis.get("seeds")),
            "differences_from": f"experiment={thesis['setting']}"}


def recomposed_differences(entry: dict[str, Any], snapshot: dict[str, Any],
                           root: Path | None = None) -> dict[str, Any]:
    """For a kept imitation snapshot made before snapshots carried ``differences`` (its run folders
    gone): the runs' configs recomposed from ``conf/`` at their git commits with their recorded
    overrides (:func:`aslexp.results.differences.configs_at_commits`), the budget and seeds from its
    rows, and the evaluation protocol from the recomposed config (the runs' ``report: scratch`` and
    ``residual`` baselines were measured by the runs under it; ``thesis`` ones at report time from
    phase 0). {} when it cannot be done (no commit, no git)."""
    import subprocess

    from aslexp.results import differences

    commits = [c for c in snapshot.get("git") or [] if c and c != "-"]
    if not (entry.get("thesis") or {}).get("setting") or not commits:
        return {}
    root = root or Path(__file__).resolve().parents[3]  # the repository: src/aslexp/results/ is three below
    job, _ = command_overrides(entry["command"])
    try:
        configs = differences.configs_at_commits(job, snapshot.get("overrides") or {}, commits, root)
    except (subprocess.CalledProcessError, OSError, ValueError) as err:
        log.warning("warning: %s: its runs' configs cannot be recomposed (%s); no differences", entry["id"], err)
        return {}
    ppo, env = configs[0]["ppo"], configs[0]["env"]
    phases = len(ppo.get("eval_phases") or []) or int(ppo.get("eval_episodes", 4))
    steps = [s for r in snapshot["rows"] if r.get("steps") for s in r["steps"]]
    measured_by_runs = entry["report"] in ("scratch", "residual")
    runs = {"steps": steps, "seeds_per_motion": sorted({r["learned"]["n"] for r in snapshot["rows"] if r["learned"].get("n")}),
            "protocols": [((phases, ppo.get("eval_steps")),
                           (phases, ppo.get("eval_steps") / env.get("control_hz", 30)) if measured_by_runs else None)]}
    extra = thesis_differences(entry, configs, [], runs)
    if extra:
        extra["differences_source"] = ("the run folders are gone: their configs recomposed from conf/ at their "
                                       f"commits ({', '.join(sorted({c.rstrip('+') for c in commits}))}) "
                                       "with their overrides")
    return extra


def refresh(entry: dict[str, Any], snapshot: dict[str, Any]) -> dict[str, Any]:
    """A kept snapshot's differences from the thesis, where it has none yet (:func:`recomposed_differences`)."""
    return {} if "differences" in snapshot else recomposed_differences(entry, snapshot)


for _name in ("thesis", "scratch", "residual"):
    register_report(ReportKind(_name, imitation_summary, refresh=refresh,
                               refreshed="differences recomposed from its commits"))
