"""The command shell: help for every command, internal errors in one line, --debug."""

import pytest

import dualcal.synthetic.synth as synth_module

COMMANDS = ["detect", "calibrate", "evaluate", "undistort", "rectify", "report", "export", "synth", "pick", "measure"]


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_has_help(run_cli, command):
    res = run_cli(command, "--help")
    assert res.code == 0 and "Usage: dualcal" in res.out


def test_version(run_cli):
    res = run_cli("--version")
    assert res.code == 0 and "dualcal" in res.out


def test_unexpected_errors_are_one_line_and_the_traceback_needs_debug(run_cli, tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(synth_module, "make_truth", broken)
    res = run_cli("synth", tmp_path / "s", "--no-photos")
    assert res.code == 1
    assert res.err_lines == ["dualcal: internal error: ZeroDivisionError: a bug (run again with --debug for the "
                             "traceback)"]
    with pytest.raises(ZeroDivisionError):
        from dualcal.cli import main
        main(["--debug", "synth", str(tmp_path / "s"), "--no-photos"])


def test_unknown_command_is_a_usage_error(run_cli):
    res = run_cli("calibrat")
    assert res.code == 2 and "Traceback" not in res.err


def test_the_package_exposes_its_api():
    import dualcal
    for name in dualcal.__all__:
        assert getattr(dualcal, name) is not None
