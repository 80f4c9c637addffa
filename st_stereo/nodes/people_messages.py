"""
Messages of the people node from ``st_stereo.core.people`` tracks (no node state here).

- ``poses_msg``: geometry_msgs/PoseArray, one pose per person on the floor (z = 0), facing
  the direction of walking (identity while slower than ``FACING_MIN_SPEED``).
- ``detections_cloud``: sensor_msgs/PointCloud2, one point per person, float32 fields
  ``DETECTION_FIELDS`` (x, y, z = 0 on the floor; id; vx, vy in m/s; head height; confidence
  0..1; points used; the floor position covariance cov_xx, cov_xy, cov_yy in m^2;
  head_visible 1 when the height is the median of the track's detections seen whole, 0 when
  it is a lower bound: the body cut by the image's edge, or its head in the image's top rows).
- ``markers_msg``: visualization_msgs/MarkerArray, a cylinder (floor to head) and a text
  with the id per person, namespaces ``people`` and ``people_ids``, marker id = track id;
  a track that ended gets DELETE markers of both.
- ``detection3d_msg``: vision_msgs/Detection3DArray when vision_msgs is importable (it is not
  installable from the package index: tested with a stand-in module).
"""

import math

from geometry_msgs.msg import Pose, PoseArray
import numpy as np
from sensor_msgs.msg import PointCloud2, PointField
from visualization_msgs.msg import Marker, MarkerArray

DETECTION_FIELDS = ('x', 'y', 'z', 'id', 'vx', 'vy', 'height', 'confidence', 'points',
                    'cov_xx', 'cov_xy', 'cov_yy', 'head_visible')
FACING_MIN_SPEED = 0.2       # m/s: slower, the pose keeps the identity orientation
CYLINDER_DIAMETER_M = 0.5
MARKER_LIFETIME_S = 1.0      # a marker not refreshed disappears (a node that stopped)


def _yaw_quaternion(pose, vx, vy):
    if math.hypot(vx, vy) >= FACING_MIN_SPEED:
        yaw = math.atan2(vy, vx)
        pose.orientation.z, pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    else:
        pose.orientation.w = 1.0


def poses_msg(header, tracks):
    """Build the PoseArray of the tracks (header: the pair's stamp, the world frame)."""
    msg = PoseArray()
    msg.header = header
    for track in tracks:
        pose = Pose()
        pose.position.x, pose.position.y = (float(v) for v in track.position)
        _yaw_quaternion(pose, float(track.state[2]), float(track.state[3]))
        msg.poses.append(pose)
    return msg


def detection_rows(tracks):
    """Return the (n, len(DETECTION_FIELDS)) float32 rows of the tracks."""
    rows = np.zeros((len(tracks), len(DETECTION_FIELDS)), dtype='<f4')
    for row, track in zip(rows, tracks):
        cov = track.position_covariance
        x, y = track.position
        row[:] = (x, y, 0.0, track.track_id, track.state[2],
                  track.state[3], track.head_height, track.confidence, track.points,
                  cov[0, 0], cov[0, 1], cov[1, 1], float(track.head_visible))
    return rows


def detections_cloud(header, tracks):
    """Build the PointCloud2 with one point per person (``DETECTION_FIELDS``, float32)."""
    rows = detection_rows(tracks)
    msg = PointCloud2()
    msg.header = header
    msg.height, msg.width = 1, len(rows)
    msg.fields = [PointField(name=name, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, name in enumerate(DETECTION_FIELDS)]
    msg.is_bigendian = False
    msg.point_step = 4 * len(DETECTION_FIELDS)
    msg.row_step = msg.point_step * len(rows)
    msg.is_dense = True
    msg.data = rows.tobytes()
    return msg


def markers_msg(header, tracks, ended):
    """Build the MarkerArray: a cylinder and an id text per track; DELETE for ``ended``."""
    msg = MarkerArray()
    for track in tracks:
        height = max(float(track.head_height) + 0.1, 0.2)
        cylinder = Marker()
        cylinder.header = header
        cylinder.ns, cylinder.id = 'people', int(track.track_id)
        cylinder.type, cylinder.action = Marker.CYLINDER, Marker.ADD
        cylinder.pose.position.x, cylinder.pose.position.y = (float(v) for v in track.position)
        cylinder.pose.position.z = height / 2
        cylinder.pose.orientation.w = 1.0
        cylinder.scale.x = cylinder.scale.y = CYLINDER_DIAMETER_M
        cylinder.scale.z = height
        cylinder.color.r, cylinder.color.g, cylinder.color.b, cylinder.color.a = \
            0.9, 0.4, 0.1, 0.6
        cylinder.lifetime.sec = int(MARKER_LIFETIME_S)
        text = Marker()
        text.header = header
        text.ns, text.id = 'people_ids', int(track.track_id)
        text.type, text.action = Marker.TEXT_VIEW_FACING, Marker.ADD
        text.pose.position.x, text.pose.position.y = (float(v) for v in track.position)
        text.pose.position.z = height + 0.2
        text.pose.orientation.w = 1.0
        text.scale.z = 0.25
        text.color.r = text.color.g = text.color.b = text.color.a = 1.0
        text.text = str(track.track_id)
        text.lifetime.sec = int(MARKER_LIFETIME_S)
        msg.markers += [cylinder, text]
    for track_id in ended:
        for namespace in ('people', 'people_ids'):
            marker = Marker()
            marker.header = header
            marker.ns, marker.id, marker.action = namespace, int(track_id), Marker.DELETE
            msg.markers.append(marker)
    return msg


def detection3d_msg(vision_msgs, header, tracks):
    """
    Build the vision_msgs/Detection3DArray of the tracks (``vision_msgs``: the module).

    Each detection: the bounding box from the floor to the head, the id as ``results[0]``'s
    hypothesis ``class_id`` 'person' with the confidence as score and the floor position and
    its covariance as the pose (6x6, row-major: x, y filled, the others 0), ``id`` the track id.
    """
    msg = vision_msgs.Detection3DArray()
    msg.header = header
    for track in tracks:
        detection = vision_msgs.Detection3D()
        detection.header = header
        detection.id = str(track.track_id)
        height = max(float(track.head_height) + 0.1, 0.2)
        detection.bbox.center.position.x = float(track.position[0])
        detection.bbox.center.position.y = float(track.position[1])
        detection.bbox.center.position.z = height / 2
        detection.bbox.center.orientation.w = 1.0
        detection.bbox.size.x = detection.bbox.size.y = CYLINDER_DIAMETER_M
        detection.bbox.size.z = height
        hypothesis = vision_msgs.ObjectHypothesisWithPose()
        hypothesis.hypothesis.class_id = 'person'
        hypothesis.hypothesis.score = float(track.confidence)
        hypothesis.pose.pose.position.x = float(track.position[0])
        hypothesis.pose.pose.position.y = float(track.position[1])
        hypothesis.pose.pose.orientation.w = 1.0
        covariance = [0.0] * 36
        cov = track.position_covariance
        covariance[0], covariance[1], covariance[6], covariance[7] = \
            float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 0]), float(cov[1, 1])
        hypothesis.pose.covariance = covariance
        detection.results.append(hypothesis)
        msg.detections.append(detection)
    return msg
