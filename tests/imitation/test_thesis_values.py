"""The thesis' numbers used by the imitation configs and reports, checked against ../shared/THESIS.md
itself (skipped where that file is absent): a transcription slip fails here."""

from __future__ import annotations

import re

import pytest

from aslexp.reports.thesis_report import THESIS_TABLE_6_7
from . import thesis_values as T


@pytest.fixture(scope="module")
def thesis(data_root):
    path = data_root.parent / "THESIS.md"
    if not path.is_file():
        pytest.skip(f"THESIS.md not found beside the data root ({path})")
    return path.read_text(encoding="utf-8")


def table(text: str, heading: str) -> list[list[str]]:
    """The rows (cells stripped, header and rule dropped) of the first table after ``heading``."""
    start = text.index(heading)
    rows = []
    for line in text[start:].splitlines()[1:]:
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip("|").split("|")])
        elif rows:
            break
    return [r for r in rows[1:] if not set("".join(r)) <= set("-: ")]


def number(cell: str) -> float:
    cell = cell.replace("−", "-").replace("**", "").strip()
    return float(re.match(r"-?[\d.]+(e-?\d+)?", cell).group(0))


def numbers(cell: str) -> list[float]:
    return [number(x) for x in re.findall(r"[−-]?[\d.]+(?:e-?\d+)?", cell.split("(")[0].replace("−", "-"))]


def test_table_5_2(thesis):
    rows = {r[0]: (number(r[1]), number(r[2])) for r in table(thesis, "### 3.3 Table 5.2")}
    assert rows == {"pose": T.TABLE_5_2["pose"], "velocity": T.TABLE_5_2["velocity"],
                    "end effectors": T.TABLE_5_2["end_effector"], "root": T.TABLE_5_2["root"]}


@pytest.mark.parametrize("heading, columns, values", [
    ("### 4.5 Table 6.4", ["default", "run1", "run2", "run3"], T.TABLE_6_4),
    ("### 4.6 Table 6.5", ["run1", "run2", "run3", "run4"], T.TABLE_6_5),
])
def test_k_factor_tables(thesis, heading, columns, values):
    rows = table(thesis, heading)[:4]  # k_p,b, k_p,h, k_v,b, k_v,h
    got = {col: tuple(number(r[i + 1]) for r in rows) for i, col in enumerate(columns)}
    assert got == {k: tuple(float(x) for x in v) for k, v in values.items()}


def test_table_d1_best_row(thesis):
    row = table(thesis, "### 3.5 Best PPO setting")[0]
    keys = ["batch_size", "gamma", "learning_rate", "log_std_init", "n_epochs", "n_steps", "ortho_init", "weight_decay"]
    got = {k: (row[i] == "true") if k == "ortho_init" else number(row[i]) for i, k in enumerate(keys)}
    assert got == T.TABLE_D1_BEST


@pytest.mark.parametrize("heading, values", [("### 4.4 Table 6.3", T.TABLE_6_3), ("### 4.7 Table 6.6", T.TABLE_6_6)])
def test_upper_body_ppo_tables(thesis, heading, values):
    row = table(thesis, heading)[0]
    assert [int(x) for x in row[0].split(",")] == values["hidden"]
    assert [number(c) for c in row[1:]] == [values[k] for k in ("learning_rate", "n_steps", "batch_size", "log_std",
                                                                "gamma", "n_epochs")]


