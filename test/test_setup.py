"""make setup's installer: every pin installed at its version, and pip's index settings handed to uv.

tools/setup.sh installs requirements.txt and requirements-dev.txt under constraints.txt with uv (pinned in
requirements-setup.txt), or with pip where uv fails. Whichever ran, the venv must hold exactly the pinned
versions; and uv, which does not read pip's configuration, must be given the index, extra index and
find-links pip would use (an index only the user's pip.conf names would otherwise be skipped).
"""

import importlib.metadata
import os
import re
import subprocess
import sys

import pytest

from conftest import REPO


def _pins(path):
    pins = {}
    for line in (REPO / path).read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, version = line.split("==")
            pins[re.sub(r"\[.*\]", "", name)] = version
    return pins


@pytest.mark.parametrize("path", ["constraints.txt", "requirements-setup.txt"])
def test_every_pinned_distribution_is_installed_at_its_pin(path):
    pins = _pins(path)
    assert len(pins) > (200 if path == "constraints.txt" else 0)
    wrong = {}
    for name, version in pins.items():
        try:
            got = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            got = None
        if got != version:
            wrong[name] = (version, got)
    assert not wrong, f"pinned (want, installed): {wrong}"


def _sources(env):
    """What tools/setup.sh's pip_sources prints for uv, one argument per line, in ``env``."""
    script = (f"VENV={sys.prefix}; "
              + "source <(sed -n '/^pip_sources()/,/^}/p' tools/setup.sh); pip_sources")
    done = subprocess.run(["bash", "-c", script], cwd=REPO, env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout.splitlines()


def test_pips_index_settings_are_passed_to_uv(tmp_path):
    conf = tmp_path / "pip.conf"
    conf.write_text("[global]\nindex-url = https://mirror.example/simple\n"
                    "extra-index-url = file:///srv/a/simple file:///srv/b/simple\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}
    env["PIP_CONFIG_FILE"] = str(conf)
    env["PIP_FIND_LINKS"] = "/srv/wheels"
    assert _sources(env) == ["--index-url", "https://mirror.example/simple",
                             "--extra-index-url", "file:///srv/a/simple", "--extra-index-url", "file:///srv/b/simple",
                             "--find-links", "/srv/wheels"]
    # an environment variable wins over the file, as it does for pip
    env["PIP_INDEX_URL"] = "https://other.example/simple"
    assert _sources(env)[:2] == ["--index-url", "https://other.example/simple"]
