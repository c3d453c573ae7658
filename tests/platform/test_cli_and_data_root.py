"""The CLI's own surface: help, the data commands, and a clear error for a bad data root."""

from __future__ import annotations


def test_help_lists_jobs_and_tools(aslexp):
    out = aslexp("--help").stdout
    for word in ("recognize", "data", "report", "runs", "sweep"):
        assert word in out


def test_data_check_passes_on_the_shared_data(aslexp):
    out = aslexp("data", "check")
    assert "0 missing, 0 mismatched" in out.stdout


def test_data_fetch_offline_names_what_it_could_not_reach(aslexp, tmp_path):
    proc = aslexp("data", "fetch", "--root", str(tmp_path / "d"), "--timeout", "2", check=False)
    assert proc.returncode == 1
    assert "could not fetch" in proc.stderr and "raw.githubusercontent.com" in proc.stderr


def test_a_missing_data_root_is_a_clear_error(aslexp, tmp_path):
    proc = aslexp("recognize", "experiment=debug", "classifier=logreg",
                  f"data.root={tmp_path / 'nowhere'}", f"hydra.run.dir={tmp_path / 'r'}", check=False)
    assert proc.returncode != 0
    assert "data root" in proc.stderr and "nowhere" in proc.stderr
