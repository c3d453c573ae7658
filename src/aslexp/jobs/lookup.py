"""`aslexp lookup`: one clip's predicted phonology and the ASL-LEX signs that fit it best.

    aslexp lookup FILE model=RUN_DIR [top_k=10] [format=md|html] [frames=START:END]   (FILE: the same as input=FILE)

FILE is a keypoint array (.npy: read by the model's own keypoint source, or as an `aslexp extract`
folder where a layout.json lies beside it), a .pose file (pose-format) or a video (MediaPipe, when
its environment is set up); RUN_DIR is a run folder of `aslexp retrieve retrieval.save_model=all`
(or first_split). ``frames=11:60`` cuts the clip first (1-based, inclusive, as `aslexp extract --frames`
reads it). The clip goes through the model's WLASL-Lex preprocessing, every property's
classifier predicts it, and all lexicon entries are scored as `aslexp retrieve` scores them
(:mod:`aslexp.recognition.lookup`). The run folder gets card.md (or card.html), metrics.json (the
predictions, the top-k, the clip's own sign and its rank where the file names a WLASL video) and
keypoints.png; the terminal gets a short table (stdout). Bad input (a missing or unreadable file, a
run folder without a saved model, keypoints the model's layout cannot be read from, a frame range
outside the clip) is one line naming the file, the field and what was expected, exit 2, refused
before any run folder is made (a video's frame range is checked once it is extracted, in the run).
Docs: docs/recognition.md, "Looking up one clip".
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from aslexp.errors import ConfigError, DataError
from aslexp.jobs._common import JobAbort, job_main, one_line, run_guarded, to_dict

log = logging.getLogger("aslexp.lookup")

CARD = {"md": "card.md", "html": "card.html"}
FIGURE = "keypoints.png"
# Hydra's flags that take the next word as their value: that word is not the input file.
_VALUED_FLAGS = {"-c", "--cfg", "-p", "--package", "-cp", "--config-path", "-cn", "--config-name", "-cd",
                 "--config-dir", "-i", "--info", "--experimental-rerun"}


def positional_input(argv: list[str]) -> list[str]:
    """``aslexp lookup FILE ...`` -> ``aslexp lookup input='FILE' ...``: the one word that is not a
    flag, a flag's value or an override (no ``=``) is the input (quoted for Hydra's grammar)."""
    out, previous, found = [], "", False
    for word in argv:
        plain = (word and not word.startswith(("-", "+", "~")) and "=" not in word
                 and previous not in _VALUED_FLAGS)
        if plain and not found:
            quote = "'" if "'" not in word else '"'
            word, found = f"input={quote}{word}{quote}", True
        out.append(word)
        previous = word
    return out


_KEYS = ("input", "model", "top_k", "format", "data_root", "frames")


def frame_span(frames: Any, given: str) -> tuple[int, int] | None:
    """``frames=START:END`` (`aslexp extract --frames`' syntax: 1-based, inclusive, END -1 or empty
    = to the end) -> (start, end), or None for the whole clip; a VIDEO_ID= prefix must name the input."""
    from aslexp.pose.extract import ExtractionError, parse_frames

    if frames is None:
        return None
    try:
        video_id, start, end = parse_frames(str(frames), f"frames={frames}")
    except ExtractionError as error:
        raise ConfigError(str(error)) from None
    if video_id is not None and video_id != Path(given).stem:
        raise ConfigError(f"frames={frames}: names video id {video_id!r}, not the input's {Path(given).stem!r}; "
                          "expected START:END")
    return start, end


def _settings(cfg: DictConfig | dict) -> tuple[str, str, int, str, Any, tuple[int, int] | None]:
    if isinstance(cfg, DictConfig):  # the job's own keys only (the hydra node does not resolve in a callback)
        plain = {key: to_dict(OmegaConf.select(cfg, key, default=None)) for key in _KEYS}
    else:
        plain = cfg
    given, model = plain.get("input"), plain.get("model")
    if not given:
        raise ConfigError("input=null: expected the clip to look up: `aslexp lookup FILE model=RUN_DIR` (a .npy "
                          "keypoint array, a .pose file or a video)")
    if not model:
        raise ConfigError("model=null: expected the run folder of `aslexp retrieve retrieval.save_model=all` "
                          "(its model/ folder holds the classifiers)")
    top_k = plain.get("top_k")
    if not isinstance(top_k, int) or isinstance(top_k, bool) or top_k < 1:
        raise ConfigError(f"top_k={top_k!r}: expected an integer >= 1")
    card = plain.get("format")
    if card not in CARD:
        raise ConfigError(f"format={card!r}: expected one of {list(CARD)}")
    return str(given), str(model), top_k, card, plain.get("data_root"), frame_span(plain.get("frames"), str(given))


def _root(model, data_root):
    """The data root for the lexicon: ``data_root``, else the one the model was trained with (when
    it exists here), else $ASLEXP_DATA_ROOT or ../shared/data."""
    from aslexp.data.root import resolve_data_root

    if data_root:
        return resolve_data_root(data_root)
    recorded = Path(model.meta.get("data_root") or "")
    return recorded if str(recorded) and recorded.is_dir() else resolve_data_root(None)


def check_inputs(cfg) -> None:
    """What a lookup needs, checked before anything is written: the settings, the input file (for
    keypoints also read and preprocessed; for a video the MediaPipe environment) and the model."""
    from aslexp.recognition.lookup import check_input, load_lookup_model, read_clip

    given, model_dir, _, _, data_root, frames = _settings(cfg)
    kind = check_input(given)
    model = load_lookup_model(model_dir)
    if kind != "video":  # cheap (milliseconds); a video is extracted in the run
        read_clip(given, model, root=_root(model, data_root), frames=frames)


class InputCheck(Callback):
    """Refuse bad input before the run folder is claimed (listed before run_guard in conf/lookup.yaml)."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        if OmegaConf.select(config, "hydra.job.config_name", default=None) != "lookup":
            return
        try:
            check_inputs(config)
        except (ConfigError, DataError, OSError) as error:  # the message names the file (or the key)
            text = str(error) if isinstance(error, (ConfigError, DataError, FileNotFoundError)) else one_line(error)
            raise JobAbort(text.strip().replace("\n", " "), code=2) from None


