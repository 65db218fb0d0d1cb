"""The README's Python code blocks run as they are, one after the other, in an empty folder."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_python_examples_of_the_readme_run(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    assert len(blocks) >= 2
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "readme"}
    for block in blocks:
        exec(compile(block, str(README), "exec"), namespace)
    out = capsys.readouterr().out
    assert "tele fx = " in out and "vertical rig: True" in out
    assert "c0-c7: " in out and "(true 241.9)" in out        # the "Measuring" example ran to its end
    assert (tmp_path / "calib.json").is_file() and len(list((tmp_path / "photos" / "tele").glob("*.jpg"))) == 8
