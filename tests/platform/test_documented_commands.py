"""The commands of the pages whose commands run for hours or on a GPU (BENCHMARKS.md, docs/imitation.md,
docs/imitation_upper_body.md, docs/recognition.md, docs/extraction.md) are accepted as written.

A job's overrides compose, for every value the command sweeps, and pass the config check the job
runs at its edge (``aslexp.jobs.validation``); a tool's, a benchmark script's and a module's
arguments parse with the program's own parser (argparse stops right after parsing). So a renamed
option, key, overlay or sweep file is caught here. The pages whose commands run as written on tiny
budgets are tested elsewhere: README and how-tos (tests/extraction/test_howto_commands.py,
tests/tuning/test_docs_commands.py), docs/sweeps.md (the latter), docs/engines.md
(tests/imitation/test_engines_doc.py); the extraction commands' behaviour: tests/extraction.
"""

from __future__ import annotations

import argparse
import os
import re
import runpy
import shlex
import sys
from pathlib import Path

import pytest
from doc_commands import bash_lines, override_variants

from aslexp import cli

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "BENCHMARKS.md", *(ROOT / "docs" / name for name in
                                   ("imitation.md", "imitation_upper_body.md", "recognition.md", "extraction.md"))]
# Lines that are not the project's commands, and why they are not parsed here.
NOT_PARSED = {
    "bash scripts/": "the setup scripts: CI runs them (.ci/run), and tests/platform/test_wheel_install.py",
    "mkdir ": "shell", "cp ": "shell",
    'python -c "import pickle': "the ids conversion: tests/platform/test_hostile_files.py runs it",
}
# Values the pages leave to the shell or to the reader.
SHELL = {"$OUT": "/tmp/out", "$SLURM_ARRAY_TASK_ID": "0", "$SLURM_ARRAY_TASK_COUNT": "2"}


def documented() -> list[tuple[str, str]]:
    """(page, command) for every command of PAGES, shell variables the page sets substituted."""
    out = []
    for page in PAGES:
        variables = dict(SHELL)
        for line in bash_lines(page):
            assignment = re.fullmatch(r"([A-Z_]+)=(\S+)", line)
            if assignment:
                variables["$" + assignment[1]] = assignment[2]
                continue
            for name in sorted(variables, key=len, reverse=True):
                line = line.replace("${" + name[1:] + "}", variables[name]).replace(name, variables[name])
            if not line.startswith(tuple(NOT_PARSED)):
                out.append((page.name, line))
    return out


COMMANDS = documented()


class _Parsed(BaseException):
    """Raised by the patched ``parse_args`` once a program's arguments are parsed (a BaseException:
    no program's ``except Exception`` turns it into an error line)."""


@pytest.fixture
def parse_only(monkeypatch):
    parse_args = argparse.ArgumentParser.parse_args

    def parse_and_stop(self, args=None, namespace=None):
        raise _Parsed(parse_args(self, args, namespace))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_and_stop)


def _words(command: str) -> list[str]:
    words = shlex.split(re.sub(r"\[(--[^\]]*)\]", r"\1", command))  # `[--option value]`: the option given
    while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):  # PYTHONPATH=src python ...
        words.pop(0)
    return [re.sub(r"<[^>/]+>", "FOLDER", w) for w in words]  # outputs/.../<sweep>


def _accepted(run, capsys) -> None:
    try:
        run()
    except _Parsed:
        return
    except SystemExit as stop:
        pytest.fail(f"refused (exit {stop.code}): {capsys.readouterr().err.strip()}")
    pytest.fail("the program returned without parsing its arguments")


@pytest.fixture(autouse=True)
def _environment_put_back():
    """A program run in this process may set variables for itself (bench/imitation_env.py:
    OMP_NUM_THREADS=1); its own process would have taken them with it."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)


@pytest.mark.parametrize(("page", "command"), COMMANDS, ids=[f"{p}:{c[:70]}" for p, c in COMMANDS])
def test_every_long_running_documented_command_is_accepted_as_written(page, command, parse_only, monkeypatch,
                                                                     capsys):
    words = _words(command)
    monkeypatch.chdir(ROOT)
    if words[0] == "aslexp" and words[1] in cli._jobs():
        _composes(words[1], [w for w in words[2:] if w not in ("-m", "--multirun")])
    elif words[0] == "aslexp":
        assert words[1] in cli._TOOLS, f"{page}: {command}: no such aslexp command"
        module, function, _ = cli._TOOLS[words[1]]
        _accepted(lambda: getattr(__import__(module, fromlist=[function]), function)(words[2:]), capsys)
    elif words[:2] == ["python", "-m"]:
        monkeypatch.setattr(sys, "argv", [words[2], *words[3:]])
        monkeypatch.delitem(sys.modules, words[2], raising=False)  # run_module runs it afresh
        _accepted(lambda: runpy.run_module(words[2], run_name="__main__", alter_sys=True), capsys)
    elif words[0] == "python" and words[1].startswith("bench/"):
        script = ROOT / words[1]
        assert script.is_file(), f"{page}: {command}: no {words[1]}"
        monkeypatch.setattr(sys, "argv", [str(script), *words[2:]])
        _accepted(lambda: runpy.run_path(str(script), run_name="__main__"), capsys)
    else:
        pytest.fail(f"{page}: {command}: a command this test does not know; parse it here or say in "
                    "NOT_PARSED why not")


def _composes(job: str, overrides: list[str]) -> None:
    from hydra import compose, initialize_config_dir
    from hydra.core.hydra_config import HydraConfig

    from aslexp.jobs.validation import check_config
    from aslexp.paths import CONF_DIR

    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        for variant in override_variants(overrides):
            cfg = compose(job, overrides=variant, return_hydra_config=True)
            HydraConfig.instance().set_config(cfg)  # ${hydra:job.num} in a value
            check_config(job, cfg)


def test_the_pages_commands_are_all_read():
    """Every kind of line is read: a new page's block or command form is not skipped unseen."""
    kinds = {(c.split()[0] if not c.startswith("PYTHONPATH") else "python") for _, c in COMMANDS}
    assert kinds == {"aslexp", "python"}, kinds
    assert len(COMMANDS) >= 50 and {p for p, _ in COMMANDS} == {p.name for p in PAGES}