def lookup(cfg: DictConfig, run) -> None:
    from aslexp.files import write_text
    from aslexp.recognition.lookup import card_html, card_markdown, load_lookup_model, load_table, lookup_clip, \
        read_clip, terminal_lines

    given, model_dir, top_k, card, data_root, frames = _settings(cfg)
    model = load_lookup_model(model_dir)
    root = _root(model, data_root)
    clip = read_clip(given, model, root=root, work_dir=run.dir / "keypoints", frames=frames)
    table, lexicon = load_table(model, root)
    result = lookup_clip(model, clip, table, lexicon, top_k=top_k, root=root)
    figure = None
    try:
        from aslexp.viz.keypoints import plot_keypoint_sequence
    except ImportError as error:  # a node without matplotlib: the card says the rest
        log.warning("no figure (%s)", error)
    else:
        layout = model.layout
        plot_keypoint_sequence(clip.X[0], clip.mask[0], layout.names, layout.edges, model.channels, run.dir / FIGURE,
                               frames=clip.frames, title=f"{Path(given).name}: the model's input ({layout.name}, "
                               f"normalised; {clip.frames} frames), skeletons and wrist paths")
        figure = FIGURE
    text = card_html(result, figure) if card == "html" else card_markdown(result, figure)
    write_text(run.dir / CARD[card], text)
    result["files"] = {"card": CARD[card], **({"figure": figure} if figure else {})}
    run.save_metrics(result)
    print("\n".join(terminal_lines(result)), flush=True)
    log.info("lookup of %s: top sign %s; card %s", Path(given).name, result["top"][0]["entry_id"],
             run.dir / CARD[card])
    return None


@job_main("lookup")
def _main(cfg: DictConfig) -> None:
    return run_guarded("lookup", cfg, lambda run: lookup(cfg, run))


def main() -> None:
    """The job, with a first plain word taken as ``input=``."""
    sys.argv = [sys.argv[0], *positional_input(sys.argv[1:])]
    return _main()


if __name__ == "__main__":
    main()
