"""The documentation site (mkdocs.yml, docs/): it builds with --strict, every page of its nav is in it, and the
API reference generated from the docstrings holds what the code documents."""

import os
import subprocess
import sys

import pytest
import yaml

from conftest import REPO

#: the sub-packages with an API page of their own (docs/api/<name>.md, a nested one's page named by its last
#: part), one ``::: module`` directive per module
API_PACKAGES = ("geometry", "interference", "planning", "machining", "cnc", "process", "roughing", "records",
                "nodes", "nodes.programs", "ros", "apps", "bench")


def nav_pages(nav):
    """Every Markdown file the nav names, in order."""
    for entry in nav:
        value = next(iter(entry.values())) if isinstance(entry, dict) else entry
        if isinstance(value, list):
            yield from nav_pages(value)
        else:
            yield value


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built as `make docs` builds it, into a directory of its own; its build log."""
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(out)], cwd=REPO, env=env,
                         capture_output=True, text=True, timeout=300)
    return out, run


def test_the_site_builds_strictly_without_a_warning(site):
    out, run = site
    log = run.stdout + run.stderr
    assert run.returncode == 0, log
    assert "WARNING" not in log, log
    assert (out / "index.html").is_file()


def test_every_page_of_the_nav_is_built(site):
    out, _ = site
    config = yaml.safe_load((REPO / "mkdocs.yml").read_text())
    pages = list(nav_pages(config["nav"]))
    assert "index.md" in pages and "api/cnc.md" in pages
    for page in pages:
        assert (REPO / "docs" / page).is_file(), page
        assert (out / page).with_suffix(".html").is_file(), page      # use_directory_urls: false
    # and no page of docs/ is left out of the nav (mkdocs would only say so)
    files = sorted(str(p.relative_to(REPO / "docs")) for p in (REPO / "docs").rglob("*.md"))
    assert sorted(pages) == files


def test_the_post_processor_page_documents_write_program(site):
    out, _ = site
    text = (out / "api" / "cnc.html").read_text()
    assert 'id="edm_planner.cnc.post"' in text
    assert 'id="edm_planner.cnc.post.write_program"' in text
    assert "The NC program of one or more electrodes" in text      # its docstring, not only its name


def test_every_module_of_a_subpackage_is_on_its_api_page():
    """A module added to a sub-package needs its ``::: edm_planner.<package>.<module>`` line on the page."""
    for package in API_PACKAGES:
        page = (REPO / "docs" / "api" / f"{package.split('.')[-1]}.md").read_text()
        for module in sorted((REPO / "edm_planner" / package.replace(".", "/")).glob("*.py")):
            if module.stem == "__main__":          # `python -m` glue, documented with its package
                continue
            name = f"edm_planner.{package}" + ("" if module.stem == "__init__" else f".{module.stem}")
            assert f"::: {name}\n" in page, f"{name} is not on docs/api/{package}.md"


@pytest.mark.slow
def test_the_readme_python_example_plans_and_writes_a_certified_plan(tmp_path):
    """The README's *From Python* block, run as a user would from the repository's directory layout: it plans
    the channel (SUCCESS, certified) and writes the export it names."""
    import re

    code = re.search(r"```python\n(.*?)```", (REPO / "README.md").read_text(), re.S).group(1)
    (tmp_path / "config").symlink_to(REPO / "config")
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=500)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.startswith("SUCCESS certified path"), run.stdout
    plan = yaml.safe_load((tmp_path / "out" / "plan0" / "plan.json").read_text())
    assert plan["error_code"] == "SUCCESS" and plan["channel"] == 0
