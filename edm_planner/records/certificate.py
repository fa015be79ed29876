"""The certificate digest: what was certified, bit for bit, so that nothing else is ever sent (no rclpy).

A certified plan is kept (plan store) and published (ChannelPlan) with a
SHA-256 of exactly what the certificate covers and the machine will move
along: plan id, geometry id, channel, electrode id, method, axis names, the
axis samples, the reference pose the axis values are measured from (4x4,
channel 0) and, for a plan with a machining cycle, every leg's phase and
samples, the machining margin, the cycle's verdict and its clear zone. Numbers enter as
little-endian float64 bytes, so one changed bit changes the digest.

The digest is computed once, when the plan is turned into a record right
after planning (:func:`edm_planner.records.store.plan_to_stored`,
:func:`~edm_planner.records.store.roughing_to_stored`), and travels with it.
Whoever executes or re-serves a plan recomputes it from what they hold and
refuses a mismatch (NOT_CERTIFIED): the axis bridge for a plan from the store
or from the ``plan`` topic, the planner and ``edm-plan`` for a plan read from
the store. A record or message without a digest (written before digests
existed) is refused the same way: re-plan it.

The digest detects a plan altered after certification (an edited store
record, a message changed or damaged in transit, a mix-up of plans); it is a
checksum, not a signature: whoever can write the store can also write a
matching digest. Keep the store and the ROS graph writable by the cell only
(file permissions, SROS2).
"""

import hashlib
import json

import numpy as np

from ..errors import EdmError, ErrorCode
from .cycle_record import cycle_from_record

#: the digest's format; part of what is hashed, so another format can never match by accident
DIGEST_FORMAT = "edm_planner.certificate/1"
#: the key of the digest in a plan-store record's meta
META_KEY = "certificate_sha256"


def _f8(array):
    return np.ascontiguousarray(np.asarray(array, dtype=np.float64), dtype="<f8")


def certificate_digest(plan_id, geometry_id, channel, electrode_id, method, axis_names, samples, reference_pose,
                       cycle=None):
    """SHA-256 (hex) of what a plan's certificate covers.

    Parameters
    ----------
    plan_id, geometry_id, electrode_id, method : str
    channel : int
    axis_names : sequence of str
    samples : (N, k) float
        The certified axis samples [mm, rad].
    reference_pose : (4, 4) float
        Electrode frame -> W with every axis at 0, channel 0 [mm].
    cycle : MachiningCycle, optional
        Its legs (phase, samples), margin [mm] and verdict enter the digest.

    Returns
    -------
    str
        64 hex digits.
    """
    names = [str(n) for n in axis_names]
    samples = _f8(samples).reshape(-1, len(names)) if names else _f8(samples)
    pose = _f8(reference_pose).reshape(4, 4)
    head = {"format": DIGEST_FORMAT, "plan_id": str(plan_id), "geometry_id": str(geometry_id),
            "channel": int(channel), "electrode_id": str(electrode_id), "method": str(method), "axis_names": names,
            "samples_shape": list(samples.shape)}
    legs = []
    if cycle is not None:
        legs = [_f8(leg.samples) for leg in cycle.legs]
        head["cycle"] = {"axis_names": [str(n) for n in cycle.axis_names],
                         "phases": [str(leg.phase) for leg in cycle.legs],
                         "leg_shapes": [list(s.shape) for s in legs],
                         "margin": repr(float(cycle.margin)), "certified": bool(cycle.certified)}
        zone = getattr(cycle, "clear_zone", None)
        if zone is not None:       # it certifies the index moves and tool changes (absent: older cycles)
            head["cycle"]["clear_zone"] = [repr(float(v)) for v in (zone.side, *zone.envelope, zone.sphere_radius,
                                                                    zone.origin_x, zone.clear_x, zone.blade_gap)]
    h = hashlib.sha256(json.dumps(head, sort_keys=True).encode())
    h.update(samples.tobytes())
    h.update(pose.tobytes())
    for s in legs:
        h.update(s.tobytes())
    return h.hexdigest()


def record_digest(stored):
    """The certificate digest of a plan-store record (:class:`~edm_planner.records.store.StoredPlan`)."""
    cycle = cycle_from_record(stored.meta, stored.arrays) if stored.kind == "channel" else None
    return certificate_digest(stored.plan_id, stored.geometry_id, stored.channel, stored.electrode_id, stored.method,
                              stored.axis_names, stored.samples, stored.final_pose, cycle)


class NotCertifiedError(EdmError):
    """NOT_CERTIFIED: a plan without a certificate digest, or one that no longer matches what was certified."""

    def __init__(self, message):
        super().__init__(ErrorCode.NOT_CERTIFIED, message)


def check_digest(plan_id, recorded, actual, where):
    """Raise :class:`NotCertifiedError` unless ``recorded`` (the digest kept with the plan) equals ``actual``.

    Parameters
    ----------
    plan_id : str
    recorded : str
        The digest the record or message carries ('' or None: none).
    actual : str
        The digest of what is held now (:func:`certificate_digest`).
    where : str
        Where the plan came from, for the message ("the plan store /path", "the 'plan' topic").
    """
    if not recorded:
        raise NotCertifiedError(f"plan {plan_id} from {where} has no certificate digest (made by an edm_planner "
                                f"before digests existed, or by another publisher): nothing is sent that is not "
                                f"certified; re-plan it (an equal PlanChannel request, or `edm-plan plan --replan`, plans it "
                                f"anew and replaces the record)")
    if recorded != actual:
        raise NotCertifiedError(f"plan {plan_id} from {where} was altered after certification: its samples, poses, "
                                f"channel or cycle do not match its certificate digest (recorded {recorded[:16]}..., "
                                f"now {actual[:16]}...); it is not sent; re-plan it")


def verify_record(stored, where="the plan store"):
    """Raise :class:`NotCertifiedError` unless a plan-store record matches the digest it carries."""
    check_digest(stored.plan_id, stored.meta.get(META_KEY, ""), record_digest(stored), where)
