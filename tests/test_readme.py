"""The README is a front door: short, the two set-up commands, links that lead somewhere, and a tour whose every
command runs in the documentation's tests (tests/test_docs_examples.py), the same line on a page."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def test_the_readme_is_short_and_gives_the_two_set_up_commands():
    assert len(README.splitlines()) <= 150
    assert re.search(r"^ +make demo +#", README, re.M) and re.search(r"^ +make test +#", README, re.M)


def test_every_link_and_picture_of_the_readme_exists():
    targets = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README)
    assert targets and not [t for t in targets if not t.startswith("http") and not (ROOT / t).exists()]


def test_every_command_of_the_tour_runs_on_a_page_of_the_docs():
    tour = [line.split("#")[0].strip() for line in README.splitlines() if line.startswith("    dualcal ")]
    run = {line[2:].strip() for page in (ROOT / "docs").rglob("*.md")
           for line in page.read_text(encoding="utf-8").splitlines() if line.startswith("$ dualcal ")}
    assert len(tour) == 5 and not [command for command in tour if command not in run]
