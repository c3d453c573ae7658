"""Matching WLASL glosses to ASL-LEX entries.

Rule (it reproduces the published overlap exactly: ASL-LEX 1.0: 802 glosses / 10,051 videos;
ASL-LEX 2.0: 1,383 glosses / 15,911 videos):

    norm(s) = s.strip().lower(), then drop one trailing ``_<digits>`` suffix, then '_' -> ' ',
    then strip.

A WLASL gloss matches a lexicon row when ``norm(gloss)`` equals ``norm(EntryID)`` or
``norm(LemmaID)`` of that row. Near misses are deliberately *not* matched, because matching them
would change the published counts: e.g. WLASL 'ice cream' vs ASL-LEX 'icecream', "don't want" vs
'dont_want' (punctuation and spacing are not normalised).

Several rows can match one gloss (e.g. candy -> candy_1, candy_2; drink -> drink, drink_2;
bathroom -> bathroom, toilet via LemmaID). The row is chosen by the first of:
  1. the row whose EntryID equals the gloss exactly (case-insensitive, ' ' == '_');
  2. rows matched through their EntryID before rows matched only through their LemmaID;
  3. the lowest numeric suffix (no suffix counts as 0, so 'drink' < 'drink_2', 'candy_1' < 'candy_2');
  4. file order.
Each ambiguous gloss is logged at DEBUG, their number at INFO and returned.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass

from aslexp.data.lexicon import Lexicon, LexiconEntry
from aslexp.data.wlasl import Wlasl

log = logging.getLogger(__name__)

_SUFFIX = re.compile(r"_(\d+)$")


def normalise_gloss(text: str) -> str:
    """The matching key of a gloss, EntryID or LemmaID (see the module docstring)."""
    key = _SUFFIX.sub("", text.strip().lower())
    return key.replace("_", " ").strip()


@dataclass(frozen=True)
class GlossMatch:
    gloss: str
    entry: LexiconEntry
    candidates: tuple[str, ...]  # EntryIDs of every matching row, best first


@dataclass(frozen=True)
class MatchResult:
    matches: dict[str, GlossMatch]  # WLASL gloss -> chosen lexicon row
    unmatched: tuple[str, ...]  # WLASL glosses with no lexicon row
    num_videos: int  # WLASL instances whose gloss matched

    @property
    def num_glosses(self) -> int:
        return len(self.matches)

    @property
    def ambiguous(self) -> dict[str, tuple[str, ...]]:
        return {g: m.candidates for g, m in self.matches.items() if len(m.candidates) > 1}


def _rank(gloss: str, entry: LexiconEntry) -> tuple[int, int, int, int]:
    entry_id = entry.entry_id.strip().lower()
    exact = entry_id.replace("_", " ") == gloss.strip().lower().replace("_", " ")
    via_entry = normalise_gloss(entry.entry_id) == normalise_gloss(gloss)
    suffix = _SUFFIX.search(entry_id)
    return (0 if exact else 1, 0 if via_entry else 1, int(suffix.group(1)) if suffix else 0, entry.row)


def lexicon_keys(lexicon: Lexicon) -> dict[str, list[LexiconEntry]]:
    """``normalise_gloss`` of every EntryID and LemmaID -> the rows that have it."""
    rows_by_key: dict[str, list[LexiconEntry]] = {}
    for entry in lexicon.entries:
        for key in {normalise_gloss(entry.entry_id), normalise_gloss(entry.lemma_id)}:
            if key:
                rows_by_key.setdefault(key, []).append(entry)
    return rows_by_key


def match_names(glosses, lexicon: Lexicon) -> tuple[dict[str, GlossMatch], list[str]]:
    """Match gloss names to at most one lexicon row each (rule in the module docstring):
    ({gloss: match}, [glosses with no row])."""
    rows_by_key = lexicon_keys(lexicon)
    matches, unmatched = {}, []
    for gloss in glosses:
        candidates = sorted(rows_by_key.get(normalise_gloss(gloss), []), key=lambda e: _rank(gloss, e))
        if not candidates:
            unmatched.append(gloss)
            continue
        matches[gloss] = GlossMatch(gloss, candidates[0], tuple(e.entry_id for e in candidates))
        if len(candidates) > 1:
            log.debug("gloss %r matches %d %s rows %s; chose %r", gloss, len(candidates),
                      lexicon.name, [e.entry_id for e in candidates], candidates[0].entry_id)  # fmt: skip
    return matches, unmatched


def match_glosses(wlasl: Wlasl, lexicon: Lexicon) -> MatchResult:
    """Match every WLASL gloss to at most one lexicon row (rule in the module docstring)."""
    matches, unmatched = match_names(wlasl.glosses, lexicon)
    num_videos = sum(1 for instance in wlasl.instances if instance.gloss in matches)
    result = MatchResult(matches=matches, unmatched=tuple(unmatched), num_videos=num_videos)
    log.info("WLASL x %s: %d of %d glosses matched (%d videos); %d ambiguous glosses resolved "
             "by exact EntryID > EntryID match > lowest suffix > file order",
             lexicon.name, result.num_glosses, len(wlasl.glosses), num_videos,
             len(result.ambiguous))  # fmt: skip
    return result
