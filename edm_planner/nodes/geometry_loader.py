"""geometry_loader node: loads blisk geometries and publishes them for the other nodes.

Parameters
----------
geometry_file : str
    YAML loaded at start (default: the built-in blisk, share/edm_planner/config/default_blisk.yaml);
    empty: load nothing at start.
allowed_directories : str[]
    Directories LoadGeometry may read from (the YAML and every file it names,
    symlinks resolved); default: the package's config directory.
frame_id : str
    Frame of the published geometry (the workpiece frame W, X = blisk axis).
mesh_resolution : float
    Edge length [mm] of the published channel surface meshes (viewers only;
    nodes rebuild the exact model from model_json).
max_yaml_bytes, max_mesh_bytes, max_table_bytes, max_step_bytes : int
    Size limits [bytes] of the geometry YAML (file or inline), a mesh (a blade's
    or a whole-blisk scan), a table (blade sections, meridional lines) and a
    STEP file: a larger file is refused (FILE_ERROR) before it is parsed.
    Defaults 4 MiB, 200 MiB, 16 MiB, 256 MiB.

Notes
-----
Services: ``load_geometry`` (edm_planner_msgs/LoadGeometry).
Topics (TRANSIENT_LOCAL, depth 1): ``geometry`` (edm_planner_msgs/BliskGeometry),
``geometry_markers`` (visualization_msgs/MarkerArray). The markers (for RViz) are built only while a
viewer subscribes to them: building their 200 000 points takes about 2 s of CPU, which a cell without a
viewer never needs. They are built after the geometry, in a thread of their own (neither the LoadGeometry
answer nor the node's start waits for them), for the latest geometry: on each load while a viewer is
matched, and when a viewer is matched that has not got them yet (the publisher's matched event).
"""

import concurrent.futures
import json
import logging
import os
import threading

from edm_planner_msgs.msg import BliskGeometry
from edm_planner_msgs.srv import LoadGeometry
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from ..ros.startup import prepare_process

#: this entry point's set-up, before the core's kernel modules load (numba reads its cache directory then) and
#: before rclpy.init (Fast DDS on loopback): :func:`edm_planner.ros.startup.prepare_process`
DDS_SETUP = prepare_process()

from ..errors import EdmError, ErrorCode
from ..geometry.blisk import CHANNEL_SURFACES
from ..geometry.loader import FileLimits, GeometryMemo, load_geometry
from ..ros.runtime import spin_node
from ..ros.shared import LATCHED, config_directory
from ..ros.conversions import error_code, matrices_to_poses, mesh_marker, mesh_to_msg, summary_to_msg

#: QoS of data that late joiners need (like tf_static)
#: the kinds of file with a size limit, each a parameter max_<kind>_bytes
LIMITED_KINDS = ("yaml", "mesh", "table", "step")
COLOURS = {"suction": (0.2, 0.4, 0.9, 0.6), "pressure": (0.9, 0.3, 0.2, 0.6),
           "hub": (0.5, 0.5, 0.5, 0.5), "shroud": (0.6, 0.6, 0.3, 0.3)}


