"""``aslexp retarget``: an extraction folder's landmarks retargeted and scored end to end against the person.

    aslexp retarget                                              # the six videos, conf/retargeting/default.yaml
    aslexp retarget retargeting.filter.kind=savgol retargeting.filter.window=0.3
    aslexp retarget -m +sweeps=retargeting                       # the Optuna search over the retargeting

Each video of ``retarget.keypoints`` (a folder ``aslexp extract VIDEO...`` wrote) is retargeted with
``retargeting`` (:func:`aslexp.pose.retarget.retarget_landmarks`: the landmark filter, the angles'
smoothing) into the run folder's ``motions/``, and its upper-body motion performed once from its
start as ``aslexp signing`` performs it (:func:`aslexp.jobs.signing.score_clip`: the reference
played kinematically, the controller alone). Per video, ``retarget.json`` holds the held
handshapes' flicker (finger-angle std where the source hand holds its shape) and the keypoint
errors to the person; the objective, to minimise, is the mean over the videos of the hands' DTWp
(shoulder widths) at ``retarget.stage``. ``retarget.png`` shows the finger angles over time.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from aslexp.errors import ConfigError
from aslexp.jobs._common import job_main, run_guarded, seed_everything, to_dict

log = logging.getLogger("aslexp.retarget")

RESULT_FILE = "retarget.json"
FIGURE = "retarget.png"
STAGES = ("reference", "controller")


def retargeting_options(section: dict[str, Any]) -> dict[str, Any]:
    """``retargeting`` -> the keyword arguments of :func:`aslexp.pose.retarget.retarget_landmarks`."""
    from aslexp.pose.landmark_filter import retargeting_options as parse

    try:
        return parse(section)
    except ValueError as error:
        raise ConfigError(str(error)) from None


def video_ids(folder: Path, limit: int | None) -> list[str]:
    """The videos of an extraction folder: those with keypoints and world landmarks."""
    if not (folder / "world").is_dir():
        raise ConfigError(f"retarget.keypoints={folder}: no world/ folder; expected a folder `aslexp extract "
                          "VIDEO... --out DIR` wrote")
    ids = sorted(p.stem for p in (folder / "world").glob("*.npy") if (folder / f"{p.stem}.npy").is_file())
    if not ids:
        raise ConfigError(f"retarget.keypoints={folder}: no video with both <id>.npy and world/<id>.npy")
    return ids if limit is None else ids[: int(limit)]


def _hands(report: dict) -> dict[str, Any]:
    """The upper-body report's per-hand flicker (the hands MediaPipe saw)."""
    return {side: report[f"{side}_hand"]["handshape_flicker"] for side in ("right", "left")
            if isinstance(report.get(f"{side}_hand"), dict) and "handshape_flicker" in report[f"{side}_hand"]}


