"""The bridge never sends what the machine cannot do (issue 15.4), over real DDS.

Small hand-made plans (a straight feed, a five-leg cycle) sealed with their
certificate digest like the planner's, so that nothing here plans and the
module runs in seconds: a plan altered in the plan store or in transit, or
without a digest, is refused NOT_CERTIFIED; a sample outside the travel on any
leg is refused before timing; a request whose channel, geometry or reference
pose disagrees with the plan is refused; an export never leaves export_dir.
Each refusal is paired with the same plan passing when nothing is wrong.
"""

import time

import numpy as np
import pytest
from edm_planner_msgs.msg import ChannelPlan, ErrorCode, PlanMetrics
from edm_planner_msgs.srv import ExecutePlan
from rclpy.node import Node
from rclpy.parameter import Parameter
from trajectory_msgs.msg import JointTrajectory

from edm_planner.geometry.frames import rotation_about_x
from edm_planner.machining.cycle import Leg, MachiningCycle, ProcessReach
from edm_planner.nodes.axis_bridge import AxisBridgeNode
from edm_planner.ros.shared import LATCHED
from edm_planner.nodes.trajectory_planner import axis_path_msg, channel_plan_msg, pose_array_msg
from edm_planner.records.certificate import META_KEY, record_digest
from edm_planner.records.store import PlanStore, StoredPlan, cycle_to_record

from test_axis_bridge_node import Inbox

PITCH = 2 * np.pi / 60
AXES = ("X", "Y", "Z", "A", "C")
TOPIC = "/refusals/joint_trajectory"
GEOMETRY = "9" * 64


