"""The documentation site builds in strict mode, offline, with every check, error and public name on its page.

``mkdocs build --strict`` (what ``make docs`` runs) fails on any warning: a broken link or anchor, a reference
mkdocstrings cannot resolve, a docstring griffe cannot parse, and a public name of ``dualcal`` without its
numpydoc docstring (``docs/gen_pages.py`` warns of it).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    pytest.importorskip("mkdocs", reason="the docs extra builds the site (make test installs it)")
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true"}
    res = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                          "-d", str(out)], cwd=ROOT, env=env, capture_output=True, text=True)
    return res, out


def test_the_site_builds_in_strict_mode_without_a_warning(site):
    res, out = site
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-4000:]
    assert not [line for line in log.splitlines() if line.startswith(("WARNING", "ERROR"))], log[-4000:]
    assert (out / "index.html").is_file() and (out / "getting-started.html").is_file()


def test_every_check_and_error_has_its_entry_on_the_built_page(site):
    from dualcal import messages

    html = (site[1] / "checks.html").read_text(encoding="utf-8")
    for name in [*messages.CHECKS, *messages.ERRORS, *messages.LINES]:
        anchor = messages.page_of(name).split("#")[1]
        assert f'id="{anchor}"' in html, name


def test_every_public_name_is_in_the_api_reference(site):
    import dualcal

    html = (site[1] / "reference" / "api.html").read_text(encoding="utf-8")
    missing = [name for name in dualcal.__all__ if name != "__version__" and f"dualcal.{name}" not in html]
    assert not missing


def test_the_site_works_offline(site):
    """No page loads anything from the network (no web fonts, scripts or styles), and search is built in."""
    out = site[1]
    remote = re.compile(r"""<(?:script|link|img|iframe)[^>]+(?:src|href)=["']https?://""")
    pages = [p for p in out.rglob("*.html")]
    assert len(pages) > 20
    assert [str(p.relative_to(out)) for p in pages if remote.search(p.read_text(encoding="utf-8"))] == []
    assert (out / "search" / "search_index.js").is_file()          # the offline plugin's index, for file://
    assert (out / "figures" / "practice-roll.jpg").is_file() and (out / "examples" / "advise.html").is_file()


def test_a_public_function_without_its_numpydoc_docstring_is_a_warning():
    """What the build warns of (and so fails on): no docstring, no Parameters, no Returns, an undocumented method."""
    pytest.importorskip("mkdocs_gen_files", reason="the docs extra")
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        import gen_pages
    finally:
        sys.path.remove(str(ROOT / "docs"))

    def bare(x):
        return x

    def summary_only(x: int) -> int:
        """Twice x."""
        return 2 * x

    def documented(x: int) -> int:
        """Twice x.

        Parameters
        ----------
        x : int
            A number.

        Returns
        -------
        int
            Twice it.
        """
        return 2 * x

    class Thing:
        """A thing."""

        def method(self):
            return 1

    assert gen_pages._docstring_problems("bare", bare) == ["bare has no docstring"]
    assert len(gen_pages._docstring_problems("summary_only", summary_only)) == 2
    assert gen_pages._docstring_problems("documented", documented) == []
    assert gen_pages._docstring_problems("Thing", Thing) == ["Thing.method has no docstring"]
