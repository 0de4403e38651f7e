"""``--version`` prints the installed version; the version is read only when asked for."""

from __future__ import annotations

import subprocess
import sys

import pytest

import biplanar_reg
from biplanar_reg.cli import main


def test_version_flag_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"biplanar-reg {biplanar_reg.__version__}"


def test_unknown_attribute_of_the_package_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        biplanar_reg.no_such_name  # noqa: B018


def test_importing_the_cli_and_a_registration_does_not_read_the_version():
    code = (
        "import biplanar_reg, biplanar_reg.cli, biplanar_reg.cases.run\n"
        "print('__version__' in vars(biplanar_reg))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