def retarget_and_score(cfg: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """The job without Hydra: every video retargeted, performed and scored; the summary."""
    from aslexp.data.root import resolve_data_root
    from aslexp.files import write_json
    from aslexp.jobs.signing import score_clip
    from aslexp.pose.landmarks import load_world
    from aslexp.pose.retarget import retarget_landmarks
    from aslexp.pose.source_frame import record_source

    settings = cfg["retarget"]
    if settings.get("stage") not in STAGES:
        raise ConfigError(f"retarget.stage={settings.get('stage')!r}: expected one of {', '.join(STAGES)}")
    options = retargeting_options(cfg["retargeting"])
    folder = Path(settings["keypoints"])
    ids = video_ids(folder, settings.get("limit"))
    data_root = resolve_data_root(cfg.get("data_root"))
    motions = out_dir / "motions"
    clips, started = [], time.perf_counter()
    for i, vid in enumerate(ids):
        result = retarget_landmarks(load_world(folder, vid), motions, data_root=data_root, **options)
        record_source(result, folder / f"{vid}.npy", motions, data_root)
        clip: dict[str, Any] = {"video": vid, "fps": result["fps"], "frames": result["frames"]}
        hand = result.get("hand", {})
        if hand.get("status") == "ok":
            clip["hand_motion_flicker"] = hand["handshape_flicker"]
        body = result.get("upper_body", {})
        if body.get("status") != "ok":
            clip["why"] = body.get("error", "no upper-body motion")
        else:
            clip["flicker"] = _hands(body)
            scored = score_clip(cfg, Path(body["path"]), data_root, None, {})
            clip.update(rewards=scored["rewards"], diverged=scored["diverged"])
            stages = scored.get("stages") or {}
            clip["hands_dtwp"] = {s: (stages.get(s) or {}).get("hands", {}).get("dtwp") for s in STAGES}
            clip["body_dtw_mje"] = {s: (stages.get(s) or {}).get("body", {}).get("dtw_mje") for s in STAGES}
        clips.append(clip)
        rate = (i + 1) / (time.perf_counter() - started)
        log.info("retarget: %d/%d videos (%.2f videos/s, ETA %.0f s): %s hands DTWp %s, flicker %s", i + 1, len(ids),
                 rate, (len(ids) - i - 1) / rate, vid, clip.get("hands_dtwp"), clip.get("flicker"))
    summary = summarise(clips, settings["stage"])
    out = {"keypoints": str(folder), "retargeting": cfg["retargeting"], "stage": settings["stage"], "clips": clips,
           **summary, "seconds": round(time.perf_counter() - started, 1)}
    write_json(out_dir / RESULT_FILE, out)
    if cfg.get("plots", True):
        from aslexp.viz.retargeting import plot_finger_angles

        plot_finger_angles(finger_panels(motions, clips), out_dir / FIGURE)
    return out


def finger_panels(motions: Path, clips: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """retarget.png's panels: per scored video, the finger angles of the hand held longest."""
    from aslexp.pose.retarget import finger_columns
    from aslexp.sim.motion import load_motion

    panels = []
    for clip in clips:
        if not clip.get("flicker"):
            continue
        side = max(clip["flicker"], key=lambda s: clip["flicker"][s]["held_frames"])
        flicker = clip["flicker"][side]
        motion = load_motion(motions / "upper_body" / f"{clip['video']}.txt")
        panels.append({"angles": motion.frames[:, finger_columns(side)], "dt": float(motion.dt[0]),
                       "held": flicker.get("held", []),
                       "title": f"{clip['video']}, {side} hand: flicker {flicker['flicker_rad']} rad over "
                                f"{flicker['held_frames']} held frames; hands DTWp: reference "
                                f"{clip['hands_dtwp']['reference']}, controller {clip['hands_dtwp']['controller']}"})
    return panels


def _mean(values: list) -> float | None:
    kept = [float(v) for v in values if v is not None]
    return round(sum(kept) / len(kept), 5) if kept else None


def summarise(clips: list[dict], stage: str) -> dict[str, Any]:
    """Means over the videos: the hands' DTWp per stage, the flicker of every seen hand; the objective."""
    scored = [c for c in clips if "hands_dtwp" in c]
    if not scored:
        raise ConfigError("retarget: no video gave an upper-body motion to score (each clip's `why` says why)")
    hands = {s: _mean([c["hands_dtwp"][s] for c in scored]) for s in STAGES}
    body = {s: _mean([c["body_dtw_mje"][s] for c in scored]) for s in STAGES}
    flicker = _mean([f["flicker_rad"] for c in scored for f in c["flicker"].values()])
    if hands[stage] is None:
        raise ConfigError(f"retarget: no video's hands were scored at stage {stage}")
    return {"videos": len(clips), "scored": len(scored), "hands_dtwp": hands, "body_dtw_mje": body,
            "flicker_rad": flicker, "objective": hands[stage]}


@job_main("retarget")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns the objective (the hands' mean DTWp: lower is better)."""
    def body(run) -> float:
        seed_everything(int(cfg.seed))
        result = retarget_and_score(to_dict(cfg), run.dir)
        run.save_metrics({k: result[k] for k in ("videos", "scored", "hands_dtwp", "body_dtw_mje", "flicker_rad",
                                                 "objective", "stage")})
        log.info("retarget: hands DTWp %s (objective, %s), flicker %s rad over %d videos", result["objective"],
                 result["stage"], result["flicker_rad"], result["scored"])
        return result["objective"]

    return run_guarded("retarget", cfg, body)


if __name__ == "__main__":
    main()
