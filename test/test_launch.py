"""The cell's launch file and its parameters YAML (issue 23).

``ros2 launch`` is not among the ROS 2 wheels this project installs, so what can run here runs: the launch
file is read as the program it is (its nodes, package and default parameters file, all installed), and the
parameters YAML is loaded into the four node processes exactly as launch_ros passes it
(``--ros-args --params-file``): every key is a parameter its node declares, with the value the file gives,
and every parameter a node declares is in the file.
"""

import ast
import importlib.metadata
import pathlib
import sys

import pytest
import yaml

REPO = pathlib.Path(__file__).resolve().parent.parent
SHARE = pathlib.Path(sys.prefix) / "share" / "edm_planner"
LAUNCH = REPO / "launch" / "edm_cell.launch.py"
PARAMS = REPO / "config" / "edm_cell.yaml"
#: parameters every rclpy node has, not the cell's to configure
ROS_OWN = {"use_sim_time", "start_type_description_service"}
#: parameters the file leaves at the node's default on purpose (named in the file's comments): the loader's
#: allowed directories default to the install's own config directory, which no file can name for every install
LEFT_TO_DEFAULT = {"geometry_loader": {"allowed_directories"}}


def launch_constant(name):
    tree = ast.parse(LAUNCH.read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError(f"{name} not defined in {LAUNCH}")


def test_the_launch_file_starts_every_node_of_the_package_with_the_installed_parameters_file():
    nodes = launch_constant("NODES")
    executables = {ep.name for ep in importlib.metadata.entry_points(group="console_scripts")
                   if ep.value.startswith("edm_planner.nodes.")}
    assert set(nodes) == executables, "the launch file must start exactly the package's node executables"
    assert launch_constant("PACKAGE") == "edm_planner"
    text = LAUNCH.read_text()
    assert '"config", "edm_cell.yaml"' in text, "the default parameters file is the installed edm_cell.yaml"
    assert "generate_launch_description" in text
    # installed where ros2 launch looks (share/<package>/launch) and with its parameters file
    assert (SHARE / "launch" / LAUNCH.name).read_text() == text, "launch file not installed (make setup)"
    assert (SHARE / "config" / PARAMS.name).read_text() == PARAMS.read_text()
    assert yaml.safe_load(PARAMS.read_text()).keys() == set(nodes), "one section per node of the launch file"


def _parameters(ros, client, node_name, names):
    from rcl_interfaces.srv import GetParameters, ListParameters
    from rclpy.parameter import parameter_value_to_python

    listed = ros.call(client, ListParameters, f"/{node_name}/list_parameters", ListParameters.Request(), timeout=120)
    declared = set(listed.result.names)
    got = ros.call(client, GetParameters, f"/{node_name}/get_parameters", GetParameters.Request(names=list(names)),
                   timeout=60)
    return declared, {n: parameter_value_to_python(v) for n, v in zip(names, got.values)}


@pytest.mark.slow
def test_the_parameters_yaml_is_loaded_into_the_nodes_and_names_every_parameter(ros, node_processes, tmp_path,
                                                                                field_cache):
    from rclpy.node import Node

    shipped = yaml.safe_load(PARAMS.read_text())
    # values that differ from every default, so that what the nodes report can only come from the file; no
    # geometry at start, so nothing is built
    changed = {"geometry_loader": {"geometry_file": "", "mesh_resolution": 0.5, "max_yaml_bytes": 1234567},
               "interference_checker": {"max_poses": 1234, "prebuild_fast": False, "cache_dir": field_cache},
               "trajectory_planner": {"geometry_wait": 7.5, "frame_id": "blisk_test", "plan_store": "none"},
               "axis_bridge": {"plan_wait": 0.25, "joint_states_topic": "", "start_tolerance_rotary": 0.002,
                               "plan_store": "none"}}
    doc = {node: {"ros__parameters": {**section["ros__parameters"], **changed[node]}}
           for node, section in shipped.items()}
    path = tmp_path / "edm_cell.yaml"
    path.write_text(yaml.safe_dump(doc))
    for node in doc:
        node_processes.start(node, "--ros-args", "--params-file", str(path))
    client = ros.add(Node("params_probe", context=ros.context))
    for node, section in doc.items():
        want = section["ros__parameters"]
        declared, got = _parameters(ros, client, node, sorted(want))
        assert set(want) <= declared, f"{node}: keys in the YAML that the node does not declare: {set(want) - declared}"
        missing = declared - ROS_OWN - LEFT_TO_DEFAULT.get(node, set()) - set(shipped[node]["ros__parameters"])
        assert not missing, f"{node}: parameters missing from config/edm_cell.yaml: {missing}"
        for name, value in want.items():
            assert got[name] == pytest.approx(value) if isinstance(value, float) else got[name] == value, \
                f"{node}.{name}: the node has {got[name]!r}, the file says {value!r}"
    # the processes are alive: nothing was refused at start
    assert all(p.poll() is None for p, _ in node_processes.procs.values()), {
        n: node_processes.log(n)[-2000:] for n, (p, _) in node_processes.procs.items() if p.poll() is not None}
