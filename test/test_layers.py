"""The layer contract (.importlinter) holds: entry points over records over the domain over the base, no rclpy
or ROS message outside the ROS shell (nodes, ros), and no import cycle anywhere in the package."""

import configparser
import subprocess
import sys

import grimp
import networkx as nx

from conftest import REPO


def test_the_import_linter_contracts_are_kept():
    run = subprocess.run([str(REPO / ".venv" / "bin" / "lint-imports") if (REPO / ".venv" / "bin" / "lint-imports")
                          .exists() else "lint-imports", "--no-cache"], cwd=REPO, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "Contracts: 2 kept, 0 broken." in run.stdout


def _deprecated_aliases():
    """The imports the layer contract ignores: the deprecated aliases' lazy imports of a moved name's new home."""
    config = configparser.ConfigParser()
    config.read(REPO / ".importlinter")
    lines = config["importlinter:contract:layers"]["ignore_imports"].split("\n")
    return {tuple(part.strip() for part in line.split("->")) for line in lines if "->" in line}


def test_no_module_imports_itself_back():
    """No cycle of imports between modules, inside a package or across packages, function-level ones included;
    the deprecated aliases' imports (run only when an old name is asked for, until 0.3.0) left out."""
    graph = grimp.build_graph("edm_planner")
    aliases = _deprecated_aliases()
    assert aliases, "the contract's ignore list was not read"
    edges = nx.DiGraph([(m, i) for m in graph.modules for i in graph.find_modules_directly_imported_by(m)
                        if (m, i) not in aliases])
    cycles = [sorted(c) for c in nx.strongly_connected_components(edges) if len(c) > 1]
    assert cycles == []


def test_the_contract_catches_an_upward_import(tmp_path):
    """The contract is not vacuous: a copy of the package with one domain module importing the records layer
    breaks it."""
    import shutil

    package = tmp_path / "edm_planner"
    shutil.copytree(REPO / "edm_planner", package, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / ".importlinter", tmp_path / ".importlinter")
    target = package / "geometry" / "frames.py"
    target.write_text(target.read_text() + "\nfrom ..records import store  # noqa\n")
    run = subprocess.run([sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
                          "sys.exit(lint_imports_command())", "--no-cache"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300, env={"PYTHONPATH": str(tmp_path), "PATH": ""})
    assert run.returncode != 0
    assert "edm_planner.geometry is not allowed to import edm_planner.records" in run.stdout


def test_the_ros_contract_catches_rclpy_above_the_shell(tmp_path):
    """The bench and the apps are sources of the forbidden contract too: a bench module importing rclpy, or a
    program of the ROS shell (which imports it), breaks it."""
    import shutil

    package = tmp_path / "edm_planner"
    shutil.copytree(REPO / "edm_planner", package, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / ".importlinter", tmp_path / ".importlinter")
    bench = package / "bench" / "service.py"
    bench.write_text(bench.read_text() + "\nimport rclpy  # noqa\n")
    app = package / "apps" / "warmup.py"
    app.write_text(app.read_text() + "\nfrom ..nodes.programs import demo  # noqa\n")
    run = subprocess.run([sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
                          "sys.exit(lint_imports_command())", "--no-cache"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300, env={"PYTHONPATH": str(tmp_path), "PATH": ""})
    assert run.returncode != 0
    assert "edm_planner.bench is not allowed to import rclpy:" in run.stdout, run.stdout
    assert "edm_planner.bench.service -> rclpy" in run.stdout, run.stdout
    assert "edm_planner.apps is not allowed to import rclpy:" in run.stdout, run.stdout
    assert "edm_planner.apps.warmup -> edm_planner.nodes.programs.demo" in run.stdout, run.stdout
