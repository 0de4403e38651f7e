"""The command line's last-resort handler: an unexpected exception is one line on stderr and
exit 1, with the traceback only under ``-v``; input errors stay exit 2 (issue 18)."""

from __future__ import annotations

import pytest

import biplanar_reg.cli.calibration as calibration_cli
from biplanar_reg.cli import main

#: The one line of an internal error, for an exception ``KeyError('boom')``.
LINE = "biplanar-reg: internal error: KeyError: 'boom' (run with -v for the traceback)"


@pytest.fixture()
def broken_show(monkeypatch):
    """``calibration show`` raising an exception no handler expects (a bug, not bad input)."""

    def explode(args):
        raise KeyError("boom")

    monkeypatch.setattr(calibration_cli, "_cmd_show", explode)


def test_an_unexpected_exception_is_one_line_and_exit_1(broken_show, capsys, tmp_path):
    rc = main(["calibration", "show", str(tmp_path / "c.txt")])
    out, err = capsys.readouterr()
    assert rc == 1
    assert err.strip() == LINE
    assert "Traceback" not in err and out == ""


@pytest.mark.parametrize("flag", ["-v", "--verbose", "-vv"])
def test_verbose_prints_the_traceback(broken_show, capsys, tmp_path, flag):
    rc = main([flag, "calibration", "show", str(tmp_path / "c.txt")])
    err = capsys.readouterr().err
    assert rc == 1
    assert "Traceback (most recent call last)" in err and "in explode" in err
    assert err.strip().splitlines()[-1] == LINE.replace(" (run with -v for the traceback)", "")


def test_a_multi_line_message_stays_on_one_line(monkeypatch, capsys, tmp_path):
    def explode(args):
        raise RuntimeError("first\nsecond")

    monkeypatch.setattr(calibration_cli, "_cmd_show", explode)
    assert main(["calibration", "show", str(tmp_path / "c.txt")]) == 1
    err = capsys.readouterr().err
    assert err == (
        "biplanar-reg: internal error: RuntimeError: first second (run with -v for the traceback)\n"
    )


def test_input_errors_keep_exit_2(capsys, tmp_path):
    (tmp_path / "c.txt").write_text("image size\n1,x\n")
    assert main(["calibration", "show", str(tmp_path / "c.txt")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "internal error" not in err


@pytest.mark.parametrize(
    ("argv", "hint"),
    [
        (["batch", "c", "--out", "o", "--workerz", "2"], "(did you mean '--workers'?)"),
        (["register", "c", "--outt=x"], "(did you mean '--out'?)"),
        (["regster", "c"], "(did you mean 'register'?)"),
        (["calibration", "conver", "a"], "(did you mean 'convert'?)"),
    ],
)
def test_a_mistyped_option_or_command_gets_a_suggestion(argv, hint, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(hint)


def test_an_unrelated_unknown_option_gets_no_suggestion(capsys):
    with pytest.raises(SystemExit):
        main(["register", "c", "--silhouets", "3"])
    assert "did you mean" not in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["annotate", "preview", "c", "--max-height", "-5", "-o", "p.png"],
            "argument --max-height: must be >= 16 and <= 20000, got -5",
        ),
        (
            ["population", "synth", "t.ply", "--size", "1000000000", "-o", "p"],
            "argument --size: must be >= 1 and <= 100000, got 1000000000",
        ),
        (
            ["ssm", "build", "a", "--variance", "1.5", "-o", "m.npz"],
            "must be > 0 and <= 1, got 1.5",
        ),
        (["population", "synth", "t.ply", "--seed", "-1", "-o", "p"], "<= 4294967295, got -1"),
        (
            ["annotate", "contour", "i.png", "--sigma", "nan", "-o", "x.json"],
            "argument --sigma: expected a finite number, got 'nan'",
        ),
        (
            ["ssm", "densify", "m.npz", "--points", "x", "-o", "d.npz"],
            "expected an integer, got 'x'",
        ),
    ],
)
def test_numeric_options_are_bounded(argv, message, capsys):
    """Reproducers: ``--max-height -5`` was an OpenCV traceback, ``--size 1000000000`` ran."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(message)
