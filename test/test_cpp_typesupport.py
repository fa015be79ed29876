"""A C++ user of edm_planner_msgs: the C++ type supports that make setup installs, against Python's.

``test/cpp_client`` is a CMake project as a C++ (rclcpp) user writes one: ``find_package(edm_planner_msgs)``,
the C++ message classes, ``rmw_serialize``/``rmw_deserialize`` of Fast DDS through the C++ type support
(the dispatch library and the Fast DDS one), and the C++ introspection type support. Built and run in a
new user's shell on the underlay; it fills a service request and an action goal as ``python_messages``
does here. Python's own path (the C type supports) is what every other test uses: this one shows the C++
libraries read and write the same messages.
"""

import json
import shlex

import pytest
from edm_planner_msgs.action import PlanElectrodeSet
from edm_planner_msgs.msg import AxisPoint
from edm_planner_msgs.srv import CheckInterference
from geometry_msgs.msg import Pose
from rclpy.serialization import deserialize_message, serialize_message

from conftest import REPO
from user_shell import run_in_shell

CLIENT = REPO / "test" / "cpp_client"


def python_messages():
    """The messages ``cdr_round_trip.cpp`` fills, with the same values, by its names."""
    req = CheckInterference.Request(geometry_id="blisk-7", channel=3, electrode_id="rear",
                                    method=CheckInterference.Request.METHOD_FAST, axis_names=["X", "Y", "Z", "A", "C"],
                                    segments=True, closest_points=False, threshold=0.0125)
    e = req.electrode
    e.discharge_gap, e.circumferential_reduction, e.reduction_side = 0.05, 0.03, "both"
    e.radial_reduction, e.axial_start, e.axial_end = 3.0, -12.5, 40.25
    e.split, e.split_fraction, e.split_overlap = "front_rear", 0.5, 1.0
    for k in range(2):
        p = Pose()
        p.position.x, p.position.y, p.position.z = 10.0 + k, -2.5 * k, 150.125
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = 0.0, 0.6, 0.0, 0.8
        req.poses.append(p)
    req.axis_values = [AxisPoint(positions=[1.0 * k, 2.0, -3.5, 0.1 * k, -0.25]) for k in range(3)]
    goal = PlanElectrodeSet.Goal(geometry_id="rotor37", channel=2, tolerance=0.02, max_electrodes=4,
                                 write_export=True)
    return {"check_interference_request": req, "plan_electrode_set_goal": goal}


@pytest.fixture(scope="module")
def cpp_report(tmp_path_factory):
    """The C++ program's JSON report, built with CMake against the venv's install of edm_planner_msgs."""
    build = tmp_path_factory.mktemp("cpp_client")
    steps = (f"cmake -S {shlex.quote(str(CLIENT))} -B . -DCMAKE_PREFIX_PATH=\"$VIRTUAL_ENV\" "
             "&& cmake --build . -j2")
    made = run_in_shell(build, steps, overlay=False, timeout=600)
    assert made.returncode == 0, f"{steps} failed:\n{made.stdout[-4000:]}\n{made.stderr[-4000:]}"
    written = "".join(f"{name} {serialize_message(msg).hex()}\n" for name, msg in python_messages().items())
    run = run_in_shell(build, "./cdr_round_trip", overlay=False, timeout=60, stdin=written)
    assert run.returncode == 0, f"cdr_round_trip failed:\n{run.stdout}\n{run.stderr}"
    return json.loads(run.stdout)


def test_the_cpp_program_reads_back_what_it_wrote(cpp_report):
    assert set(cpp_report) == set(python_messages())
    assert all(report["equal"] for report in cpp_report.values()), cpp_report


def test_what_python_writes_the_cpp_type_support_reads_as_the_same_message(cpp_report):
    assert {name: report["python_equal"] for name, report in cpp_report.items()} == dict.fromkeys(cpp_report, True)


def test_what_the_cpp_type_support_writes_python_reads_as_the_same_message(cpp_report):
    for name, msg in python_messages().items():
        read = deserialize_message(bytes.fromhex(cpp_report[name]["cdr"]), type(msg))
        assert read == msg, name
        # a changed value is told apart (the comparison is not vacuous)
        read.channel += 1
        assert read != msg


def test_the_cpp_introspection_lists_the_fields_python_has_in_order(cpp_report):
    for name, msg in python_messages().items():
        assert cpp_report[name]["fields"] == list(msg.get_fields_and_field_types()), name
