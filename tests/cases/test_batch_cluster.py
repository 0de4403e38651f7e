"""``batch --cluster slurm|pbs|sge``: dask-jobqueue clusters, tested without a batch system.

The job scripts dask-jobqueue generates are checked for the ``--cluster-option`` values (nothing
is submitted); the errors (dask-jobqueue missing, unknown options, no ``sbatch``, a rejected
submission) are one line with exit 2; and one case runs end to end through a stand-in ``sbatch``
that starts the job script on this machine.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
from pathlib import Path

import pytest

from biplanar_reg.cases import _cluster
from biplanar_reg.cli import main
from biplanar_reg.simulate import write_synthetic_case

ROOT = Path(__file__).resolve().parents[2]

SCRIPTS = {
    "slurm": ["#SBATCH -p short", "#SBATCH -A lab", "#SBATCH -t 02:00:00", "#SBATCH --mem=8G"],
    "pbs": ["#PBS -q short", "#PBS -A lab", "#PBS -l walltime=02:00:00", "mem=7630MB"],
    "sge": ["#$ -q short", "#$ -l h_rt=02:00:00"],
}


@pytest.mark.parametrize("kind", sorted(SCRIPTS))
def test_job_script_carries_the_cluster_options(kind):
    pytest.importorskip("dask_jobqueue")
    options = ["queue=short", "walltime=02:00:00", "memory=8GB", "dashboard-address=:0"]
    options += ["account=lab"] if kind != "sge" else []
    extra = {"slurm": "--gres=gpu:1", "pbs": "-l place=excl", "sge": "-pe smp 1"}[kind]
    options += [f"job_extra_directives={extra}", "job-script-prologue=module load python"]
    cluster = _cluster.make_cluster(kind, options)
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    for line in [*SCRIPTS[kind], extra, "module load python"]:
        assert line in script, (line, script)
    # defaults: one core, one worker process, one thread: one case at a time per job
    assert "--nthreads 1" in script and "distributed.cli.dask_worker" in script
    assert sys.executable in script


def test_cluster_option_errors():
    pytest.importorskip("dask_jobqueue")
    with pytest.raises(ValueError, match="quene=short: not an option of SLURMCluster; did you"):
        _cluster.parse_options("slurm", ["quene=short"])
    with pytest.raises(ValueError, match="expected KEY=VALUE, got 'queue'"):
        _cluster.parse_options("slurm", ["queue"])
    with pytest.raises(ValueError, match="walltime=2: given twice"):
        _cluster.parse_options("slurm", ["walltime=1", "walltime=2"])
    with pytest.raises(ValueError, match="--cluster: expected one of slurm, pbs, sge, got 'lsf'"):
        _cluster.parse_options("lsf", [])
    got = _cluster.parse_options("pbs", ["cores=4", "nanny=false", "job-extra-directives=-V"])
    assert got == {"cores": 4, "nanny": False, "job_extra_directives": ["-V"]}


def _one_line_error(capsys, argv: list[str]) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_cluster_errors_are_one_line(tmp_path, capsys, monkeypatch):
    case = tmp_path / "c0"
    case.mkdir()
    batch = ["batch", str(case), "--out", str(tmp_path / "out")]
    err = _one_line_error(capsys, [*batch, "--jobs", "2"])
    assert "--jobs and --cluster-option need --cluster" in err
    assert "--workers is for local runs" in _one_line_error(
        capsys, [*batch, "--cluster", "slurm", "--workers", "2"]
    )
    with monkeypatch.context() as m:
        m.setitem(sys.modules, "dask_jobqueue", None)  # not installed
        err = _one_line_error(capsys, [*batch, "--cluster", "slurm"])
        assert "--cluster slurm needs dask-jobqueue: pip install dask-jobqueue" in err
    pytest.importorskip("dask_jobqueue")
    assert "--jobs: must be >= 1 and <= 10000, got 0" in _one_line_error(
        capsys, [*batch, "--cluster", "pbs", "--jobs", "0"]
    )
    assert "did you mean queue" in _one_line_error(
        capsys, [*batch, "--cluster", "slurm", "--cluster-option", "queu=short"]
    )
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    monkeypatch.setenv("PATH", str(bin_dir))
    assert "sbatch not found on PATH" in _one_line_error(capsys, [*batch, "--cluster", "slurm"])
    (bin_dir / "qsub").write_text("#!/bin/sh\necho 'qsub: Unknown queue' >&2\nexit 1\n")
    (bin_dir / "qsub").chmod(0o755)
    err = _one_line_error(capsys, [*batch, "--cluster", "pbs", "--cluster-option", "queue=x"])
    assert "--cluster pbs: job submission failed: qsub: Unknown queue" in err
    assert not list((tmp_path / "out").glob(".batch*.lock"))


# a stand-in sbatch: runs the job script here, in the background, in its own session
FAKE_SBATCH = """#!/bin/sh
dir=$(dirname "$0")
n=$(ls "$dir" | grep -c '^job\\.')
cp "$1" "$dir/job.$n.sh"
setsid sh "$dir/job.$n.sh" > "$dir/job.$n.log" 2>&1 < /dev/null &
echo $! >> "$dir/jobs.txt"
echo "Submitted batch job $!"
"""
FAKE_SCANCEL = """#!/bin/sh
kill -TERM -- "-$1" 2>/dev/null || kill -TERM "$1" 2>/dev/null
exit 0
"""


def test_cluster_runs_cases_through_the_batch_system(tmp_path, capsys, monkeypatch):
    pytest.importorskip("dask_jobqueue")
    case = write_synthetic_case(tmp_path / "c0", 0, image_size=(192, 192), silhouettes=False)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, text in (("sbatch", FAKE_SBATCH), ("scancel", FAKE_SCANCEL)):
        (bin_dir / name).write_text(text)
        (bin_dir / name).chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    out = tmp_path / "out"
    argv = ["--json", "batch", str(case), "--out", str(out), "--cluster", "slurm", "--jobs", "1"]
    argv += ["--cluster-option", "walltime=00:10:00", "--cluster-option", "dashboard_address=:0"]
    argv += ["--no-report"]  # the batch system is under test, not the case report
    try:
        capsys.readouterr()
        assert main(argv) == 0
        assert json.loads(capsys.readouterr().out)["counts"]["done"] == 1
        assert (out / "c0" / "result.json").is_file()
        script = (bin_dir / "job.0.sh").read_text()
        assert "#SBATCH -t 00:10:00" in script and "--nthreads 1" in script
    finally:  # the jobs' sessions, in case scancel did not end them
        jobs = bin_dir / "jobs.txt"
        for pid in jobs.read_text().split() if jobs.exists() else []:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(int(pid), signal.SIGKILL)