def test_search_spaces(thesis):
    t53 = {r[0].split(" [")[0].split(" (")[0]: r[1] for r in table(thesis, "### 3.4 Table 5.3")}
    assert numbers(t53["learning rate"]) == T.TABLE_5_3["learning_rate"]
    assert numbers(t53["number of steps"]) == T.TABLE_5_3["n_steps"]
    assert numbers(t53["weight decay"]) == T.TABLE_5_3["weight_decay"]
    assert numbers(t53["batch size"]) == T.TABLE_5_3["batch_size"]
    assert numbers(t53["discount factor"]) == T.TABLE_5_3["gamma"]
    assert numbers(t53["log std dev"]) == T.TABLE_5_3["log_std_init"]
    assert numbers(t53["number of epochs"]) == T.TABLE_5_3["n_epochs"]
    assert t53["orthogonal initialisation"] == "true, false"
    t62 = {r[0]: r[1] for r in table(thesis, "### 4.3 Table 6.2")}
    assert {k: numbers(v) for k, v in t62.items()} == {
        "learning rate": T.TABLE_6_2["learning_rate"], "number of steps": T.TABLE_6_2["n_steps"],
        "batch size": T.TABLE_6_2["batch_size"], "log std dev": T.TABLE_6_2["log_std"],
        "discount factor": T.TABLE_6_2["gamma"], "number of epochs": T.TABLE_6_2["n_epochs"]}
    grid = re.search(r"k\^\{p,h\} ∈ \{([^}]*)\} x k\^\{v,h\} ∈ \{([^}]*)\}", thesis)
    assert numbers(grid.group(1)) == T.K_GRID["k_p,h"] and numbers(grid.group(2)) == T.K_GRID["k_v,h"]


def test_authors_code_settings(thesis):
    section = thesis[thesis.index("### 10.1"):]
    assert f"**{T.AUTHORS_ENVS_UPPER_BODY} environments**" in section
    for group, (kp, kd) in T.UPPER_BODY_GAINS.items():
        name = {"shoulder": "shoulders", "elbow": "elbows"}.get(group, group)
        if group in ("wrist", "fingers"):
            assert f"wrists and all 30 finger joints {kp:g} / {kd:g}" in section
        else:
            assert f"{name} {kp:g} / {kd:g}" in section, group


def test_the_texts_upper_body_controller(thesis):
    """THESIS.md 4.9 (Table 6.7's controller) and 4.1: DeepMimic's body gains with the arms' kd re-tuned,
    the chapter-5 hand's gains (3.1) for the hands; the code's body gains (10.1) carry the same arms' kd."""
    kd = T.UPPER_BODY_ARM_KD_TEXT
    kp_h, kd_h = T.HAND_GAINS_TEXT
    run1, run2 = (next(r for r in table(thesis, "### 4.9 Which settings") if r[0].startswith(c))
                  for c in ("Run 1", "Run 2"))
    assert run1[3] == (f"DeepMimic body gains with shoulder k_d {kd['shoulder']:g}, elbow k_d {kd['elbow']:g}; "
                       f"hand k_p {kp_h:g}, k_d {kd_h:g}")
    assert run2[3] == "same"
    s41 = thesis[thesis.index("### 4.1"):thesis.index("### 4.2")]
    assert "**DeepMimic for the body**, of **chapter 5 for the hands**" in s41
    assert f"shoulder k_d 40 → {kd['shoulder']:g}, elbow k_d 30 → {kd['elbow']:g}" in s41
    assert f"best **k_p = {kp_h:g}, k_d = {kd_h:g}**" in thesis[thesis.index("### 3.1"):thesis.index("### 3.2")]
    assert {g: T.UPPER_BODY_GAINS[g][1] for g in kd} == kd
    # the wrists: neither the chapter-5 hand nor DeepMimic's body has an actuated one (the text is silent)
    assert "wrist not mobile" in thesis[thesis.index("### 3.1"):thesis.index("### 3.2")]
    assert "the original body has no actuated wrist" in thesis


def test_table_6_7_in_the_report(thesis):
    rows = {r[0].split()[0]: r[1:] for r in table(thesis, "### 4.8 Table 6.7")}
    for sign, (run1, run1_std, run2, run2_std) in THESIS_TABLE_6_7.items():
        assert numbers(rows[sign][0]) == [run1, run1_std] and numbers(rows[sign][1]) == [run2, run2_std], sign