def reference_pose():
    """Electrode frame -> W with every axis at 0 (channel 0) [mm]: turned 0.3 rad about z, 110 mm out."""
    c, s = np.cos(0.3), np.sin(0.3)
    pose = np.eye(4)
    pose[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = [5.0, 110.0, 2.0]
    return pose


def feed(channel=0, n=40):
    """A straight feed from X = 20 mm to the machining pose (all axes 0, A at the channel) [mm, rad]."""
    q = np.zeros((n, 5))
    q[:, 0] = np.linspace(20.0, 0.0, n)
    q[:, 1] = 0.5 * np.sin(np.linspace(0.0, np.pi, n))
    q[:, 3] = channel * PITCH
    return q


def a_cycle(samples, process_z=0.05):
    """Approach, feed, process (out to Z = process_z and back), return, retract; rest samples shared exactly."""
    start, final = samples[0], samples[-1]
    home = start + [10.0, 0.0, 0.0, 0.0, 0.0]
    out = final + [0.0, 0.0, process_z, 0.0, 0.0]
    legs = [Leg("approach", "approach", np.array([home, start]), np.full(4, 0.1)),
            Leg("feed", "feed", samples.copy(), np.full(4, 0.1)),
            Leg("process", "Z out and back", np.array([final, out, final]), np.full(4, 0.1)),
            Leg("return", "return (the feed reversed)", samples[::-1].copy(), np.full(4, 0.1)),
            Leg("retract", "retract", np.array([start, home]), np.full(4, 0.1))]
    return MachiningCycle(AXES, legs, ProcessReach(), 0.08, True, "certified (test)")


def sealed(plan_id, samples, channel=0, cycle=None, seal=True):
    """A plan-store record as plan_to_stored makes one: certificate digest in its meta."""
    poses = np.repeat(rotation_about_x(channel * PITCH) @ reference_pose()[None], len(samples), axis=0)
    poses[:, :3, 3] += samples[:, :3]
    meta, arrays = cycle_to_record(cycle)
    stored = StoredPlan(plan_id=plan_id, kind="channel", geometry_id=GEOMETRY, channel=channel, electrode_id="e1",
                        method="test", axis_names=AXES, samples=samples, final_pose=reference_pose(), poses=poses,
                        meta=meta, arrays=arrays)
    if seal:
        stored.meta[META_KEY] = record_digest(stored)
    return stored


def message(stored):
    """The ChannelPlan the trajectory_planner publishes for a record."""
    return channel_plan_msg(stored, pose_array_msg(stored.poses, "blisk"),
                            axis_path_msg(stored.axis_names, stored.samples), PlanMetrics())


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    from ros_harness import InProcessRos

    store_dir, exports = tmp_path_factory.mktemp("refusal_store"), tmp_path_factory.mktemp("refusal_exports")
    ros = InProcessRos()
    bridge = ros.add(AxisBridgeNode(context=ros.context, cli_args=[
        "--ros-args", "-r", "execute_plan:=refusals/execute_plan", "-r", "plan:=refusals/plan"],
        parameter_overrides=[Parameter("joint_states_topic", value=""), Parameter("plan_store", value=str(store_dir)),
                             Parameter("export_dir", value=str(exports)), Parameter("plan_wait", value=0.2),
                             Parameter("trajectory_topic", value=TOPIC)]))
    client = ros.add(Node("refusal_client", context=ros.context))
    sent = Inbox()
    client.create_subscription(JointTrajectory, TOPIC, sent, 10)
    pub = client.create_publisher(ChannelPlan, "refusals/plan", LATCHED)
    yield dict(ros=ros, bridge=bridge, client=client, store=PlanStore(store_dir), exports=exports, sent=sent, pub=pub,
               sent_count=0)
    ros.close()


def publish(cell, msg, timeout=10.0):
    """Publish a plan on the bridge's topic and wait until the bridge holds it."""
    before = cell["bridge"].plans.get(msg.plan_id)
    cell["pub"].publish(msg)
    deadline = time.monotonic() + timeout
    while cell["bridge"].plans.get(msg.plan_id) is before:
        assert time.monotonic() < deadline, f"the bridge did not take plan {msg.plan_id}"
        time.sleep(0.02)


def execute(cell, plan_id, channel=0, dry_run=True, **fields):
    req = ExecutePlan.Request(plan_id=plan_id, channel=channel, dry_run=dry_run, **fields)
    return cell["ros"].call(cell["client"], ExecutePlan, "refusals/execute_plan", req, timeout=60)


def refused(cell, res, code, *words):
    """The response refuses with ``code`` naming every word, and nothing went to the controller."""
    assert not res.success and res.error_code.val == code, res.message
    for word in words:
        assert word in res.message, (word, res.message)
    time.sleep(0.2)
    assert len(cell["sent"].items) == cell["sent_count"]


# -- the certificate digest ---------------------------------------------------------------------------------

def test_a_plan_altered_in_the_store_is_refused(cell):
    store, plan_id = cell["store"], "a1" * 8
    cycle = a_cycle(feed())
    record = sealed(plan_id, feed(), cycle=cycle)
    store.put(record)
    count = len(cell["sent"].items)
    res = execute(cell, plan_id, dry_run=False)
    assert res.success, res.message                            # as certified: sent
    assert cell["sent"].wait(count + 1, 10)
    assert list(res.phase_names[:3]) == ["approach", "feed", "process"]
    cell["sent_count"] = count + 1
    # one feed sample moved by a micrometre, the record's own checksum rewritten by the store
    altered = sealed(plan_id, feed(), cycle=cycle)
    altered.samples[17, 1] += 0.001
    altered.meta[META_KEY] = record.meta[META_KEY]
    store.put(altered)
    refused(cell, execute(cell, plan_id, dry_run=False), ErrorCode.NOT_CERTIFIED, f"plan {plan_id}",
            "altered after certification", str(store.path))
    # a cycle leg moved (the process goes 1 mm further out): the legs are certified too
    legs = a_cycle(feed(), process_z=1.05)
    altered = sealed(plan_id, feed(), cycle=legs)
    altered.meta[META_KEY] = record.meta[META_KEY]
    store.put(altered)
    refused(cell, execute(cell, plan_id, dry_run=False), ErrorCode.NOT_CERTIFIED, "altered after certification")


def test_a_record_without_a_digest_is_refused(cell):
    plan_id = "a2" * 8
    cell["store"].put(sealed(plan_id, feed(), seal=False))
    refused(cell, execute(cell, plan_id), ErrorCode.NOT_CERTIFIED, f"plan {plan_id}", "no certificate digest",
            "re-plan")


def test_a_plan_altered_in_transit_is_refused(cell):
    plan_id = "a3" * 8
    msg = message(sealed(plan_id, feed(channel=2), channel=2))
    publish(cell, msg)
    assert execute(cell, plan_id, channel=2).success                       # as published: accepted
    msg.axis_path.points[5].positions[0] += 1e-9                           # one sample, one nanometre
    publish(cell, msg)
    refused(cell, execute(cell, plan_id, channel=2), ErrorCode.NOT_CERTIFIED, f"plan {plan_id}",
            "'plan' topic", "altered after certification")
    channel = message(sealed(plan_id, feed(channel=2), channel=2))
    channel.channel = 3                                                    # the channel changed on the way
    publish(cell, channel)
    refused(cell, execute(cell, plan_id, channel=3), ErrorCode.NOT_CERTIFIED, "altered after certification")
    pose = message(sealed(plan_id, feed(channel=2), channel=2))
    pose.reference_pose[3] += 0.01                                         # the reference moved by 10 um
    publish(cell, pose)
    refused(cell, execute(cell, plan_id, channel=2), ErrorCode.NOT_CERTIFIED, "altered after certification")
    bare = message(sealed(plan_id, feed(channel=2), channel=2))
    bare.certificate_sha256 = ""                                           # an older publisher
    publish(cell, bare)
    refused(cell, execute(cell, plan_id, channel=2), ErrorCode.NOT_CERTIFIED, "no certificate digest")


# -- travel, before timing ----------------------------------------------------------------------------------

def test_a_feed_sample_outside_the_travel_is_refused_before_timing(cell):
    plan_id = "b1" * 8
    q = feed()
    q[17, 1] = 250.0                                  # Y travel is [-200, 200] mm in config/machine.yaml
    cell["store"].put(sealed(plan_id, q))
    refused(cell, execute(cell, plan_id, dry_run=False), ErrorCode.INFEASIBLE, f"plan {plan_id} (feed)",
            "sample 17 of 40", "axis Y (joint edm_y) at 250 mm", "travel [-200, 200] mm", "before timing")


def test_a_cycle_leg_outside_the_travel_is_refused_before_timing(cell):
    plan_id = "b2" * 8
    cell["store"].put(sealed(plan_id, feed(), cycle=a_cycle(feed(), process_z=230.0)))
    refused(cell, execute(cell, plan_id, dry_run=False), ErrorCode.INFEASIBLE, f"plan {plan_id} channel 0 leg 2 "
            "(process: Z out and back)", "sample 1 of 3", "axis Z (joint edm_z) at 230 mm", "[-200, 200] mm")


# -- what the request and the cell expect ---------------------------------------------------------------------

def test_channel_geometry_and_reference_pose_must_agree_with_the_request(cell):
    plan_id = "c1" * 8
    cell["store"].put(sealed(plan_id, feed(channel=1), channel=1))
    pose = reference_pose()
    ok = execute(cell, plan_id, channel=1, expected_geometry_id=GEOMETRY,
                 expected_reference_pose=pose.reshape(-1).tolist())
    assert ok.success, ok.message
    near = pose.copy()
    near[:3, 3] += [0.0004, 0.0, 0.0]                                       # within 0.001 mm
    assert execute(cell, plan_id, channel=1, expected_reference_pose=near.reshape(-1).tolist()).success
    refused(cell, execute(cell, plan_id, channel=0), ErrorCode.INVALID_REQUEST, "channel 1", "channel 0")
    refused(cell, execute(cell, plan_id, channel=1, expected_geometry_id="8" * 64), ErrorCode.INVALID_REQUEST,
            f"plan {plan_id} is for geometry {GEOMETRY}", "8" * 64)
    moved = pose.copy()
    moved[:3, 3] += [0.0, 0.01, 0.0]                                        # 10 um off
    refused(cell, execute(cell, plan_id, channel=1, expected_reference_pose=moved.reshape(-1).tolist()),
            ErrorCode.INVALID_REQUEST, f"plan {plan_id}", "reference pose", "0.01 mm")
    turned = pose.copy()
    turned[:3, :3] = turned[:3, :3] @ rotation_about_x(1e-4)[:3, :3]       # 0.1 mrad off
    refused(cell, execute(cell, plan_id, channel=1, expected_reference_pose=turned.reshape(-1).tolist()),
            ErrorCode.INVALID_REQUEST, "reference pose", "0.0001 rad")
    refused(cell, execute(cell, plan_id, channel=1, expected_reference_pose=[1.0] * 15), ErrorCode.INVALID_REQUEST,
            "16 finite values")


# -- exports stay inside export_dir ---------------------------------------------------------------------------

def test_an_export_never_leaves_export_dir(cell, tmp_path):
    exports = cell["exports"]
    escape = "../escaped"                              # a plan id chosen by whoever published the message
    publish(cell, message(sealed(escape, feed())))
    refused(cell, execute(cell, escape), ErrorCode.INVALID_REQUEST, "'../escaped' cannot name an export")
    assert not (exports.parent / "escaped.nc").exists()
    plan_id = "d1" * 8
    publish(cell, message(sealed(plan_id, feed())))
    outside = tmp_path / "precious.nc"
    outside.write_text("not yours\n")
    (exports / f"{plan_id}.nc").symlink_to(outside)    # planted inside export_dir, pointing out
    refused(cell, execute(cell, plan_id), ErrorCode.FILE_ERROR, "symbolic link", f"{plan_id}.nc")
    assert outside.read_text() == "not yours\n"
    (exports / f"{plan_id}.nc").unlink()
    res = execute(cell, plan_id)
    assert res.success and (exports / f"{plan_id}.nc").is_file() and not (exports / f"{plan_id}.nc").is_symlink()


# -- the digest itself ----------------------------------------------------------------------------------------

def test_the_digest_of_a_published_plan_is_that_of_its_record():
    """What the planner publishes (a cycle's legs rebuilt from cycle_path) hashes as its record: no false refusal."""
    from edm_planner.nodes.axis_bridge import _KnownPlan
    from edm_planner.records.certificate import NotCertifiedError
    from edm_planner.records.store import stored_to_plan

    record = sealed("e1" * 8, feed(channel=4), channel=4, cycle=a_cycle(feed(channel=4)))
    known = _KnownPlan(message(record))
    assert known.digest == record.meta[META_KEY] and len(known.digest) == 64
    known.check_certified()
    # every part of what was certified changes it
    for change in (lambda r: r.samples.__setitem__((3, 2), r.samples[3, 2] + 1e-12),
                   lambda r: r.final_pose.__setitem__((0, 3), 5.000001),
                   lambda r: setattr(r, "channel", 5), lambda r: setattr(r, "geometry_id", "8" * 64),
                   lambda r: r.arrays["cycle_leg_samples"].__setitem__((1, 0), 19.5),
                   lambda r: r.meta["cycle"].__setitem__("certified", False),
                   lambda r: r.meta["cycle"]["phases"].__setitem__(2, "feed")):
        altered = sealed("e1" * 8, feed(channel=4), channel=4, cycle=a_cycle(feed(channel=4)))
        change(altered)
        assert record_digest(altered) != record.meta[META_KEY]
        # and the planner (stored_to_plan) refuses such a record before reading anything else of it
        with pytest.raises(NotCertifiedError) as err:
            stored_to_plan(altered, "the test store")
        assert err.value.code == 9 and "altered after certification" in err.value.message
