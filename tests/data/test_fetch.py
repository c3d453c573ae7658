import shutil

import pytest

from aslexp.data.fetch import (FetchError, build_manifest, check_data, fetch_data, load_manifest,
                               sha256_of)

SUBSET = ["asl-lex/1.0/SignData.csv", "wlasl/nslt/nslt_100.json",
          "keypoints/wlasl-mediapipe-pose/01457.npy"]


def test_embedded_manifest_matches_shared_sums(data_root):
    assert load_manifest() == build_manifest(data_root / "SHA256SUMS")
    entries = {e["path"]: e for e in load_manifest()["files"]}
    assert len(entries) == 322
    assert sum(p.startswith("keypoints/") for p in entries) == 291
    assert entries["wlasl/WLASL_v0.3.json"]["zip_member"] == "WLASL_v0.3.json"
    assert "049c4b41b47c979d21405d253eedb44f780df45b/WLASL_v0.3.zip" in entries["wlasl/WLASL_v0.3.json"]["urls"][0]


def test_check_shared_data_all_ok(data_root):
    report = check_data(data_root)
    assert report.all_ok and len(report.ok) == 322


def _copy_subset(data_root, target):
    for relpath in SUBSET:
        (target / relpath).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(data_root / relpath, target / relpath)


def test_check_subset_with_corruption(tmp_path, data_root):
    _copy_subset(data_root, tmp_path)
    corrupted = tmp_path / SUBSET[1]
    corrupted.write_bytes(corrupted.read_bytes()[:-10] + b"0000000000")
    report = check_data(tmp_path, only=["asl-lex/1.0", "wlasl/nslt", "keypoints"])  # embedded sums
    assert report.mismatched == [SUBSET[1]]
    assert set(report.ok) == {SUBSET[0], SUBSET[2]}
    assert "asl-lex/1.0/Key.csv" in report.missing and len(report.missing) == 1 + 3 + 290
    assert not report.all_ok


def test_fetch_skips_present_files(tmp_path, data_root):
    _copy_subset(data_root, tmp_path)
    report = fetch_data(tmp_path, only=[SUBSET[0], SUBSET[2]], timeout=2)
    assert report.present == [SUBSET[0], SUBSET[2]] and not report.fetched


def test_fetch_offline_names_what_failed(tmp_path, data_root):
    _copy_subset(data_root, tmp_path)
    path = SUBSET[0]
    manifest = {"files": [{"path": path, "sha256": "0" * 64,
                           "urls": ["https://no-such-host.invalid/asl-lex/SignData.csv"]}]}
    with pytest.raises(FetchError) as error:
        fetch_data(tmp_path, manifest=manifest, timeout=2)
    assert "no-such-host.invalid" in str(error.value) and path in str(error.value)
    assert sha256_of(tmp_path / path) == sha256_of(data_root / path)  # nothing overwritten