class GeometryLoaderNode(Node):
    """Loads blisk geometries (LoadGeometry) and publishes the current one."""

    def __init__(self, **kwargs):
        super().__init__("geometry_loader", **kwargs)
        config = config_directory()
        self.declare_parameter("geometry_file", str(config / "default_blisk.yaml"),
                               ParameterDescriptor(description="YAML loaded at start; empty: none"))
        self.declare_parameter("allowed_directories", [str(config)],
                               ParameterDescriptor(description="directories LoadGeometry may read from"))
        self.declare_parameter("frame_id", "workpiece")
        self.declare_parameter("mesh_resolution", 1.0,
                               ParameterDescriptor(description="published surface mesh edge length [mm]"))
        defaults = FileLimits()
        for kind in LIMITED_KINDS:
            self.declare_parameter(f"max_{kind}_bytes", defaults.of(kind), ParameterDescriptor(
                description=f"largest {kind} file read for a geometry [bytes]; larger: refused before parsing"))
        self.add_on_set_parameters_callback(self._check_parameters)
        self.geometries = {}
        self._memo = GeometryMemo()          # an unchanged file is answered without building it again
        self._published = None               # what the latched topics hold: (geometry id, frame, mesh resolution)
        self._lock = threading.Lock()
        self.geometry_pub = self.create_publisher(BliskGeometry, "geometry", LATCHED)
        # one thread: markers are published in the order of the loads, the last one latched
        self._marker_work = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="markers")
        self._marker_source = None           # (publication, meshes, electrodes, frame, stamp) of the latest
        self._markers_on_topic = None        # the publication whose markers the latched topic holds
        self.marker_builds = 0               # MarkerArrays built (only while a viewer subscribes)
        self.marker_pub = self.create_publisher(
            MarkerArray, "geometry_markers", LATCHED,
            event_callbacks=PublisherEventCallbacks(matched=self._on_marker_match))
        self.load_service = self.create_service(
            LoadGeometry, "load_geometry", self.on_load_geometry,
            callback_group=MutuallyExclusiveCallbackGroup())
        start = self.get_parameter("geometry_file").value
        if start:
            # the operator's own configuration: not subject to the request sandbox
            response = self.load(path=start, sandboxed=False)
            if not response.success:
                self.get_logger().error(f"start geometry not loaded: {response.message}")

    @staticmethod
    def _check_parameters(params):
        for p in params:
            if p.name == "allowed_directories":
                missing = [d for d in p.value if not os.path.isdir(d)]
                if missing:
                    return SetParametersResult(successful=False, reason=f"not directories: {missing}")
            if p.name == "mesh_resolution" and not 0.05 <= p.value <= 10.0:
                return SetParametersResult(successful=False, reason="mesh_resolution must be 0.05 .. 10 mm")
            if p.name in tuple(f"max_{k}_bytes" for k in LIMITED_KINDS) and \
                    (isinstance(p.value, bool) or not isinstance(p.value, int) or p.value < 1):
                return SetParametersResult(successful=False, reason=f"{p.name} must be a positive integer [bytes]")
        return SetParametersResult(successful=True)

    @property
    def file_limits(self):
        """The size limits of the files read for a geometry (parameters max_*_bytes)."""
        return FileLimits(**{f"{k}_bytes": int(self.get_parameter(f"max_{k}_bytes").value) for k in LIMITED_KINDS})

    @property
    def allowed_directories(self):
        return list(self.get_parameter("allowed_directories").value)

    def on_load_geometry(self, request, response):
        path, text = request.path.strip(), request.yaml_text
        if bool(path) == bool(text.strip()):
            return self._fail(response, ErrorCode.INVALID_REQUEST,
                              "give exactly one of 'path' and 'yaml_text'")
        return self.load(path=path or None, text=text if not path else None, response=response)

    def load(self, path=None, text=None, response=None, sandboxed=True):
        """Load, remember and publish a geometry; fills a LoadGeometry response."""
        response = response or LoadGeometry.Response()
        allowed = self.allowed_directories
        if path is not None and not os.path.isabs(path):
            path = os.path.join(allowed[0], path) if allowed else path
        try:
            geometry = load_geometry(path=path, text=text, allowed_dirs=allowed if sandboxed else None,
                                     memo=self._memo, limits=self.file_limits)
            summary = geometry.summary()
        except EdmError as exc:
            return self._fail(response, exc.code, exc.message)
        except Exception as exc:  # a bug: report it, keep the node up
            self.get_logger().error(f"internal error loading geometry: {exc!r}")
            logging.getLogger(__name__).exception("internal error")
            return self._fail(response, ErrorCode.INTERNAL, f"internal error: {exc!r}")
        with self._lock:
            self.geometries[geometry.geometry_id] = geometry
        if self._published != self._publication(geometry):    # the latched topics already hold it: not again
            self.publish(geometry)
        response.success = True
        response.error_code = error_code(ErrorCode.SUCCESS)
        response.geometry_id = geometry.geometry_id
        response.summary = summary_to_msg(summary)
        response.message = (f"loaded {geometry.source}: {summary['blade_count']} blades "
                            f"({summary['blade_source']}), {summary['electrode_count']} electrode(s)")
        self.get_logger().info(f"{response.message}, id {geometry.geometry_id[:12]}")
        return response

    def _fail(self, response, code, message):
        response.success = False
        response.error_code = error_code(code)
        response.message = message
        self.get_logger().warning(f"LoadGeometry failed ({ErrorCode(code).name}): {message}")
        return response

    def _publication(self, geometry):
        return (geometry.geometry_id, self.get_parameter("frame_id").value,
                self.get_parameter("mesh_resolution").value)

    def publish(self, geometry):
        """Publish the geometry and its markers on the latched topics."""
        self._published = self._publication(geometry)
        frame = self.get_parameter("frame_id").value
        stamp = self.get_clock().now().to_msg()
        meshes = geometry.blisk.channel_meshes(resolution=self.get_parameter("mesh_resolution").value)
        msg = BliskGeometry()
        msg.header.frame_id = frame
        msg.header.stamp = stamp
        msg.summary = summary_to_msg(geometry.summary())
        model = geometry.blisk.to_dict()
        model["geometry_id"] = geometry.geometry_id
        model["electrode_design"] = geometry.design.to_dict()
        if geometry.measured is not None:            # the blades as measured: every channel on its own walls
            model["as_measured"] = geometry.measured.to_dict()
        msg.model_json = json.dumps(model)
        msg.surface_labels = list(CHANNEL_SURFACES)
        msg.surfaces = [mesh_to_msg(meshes[label]) for label in CHANNEL_SURFACES]
        msg.electrode_ids = [e.electrode_id for e in geometry.electrodes]
        msg.electrodes = [mesh_to_msg(e.mesh) for e in geometry.electrodes]
        msg.electrode_final_poses = matrices_to_poses([e.final_pose for e in geometry.electrodes])
        self.geometry_pub.publish(msg)
        with self._lock:                         # first the source, then the count: a viewer matched meanwhile
            self._marker_source = (self._published, meshes, geometry.electrodes, frame, stamp)   # finds it
        if self.marker_pub.get_subscription_count():
            self._submit_markers()

    def _on_marker_match(self, status):
        if status.current_count_change > 0:      # a viewer came: it may not have the latest markers yet
            self._submit_markers()

    def _submit_markers(self):
        try:
            self._marker_work.submit(self._publish_latest_markers)
        except RuntimeError:                     # the node is being destroyed
            pass

    def _publish_latest_markers(self):
        """The latest geometry's markers on the latched topic, unless it holds them or no viewer listens."""
        with self._lock:
            source = self._marker_source
        if source is None or source[0] == self._markers_on_topic or not self.marker_pub.get_subscription_count():
            return
        publication, meshes, electrodes, frame, stamp = source
        try:
            markers = MarkerArray()
            for i, label in enumerate(CHANNEL_SURFACES):
                markers.markers.append(mesh_marker(meshes[label], "channel", i, frame, stamp, COLOURS[label]))
            for i, e in enumerate(electrodes):
                markers.markers.append(mesh_marker(e.mesh, "electrode", i, frame, stamp, (0.85, 0.5, 0.2, 0.9),
                                                   pose=e.final_pose))
            self.marker_builds += 1
            self.marker_pub.publish(markers)
            self._markers_on_topic = publication
        except Exception as exc:  # a viewer's markers must not take the node down
            self.get_logger().error(f"markers not published: {exc!r}")

    def destroy_node(self):
        self._marker_work.shutdown(wait=True, cancel_futures=True)      # no publish on a destroyed node
        return super().destroy_node()


def main(args=None):
    """Console entry point ``geometry_loader``."""
    return spin_node(GeometryLoaderNode, args)
