"""The optional parts (dualcal.extras): a missing extra is one line naming what installs it."""

import sys

import pytest

from dualcal.errors import InputError
from dualcal.extras import EXTRAS, require


@pytest.mark.parametrize("extra", sorted(EXTRAS))
def test_an_installed_extra_is_silent(extra):
    require(extra)          # make test installs every extra


def test_a_missing_extra_names_the_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyarrow", None)          # import pyarrow now raises ImportError
    with pytest.raises(InputError, match=r"batch .* needs pyarrow, which is not installed: pip install 'dualcal\[fleet\]'"):
        require("fleet")


@pytest.mark.parametrize("args", [["board", "8x5", "--square", "30", "-o", "{tmp}/board.pdf"],
                                  ["batch", "{tmp}", "-o", "{tmp}/out"]])
def test_the_commands_say_which_extra_they_need(monkeypatch, tmp_path, run_cli, args):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    res = run_cli(*(a.format(tmp=tmp_path) for a in args))
    assert res.code == 2 and "pip install 'dualcal[report]'" in res.err and len(res.err_lines) == 1, res.err
