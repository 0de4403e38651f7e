"""``batch --shard I/N`` and ``batch --merge``: a job array splits a study without a scheduler.

End to end on three small synthetic cases: shards 1/2 and 2/2 run at once on one output folder
(with the cases in different orders), then the merge; the merged summary equals a full run's.
"""

from __future__ import annotations

import csv
import json
import os
import random
import subprocess
import sys
from pathlib import Path

import pytest

from biplanar_reg.cases._shards import parse_shard, shard_names
from biplanar_reg.cases.batch import merge_batch
from biplanar_reg.cli import main
from biplanar_reg.simulate import write_synthetic_case

ROOT = Path(__file__).resolve().parents[2]
#: the shards and merges are under test, not the case reports (most of a small case's time)
NO_REPORT = "--no-report"


@pytest.fixture(scope="module")
def three_cases(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("shards")
    return [
        write_synthetic_case(root / f"c{i}", i, image_size=(192, 192), silhouettes=False)
        for i in range(3)
    ]


def _summary(out: Path) -> tuple[list[dict], dict, list[list[str]], list[list[str]]]:
    """summary.json rows and stats, summary.csv and summary_stats.csv, without the timings."""
    doc = json.loads((out / "summary.json").read_text())
    rows = [{k: v for k, v in r.items() if k != "seconds"} for r in doc["rows"]]
    stats = {k: v for k, v in doc["stats"].items() if k != "seconds"}
    table = list(csv.reader((out / "summary.csv").open()))
    col = table[0].index("seconds")
    table = [r[:col] + r[col + 1 :] for r in table]
    stat_rows = [r for r in csv.reader((out / "summary_stats.csv").open()) if r[0] != "seconds"]
    return rows, stats, table, stat_rows


def _cli(*args: str) -> subprocess.Popen:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    cmd = [sys.executable, "-m", "biplanar_reg.cli", *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def test_shards_then_merge_equal_a_full_run(three_cases, tmp_path, capsys):
    cases = [str(c) for c in three_cases]
    full, out = tmp_path / "full", tmp_path / "sharded"
    # the two shards of a job array run at the same time on one output folder (shard 2/2 is
    # given the cases in another order), while a full run of the same cases goes elsewhere
    shards = [
        _cli("batch", *cases, "--out", str(out), "--shard", "1/2", "--workers", "1", NO_REPORT),
        _cli("batch", *reversed(cases), "--out", str(out), "--shard", "2/2", NO_REPORT),
    ]
    assert main(["batch", *cases, "--out", str(full), "--workers", "1", NO_REPORT]) == 0
    for p in shards:
        stdout, stderr = p.communicate(timeout=120)
        assert p.returncode == 0, stderr
    assert "1 done (0 skipped), 0 failed, 0 not run, of 1 (shard 2/2)" in stdout
    names = sorted(p.name for p in out.iterdir())
    assert names == ["c0", "c1", "c2", "summary.shard-1-of-2.json", "summary.shard-2-of-2.json"]
    shard = json.loads((out / "summary.shard-1-of-2.json").read_text())
    assert shard["shard"] == {"index": 1, "count": 2}
    assert shard["study_cases"] == ["c0", "c1", "c2"]
    assert [r["case"] for r in shard["rows"]] == ["c0", "c2"]  # positions 0 and 2
    capsys.readouterr()
    assert main(["--json", "batch", "--merge", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["counts"] == {"total": 3, "done": 3, "failed": 0, "skipped": 0, "missing": 0}
    assert doc["summary"] == str(out / "summary.html") and (out / "summary.html").is_file()
    assert _summary(out) == _summary(full)  # same cases, same metrics, same statistics
    # a shard rerun skips its complete cases; merging again gives the same summary
    assert main(["batch", *cases, "--out", str(out), "--shard", "2/2", NO_REPORT]) == 0
    assert merge_batch(out).counts == {**doc["counts"], "skipped": 1}
    assert _summary(out)[0] == [{**r, "ran": r["case"] != "c1"} for r in _summary(full)[0]]


def test_merge_reports_missing_shards_and_failed_cases(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    row = {"case": "c1", "status": "failed", "reason": "c1/case.toml: bad", "seconds": 0.1}
    doc = {
        "format": "biplanar-reg/batch-summary@1",
        "shard": {"index": 2, "count": 2},
        "study_cases": ["c0", "c1", "c2"],
        "rows": [{**row, "ran": True}],
        "started": 10.0,
        "finished": 12.5,
    }
    (out / "summary.shard-2-of-2.json").write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["batch", "--merge", str(out)]) == 1  # cases not run: the study is incomplete
    assert "0 done (0 skipped), 1 failed, 2 not run, of 3" in capsys.readouterr().out
    rows = {r["case"]: r for r in csv.DictReader((out / "summary.csv").open())}
    assert rows["c0"]["status"] == rows["c2"]["status"] == "not run"
    assert rows["c0"]["reason"] == "shard 1/2 wrote no summary"
    assert rows["c1"]["status"] == "failed" and rows["c1"]["reason"] == "c1/case.toml: bad"
    assert json.loads((out / "summary.json").read_text())["wall_seconds"] == 2.5


def test_shard_selection_is_by_sorted_name():
    names = [f"k{i:03d}" for i in range(10)]
    shuffled = random.Random(1).sample(names, len(names))
    parts = [shard_names(shuffled, (i, 3)) for i in (1, 2, 3)]
    assert parts[0] == ["k000", "k003", "k006", "k009"]
    assert sorted(sum(parts, [])) == names  # disjoint and complete
    assert shard_names(names, (12, 20)) == []  # more shards than cases: an empty shard
    assert parse_shard(" 3 / 100 ") == (3, 100) and parse_shard((1, 1)) == (1, 1)
    for bad in ("0/3", "4/3", "3", "a/b", "1/0", "-1/2", "1/2/3", (2, 1), (True, 2)):
        with pytest.raises(ValueError, match="--shard: expected I/N"):
            parse_shard(bad)


def _one_line_error(capsys, argv: list[str]) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_bad_batch_options_are_one_line_errors(tmp_path, capsys):
    case = tmp_path / "c0"
    case.mkdir()
    out = tmp_path / "out"
    for n in ("0", "5000"):
        assert "--workers: must be >= 1 and <= 1024, got " + n in _one_line_error(
            capsys, ["batch", str(case), "--out", str(out), "--workers", n]
        )
    assert "--shard: expected I/N" in _one_line_error(
        capsys, ["batch", str(case), "--out", str(out), "--shard", "0/4"]
    )
    assert "runs nothing: drop CASES, --shard" in _one_line_error(
        capsys, ["batch", str(case), "--merge", str(out), "--shard", "1/2"]
    )
    assert "give CASES... and --out DIR" in _one_line_error(capsys, ["batch", str(case)])
    assert "not a folder" in _one_line_error(capsys, ["batch", "--merge", str(tmp_path / "x")])
    out.mkdir()
    assert "no shard summaries" in _one_line_error(capsys, ["batch", "--merge", str(out)])
    base = {"format": "biplanar-reg/batch-summary@1", "rows": [], "started": 0, "finished": 1}
    for i, n in ((1, 2), (1, 3)):
        doc = {**base, "shard": {"index": i, "count": n}, "study_cases": ["c0", "c1"]}
        (out / f"summary.shard-{i}-of-{n}.json").write_text(json.dumps(doc))
    assert "shards of different splits" in _one_line_error(capsys, ["batch", "--merge", str(out)])
    (out / "summary.shard-1-of-3.json").write_text("{not json")
    assert "not a readable shard summary" in _one_line_error(capsys, ["batch", "--merge", str(out)])
    doc = {**base, "shard": {"index": 1, "count": 3}, "study_cases": ["../../etc"]}
    (out / "summary.shard-1-of-3.json").write_text(json.dumps(doc))
    assert "not a shard summary" in _one_line_error(capsys, ["batch", "--merge", str(out)])
