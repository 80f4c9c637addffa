"""
The people node with real rclpy: topics, stamps, frames, and bad input.

Most inputs are handed to the node's callbacks directly, the outputs received over Fast DDS on
loopback by a subscriber; one test publishes the inputs over DDS too, with the QoS the
matcher and rectifier publish with. The person is made in the
simulated room and put into the rectified left frame by the simulator's camera model.
"""

import os

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseArray
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_helpers import keep_statuses, spin_until
from sensor_msgs.msg import PointCloud2
from st_stereo.core.people import project_to_pixels
from st_stereo.nodes.conversions import camera_info_from_calibration, image_to_msg, \
    point_cloud, point_cloud_fields
from st_stereo.nodes.people_messages import DETECTION_FIELDS
from st_stereo.nodes.people_node import PeopleNode
from st_stereo.sim.sequences import standard_sequences
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
RIG = standard_sequences()['walk_across'].rig
POSE = RIG.rig_pose()
LEFT = RIG.calibrations()[0]


class PeopleCollector(Node):
    def __init__(self, context):
        super().__init__('people_collector', context=context, namespace='stereo')
        self.poses, self.clouds, self.markers, self.statuses = [], [], [], {}
        self.create_subscription(PoseArray, 'people/poses', self.poses.append, 10)
        self.create_subscription(PointCloud2, 'people/detections', self.clouds.append, 10)
        self.create_subscription(MarkerArray, 'people/markers', self.markers.append, 10)
        self.create_subscription(DiagnosticArray, '/diagnostics',
                                 lambda msg: keep_statuses(self.statuses, msg), 10)


def people_node(context, *extra):
    """Return a people node at the simulated rig's true pose (``extra``: more Parameters)."""
    overrides = [Parameter('world_frame', value='room')] + [
        Parameter(field, value=float(getattr(POSE, field)))
        for field in ('x_m', 'y_m', 'height_m', 'yaw_deg', 'tilt_deg', 'roll_deg')]
    return PeopleNode(context=context, parameter_overrides=overrides + list(extra))


def connected_people_node(ros, *extra):
    """Return (executor, collector, node): a people node with its camera_info, a collector."""
    context, executor, add = ros
    collector = add(PeopleCollector(context))
    node = add(people_node(context, *extra))
    node._on_camera_info(camera_info_from_calibration(LEFT, Header()))
    spin_until(executor, lambda: all(
        collector.count_publishers(topic) >= 1
        for topic in ('people/poses', 'people/detections', 'people/markers')), 10.0)
    return executor, collector, node


def person_in_rectified_frame(x, y, seed):
    """Points on a standing person's front at (x, y) in the room, in the rectified frame."""
    rng = np.random.default_rng(seed)
    heights = rng.uniform(0.7, 1.75, 150)
    angle = rng.uniform(-1.0, 1.0, 150) - np.pi / 2
    world = np.column_stack([x + 0.12 * np.cos(angle), y + 0.12 * np.sin(angle), heights])
    return RIG.to_rectified_left(world)


def pair_messages(sec, points):
    """Return the matcher's points2 and the rectifier's left image (warm at the points)."""
    header = Header(frame_id='stereo_left_optical_frame')
    header.stamp.sec = sec
    p = LEFT.projection
    image = np.full((60, 80), 8000.0)
    if len(points):
        u, v = project_to_pixels(points, p[0, 0], p[1, 1], p[0, 2], p[1, 2])
        inside = (u >= 0) & (u < 80) & (v >= 0) & (v < 60)
        image[np.rint(v[inside]).astype(int).clip(0, 59),
              np.rint(u[inside]).astype(int).clip(0, 79)] += 400
    disparity = RIG.fx_baseline / np.maximum(points[:, 2], 1e-3)
    pixels = project_to_pixels(points, p[0, 0], p[1, 1], p[0, 2], p[1, 2])   # u, v
    cloud = point_cloud(header, points, disparity, np.ones(len(points)), np.zeros(len(points)),
                        np.ones(len(points)), pixels)
    return cloud, image_to_msg(image.astype(np.uint16), header)


def feed(node, cloud, image):
    """Hand a pair over as the executor does: the image first (the rectifier's), then points2."""
    if image is not None:
        node._on_image(image)
    node._on_points(cloud)


def test_people_wait_for_camera_info_then_come_with_the_pair_stamp_in_the_world_frame(ros):
    context, executor, add = ros
    collector = add(PeopleCollector(context))
    node = add(people_node(context))
    spin_until(executor, lambda: node.count_subscribers('people/poses') >= 1 and
               collector.count_publishers('people/poses') >= 1, 10.0)
    feed(node, *pair_messages(100, person_in_rectified_frame(0.2, 2.0, 0)))
    spin_until(executor, lambda: False, 0.3)
    assert node.counts['waiting_for_camera_info'] == 1 and not collector.poses
    node._on_camera_info(camera_info_from_calibration(LEFT, Header()))
    for sec in range(101, 106):
        feed(node, *pair_messages(sec, person_in_rectified_frame(0.2, 2.0, sec)))
    spin_until(executor, lambda: len(collector.clouds) >= 5 and len(collector.poses) >= 5,
               10.0)
    assert [p.header.stamp.sec for p in collector.poses] == list(range(101, 106))
    assert {p.header.frame_id for p in collector.poses} == {'room'}
    last = point_cloud_fields(collector.clouds[-1], DETECTION_FIELDS)
    assert len(last['x']) == 1
    assert (last['x'][0], last['y'][0]) == pytest.approx((0.2, 2.0), abs=0.15)
    assert last['height'][0] == pytest.approx(1.75, abs=0.1)
    assert collector.markers[-1].markers[0].ns == 'people'
    spin_until(executor, lambda: 'stereo/people: people' in collector.statuses, 5.0)
    assert collector.statuses['stereo/people: people']['waiting_for_camera_info'] == '1'


def test_an_empty_scene_publishes_empty_messages(ros):
    executor, collector, node = connected_people_node(ros)
    feed(node, *pair_messages(7, np.zeros((0, 3))))
    spin_until(executor, lambda: collector.poses and collector.clouds and collector.markers,
               10.0)
    assert collector.poses[0].poses == [] and collector.clouds[0].width == 0
    assert collector.poses[0].header.stamp.sec == 7


def test_a_cloud_without_z_is_dropped_counted_and_reported(ros):
    executor, collector, node = connected_people_node(ros)
    cloud, image = pair_messages(3, person_in_rectified_frame(0.0, 3.0, 1))
    cloud.fields = [f for f in cloud.fields if f.name != 'z']
    feed(node, cloud, image)
    assert node.counts['dropped_bad_input'] == 1
    spin_until(executor, lambda: 'stereo/people: people' in collector.statuses, 5.0)
    assert collector.statuses['stereo/people: people']['dropped_bad_input'] == '1'
    assert "no field(s) ['z']" in node.last_error


def test_a_person_at_the_image_border_is_published_without_a_crash(ros):
    executor, collector, node = connected_people_node(ros)
    # This person's right half is outside the image (columns 74-91 of 80): the pixels off the
    # image are clipped, never indexed out of range, and the body is cut by the side edge.
    for sec in range(1, 5):
        feed(node, *pair_messages(sec, person_in_rectified_frame(1.0, 2.0, sec)))
    spin_until(executor, lambda: len(collector.clouds) >= 4, 10.0)
    assert len(collector.clouds) == 4
    last = point_cloud_fields(collector.clouds[-1], DETECTION_FIELDS)
    assert last['x'].size == 1 and last['head_visible'][0] == 0.0
    assert last['x'][0] == pytest.approx(1.0, abs=0.2)


class RigInputs(Node):
    """Publishes points2, left/image_rect and left/camera_info as the suite does (RELIABLE 5)."""

    def __init__(self, context):
        from sensor_msgs.msg import CameraInfo, Image
        from st_stereo.nodes.runtime import RELIABLE
        super().__init__('rig_inputs', context=context, namespace='stereo')
        self.points = self.create_publisher(PointCloud2, 'points2', RELIABLE)
        self.image = self.create_publisher(Image, 'left/image_rect', RELIABLE)
        self.info = self.create_publisher(CameraInfo, 'left/camera_info', RELIABLE)


def test_people_from_inputs_published_over_dds(ros):
    context, executor, add = ros
    collector = add(PeopleCollector(context))
    node = add(people_node(context))
    inputs = add(RigInputs(context))
    spin_until(executor, lambda: inputs.points.get_subscription_count() >= 1 and
               inputs.image.get_subscription_count() >= 1 and
               collector.count_publishers('people/detections') >= 1, 10.0)
    for sec in range(1, 7):
        cloud, image = pair_messages(sec, person_in_rectified_frame(-0.3, 2.1, sec))
        info = camera_info_from_calibration(LEFT, image.header)
        inputs.info.publish(info)
        inputs.image.publish(image)
        spin_until(executor, lambda: False, 0.05)
        inputs.points.publish(cloud)
        spin_until(executor, lambda s=sec: any(c.header.stamp.sec == s
                                               for c in collector.clouds), 5.0)
    assert [c.header.stamp.sec for c in collector.clouds] == list(range(1, 7))
    last = point_cloud_fields(collector.clouds[-1], DETECTION_FIELDS)
    assert (last['x'][0], last['y'][0]) == pytest.approx((-0.3, 2.1), abs=0.15)
    assert node.counts['pairs_without_image'] == 0


def test_points_without_their_image_still_publish_and_are_counted(ros):
    executor, collector, node = connected_people_node(ros)
    for sec in range(1, 4):
        cloud, _ = pair_messages(sec, person_in_rectified_frame(0.2, 2.0, sec))
        feed(node, cloud, None)
    spin_until(executor, lambda: len(collector.poses) >= 3, 10.0)
    assert node.counts['pairs_without_image'] == 3
    assert [len(p.poses) for p in collector.poses] == [0, 0, 0]
    spin_until(executor, lambda: 'stereo/people: people' in collector.statuses, 5.0)
    assert collector.statuses['stereo/people: people']['pairs_without_image'] == '3'


def test_without_use_image_points_alone_find_the_person(ros):
    executor, collector, node = connected_people_node(ros, Parameter('use_image', value=False))
    for sec in range(1, 4):
        node._on_points(pair_messages(sec, person_in_rectified_frame(0.2, 2.0, sec))[0])
    spin_until(executor, lambda: len(collector.clouds) >= 3, 10.0)
    assert point_cloud_fields(collector.clouds[-1], ('x',))['x'].size == 1
    assert node.estimator.counts['no_image'] == 3


def test_a_camera_info_without_a_projection_is_rejected_and_named(ros):
    context, executor, add = ros
    node = add(people_node(context))
    info = camera_info_from_calibration(LEFT, Header())
    info.p = [0.0] * 12
    node._on_camera_info(info)
    assert node.camera_info is None and node.counts['camera_info_rejected'] == 1
    assert 'P: expected fx = P[0] > 0' in node.last_error
    info = camera_info_from_calibration(LEFT, Header())
    info.r = [2.0, 0, 0, 0, 1, 0, 0, 0, 1]
    node._on_camera_info(info)
    assert node.camera_info is None and 'R: not a rotation matrix' in node.last_error
    feed(node, *pair_messages(1, person_in_rectified_frame(0.2, 2.0, 1)))
    assert node.counts['waiting_for_camera_info'] == 1


def far_body_in_rectified_frame(x, y, seed, lowest=0.0):
    """Return a standing person's front from ``lowest`` up, as much as the image shows."""
    rng = np.random.default_rng(seed)
    heights = rng.uniform(lowest, 1.75, 400)
    angle = rng.uniform(-1.0, 1.0, 400) - np.pi / 2
    world = np.column_stack([x + 0.12 * np.cos(angle), y + 0.12 * np.sin(angle), heights])
    points = RIG.to_rectified_left(world)
    p = LEFT.projection
    u, v = project_to_pixels(points, p[0, 0], p[1, 1], p[0, 2], p[1, 2])
    return points[(u >= 0) & (u <= 79) & (v >= 0) & (v <= 59)]


@pytest.mark.parametrize('lowest, published', [(0.0, True), (0.7, False)])
def test_a_far_body_cut_by_the_top_edge_is_a_person_on_its_legs_and_not_without(
        ros, lowest, published):
    executor, collector, node = connected_people_node(ros)
    # 4.6 m away: the head is above the image (only what is below about 1.1 m shows).
    for sec in range(1, 5):
        feed(node, *pair_messages(sec, far_body_in_rectified_frame(-1.0, 4.6, sec, lowest)))
    spin_until(executor, lambda: len(collector.clouds) >= 4, 10.0)
    counts = [point_cloud_fields(c, ('x',))['x'].size for c in collector.clouds]
    tracks = node.estimator.tracker.tracks
    assert tracks and all(track.cut_top for track in tracks)
    if published:                                  # from the second pair (min_hits 2)
        assert counts == [0, 1, 1, 1]
        last = point_cloud_fields(collector.clouds[-1], DETECTION_FIELDS)
        assert last['head_visible'][0] == 0.0
        assert (last['x'][0], last['y'][0]) == pytest.approx((-1.0, 4.6), abs=0.3)
        seen = '4'
    else:                                          # a warm slab on a desk looks the same
        assert counts == [0, 0, 0, 0]
        seen = '0'
    spin_until(executor, lambda: 'people cut_legs_seen' in
               collector.statuses.get('stereo/people: people', {}), 10.0)
    status = collector.statuses['stereo/people: people']
    assert status['people cut_legs_seen'] == seen
    assert int(status['people cut_legs_checked']) >= 4


def far_pairs_rendered(count):
    """Rectified (left, right) images of one person standing 4.6 m off in the meeting room."""
    import math

    from st_stereo.core.rectification import StereoRectifier
    from st_stereo.sim import people as sim_people
    from st_stereo.sim import sequences
    spec = sequences.SequenceSpec(
        'far_person_node_test', 'one person standing far off, the head above the image',
        (sequences.PersonScript((sequences.Keyframe(0.0, 1.5, 4.6),
                                 sequences.Keyframe(9.0, 1.5, 4.6)),
                                sim_people.PersonLook(seed=11), heading_rad=math.pi),),
        duration_s=count / 8.7, rig=RIG, room='meeting_room')
    renderer = sequences.SequenceRenderer(spec)
    rectifier = StereoRectifier(*RIG.calibrations())
    for t_left, t_right in spec.pair_times():
        frame = renderer.frame(t_left, right_t=t_right)
        yield rectifier.rectify(frame['left'], frame['right'])


def pair_info_msg(header, skew_s):
    """Return the driver's pair_info of a pair (both cameras at its stamp, ``skew_s`` apart)."""
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from st_stereo.lepton.pairing import pair_info_values
    stamp = header.stamp.sec + 1e-9 * header.stamp.nanosec
    values = pair_info_values(skew_s, (stamp, stamp + skew_s), (0, 0), (False, False))
    return DiagnosticArray(header=header, status=[DiagnosticStatus(
        name='pair', values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])])


def right_messages(index, left, right):
    """points2 without a point, the left and the right images of pair ``index`` (8.7 Hz)."""
    header = Header(frame_id='stereo_left_optical_frame')
    header.stamp.sec, header.stamp.nanosec = 1 + index // 8, int(115e6 * (index % 8))
    empty = np.empty((0, 3))
    cloud = point_cloud(header, empty, np.empty(0), np.empty(0), np.empty(0), np.empty(0))
    return (cloud, image_to_msg(np.rint(left).astype(np.uint16), header),
            image_to_msg(np.rint(right).astype(np.uint16), header))


def test_with_the_right_image_a_far_body_without_matches_is_placed_by_its_silhouette(ros):
    executor, collector, node = connected_people_node(ros)
    node._on_right_info(camera_info_from_calibration(RIG.calibrations()[1], Header()))
    for sec, (left, right) in enumerate(far_pairs_rendered(4), start=1):
        cloud, left_msg, right_msg = right_messages(sec, left, right)
        node._on_image(left_msg)
        node._on_right_image(right_msg)
        if sec > 1:                                   # the first pair's pair_info is lost
            node._on_pair_info(pair_info_msg(cloud.header, 0.0))
        node._on_points(cloud)
    assert node.counts['pairs_without_right_image'] == 0
    assert node.counts['pairs_without_pair_info'] == 1
    assert node.estimator.counts['silhouette_detections'] >= 3
    # Skew 0 (the rendering's): corrected by nothing, but its motion measured from the second
    # pair on; the first had no pair_info.
    assert node.estimator.counts['silhouette_skew_corrected'] >= 2
    tracks = node.estimator.tracker.tracks
    assert len(tracks) == 1 and tracks[0].cut_top
    assert (tracks[0].state[0], tracks[0].state[1]) == pytest.approx((1.5, 4.6), abs=0.35)
    # Standing far off without legs seen, it is not published (a warm screen looks the same).
    spin_until(executor, lambda: len(collector.clouds) >= 4, 10.0)
    assert [point_cloud_fields(c, ('x',))['x'].size for c in collector.clouds] == [0] * 4


def test_pairs_without_the_right_image_are_counted_and_a_bad_one_named(ros):
    executor, collector, node = connected_people_node(ros)
    left, right = next(far_pairs_rendered(1))
    cloud, left_msg, right_msg = right_messages(1, left, right)
    feed(node, cloud, left_msg)                     # no right/camera_info, no right image
    assert node.counts['pairs_without_right_image'] == 1
    info = camera_info_from_calibration(RIG.calibrations()[1], Header())
    info.p = [info.p[0], 0.0, info.p[2], 0.0] + list(info.p[4:])   # P[3] = 0: no baseline
    node._on_right_info(info)
    assert node.right_projection is None and node.counts['right_camera_info_rejected'] == 1
    assert 'right/camera_info: P: expected' in node.right_error
    node._on_right_info(camera_info_from_calibration(RIG.calibrations()[1], Header()))
    # A right image of another size: the pair goes on without silhouettes, a near person's
    # points still make it.
    header = Header(frame_id='stereo_left_optical_frame')
    for sec in range(2, 5):
        cloud, image = pair_messages(sec, person_in_rectified_frame(0.2, 2.0, sec))
        header.stamp.sec = sec
        node._on_right_image(image_to_msg(np.full((60, 79), 8000, np.uint16), header))
        feed(node, cloud, image)
    assert node.counts['dropped_bad_input'] == 0
    assert node.counts['right_image_rejected'] == 3
    assert 'right/image_rect: 79x60, left/image_rect is 80x60' in node.right_error
    spin_until(executor, lambda: len(collector.clouds) >= 4, 10.0)
    assert point_cloud_fields(collector.clouds[-1], ('x',))['x'].size == 1
    messages = []
    collector.create_subscription(DiagnosticArray, '/diagnostics', lambda msg: messages.extend(
        status.message for status in msg.status if status.name == 'stereo/people: people'), 10)
    spin_until(executor, lambda: messages, 5.0)
    assert messages[-1].startswith('no silhouettes: right/image_rect: 79x60')


def test_right_images_that_never_come_are_a_warning(ros):
    executor, collector, node = connected_people_node(ros)
    node._on_right_info(camera_info_from_calibration(RIG.calibrations()[1], Header()))
    messages = []
    collector.create_subscription(DiagnosticArray, '/diagnostics', lambda msg: messages.extend(
        status.message for status in msg.status if status.name == 'stereo/people: people'), 10)
    for sec in range(1, 4):
        feed(node, *pair_messages(sec, person_in_rectified_frame(0.2, 2.0, sec)))
    assert node.counts['pairs_without_right_image'] == 3
    spin_until(executor, lambda: messages, 5.0)
    assert messages[-1].startswith('no right/image_rect with the stamps of points2')


def test_a_cloud_in_another_frame_than_the_camera_info_is_dropped_and_named(ros):
    context, executor, add = ros
    collector = add(PeopleCollector(context))
    node = add(people_node(context))
    node._on_camera_info(camera_info_from_calibration(
        LEFT, Header(frame_id='stereo_left_optical_frame')))
    cloud, image = pair_messages(1, person_in_rectified_frame(0.2, 2.0, 1))
    cloud.header.frame_id = 'base_link'
    feed(node, cloud, image)
    assert node.counts['dropped_frame_mismatch'] == 1 and node.counts['dropped_bad_input'] == 1
    assert "points2: frame 'base_link', expected 'stereo_left_optical_frame'" in node.last_error
    assert node.counts['published'] == 0
    feed(node, *pair_messages(2, person_in_rectified_frame(0.2, 2.0, 2)))
    assert node.counts['published'] == 1 and node.last_error == ''
    spin_until(executor, lambda: collector.poses, 10.0)
    assert collector.poses[0].header.stamp.sec == 2


def test_a_left_image_not_in_raw_counts_or_empty_is_refused_and_named(ros):
    executor, collector, node = connected_people_node(ros)
    cloud, image = pair_messages(1, person_in_rectified_frame(0.2, 2.0, 1))
    mono8 = image_to_msg(np.full((60, 80), 200, dtype=np.uint8), image.header, 'mono8')
    feed(node, cloud, mono8)
    assert node.counts['dropped_bad_input'] == 1
    assert 'left/image_rect: encoding mono8, expected mono16 or 16UC1' in node.last_error
    cloud, image = pair_messages(2, person_in_rectified_frame(0.2, 2.0, 2))
    feed(node, cloud, image_to_msg(np.zeros((0, 0), dtype=np.uint16), image.header))
    assert node.counts['dropped_bad_input'] == 2
    assert 'left/image_rect: empty image' in node.last_error


def test_points_left_out_of_the_detections_are_counted(ros):
    executor, collector, node = connected_people_node(
        ros, Parameter('min_confidence', value=0.5))
    points = person_in_rectified_frame(0.2, 2.0, 1)
    cloud, image = pair_messages(1, points)
    header = cloud.header
    behind = points.copy()
    behind[:3, 2] *= -1.0
    disparity = np.full(len(points), np.nan)
    disparity[:10] = 5.0
    confidence = np.where(np.arange(len(points)) < 4, 0.3, 1.0)
    cloud = point_cloud(header, behind, disparity, np.ones(len(points)),
                        np.zeros(len(points)), confidence)
    feed(node, cloud, image)
    assert node.counts['points_behind_camera'] == 3 and node.counts['points_not_finite'] == 0
    counts = node.estimator.counts
    assert counts['points_without_disparity'] == len(points) - 10
    assert counts['points_below_min_confidence'] == 1     # point 3: in front, 0.3, d = 5
    assert node.counts['published'] == 1


def test_an_error_in_the_people_stage_is_counted_and_the_node_goes_on(ros, monkeypatch):
    executor, collector, node = connected_people_node(ros)
    process = node.estimator.process

    def failing(*args, **kwargs):
        raise IndexError('index 0 is out of bounds')

    monkeypatch.setattr(node.estimator, 'process', failing)
    feed(node, *pair_messages(1, person_in_rectified_frame(0.2, 2.0, 1)))
    assert node.counts['dropped_internal_error'] == 1 and node.counts['published'] == 0
    assert 'IndexError: index 0 is out of bounds' in node.last_error
    spin_until(executor, lambda: 'stereo/people: people' in collector.statuses, 5.0)
    status = collector.statuses['stereo/people: people']
    assert status['dropped_internal_error'] == '1'
    monkeypatch.setattr(node.estimator, 'process', process)
    feed(node, *pair_messages(2, person_in_rectified_frame(0.2, 2.0, 2)))
    assert node.counts['published'] == 1 and node.last_error == ''


@pytest.mark.parametrize('value', [0.0, -8.7, float('inf'), float('nan')])
def test_a_target_frequency_that_is_not_a_rate_is_refused(ros, value):
    context, executor, add = ros
    with pytest.raises(ValueError, match='target_frequency: expected a finite number above 0'):
        people_node(context, Parameter('target_frequency', value=value))
    node = add(people_node(context))
    result = node.set_parameters([Parameter('target_frequency', value=value)])[0]
    assert not result.successful and 'expected a finite number above 0' in result.reason
    assert node.frequency.target_hz == pytest.approx(8.7)


def test_points_are_put_back_at_their_features_pixels():
    # points2 places points at their window's structure (point_location, the default since
    # 2026-12-07); the people stage was chosen on points at their features: each point goes
    # back on its feature's ray at its own depth; without u, v (an older cloud) it stays.
    from st_stereo.core.triangulation import at_their_features
    p = np.array([[80.0, 0.0, 40.0, 0.0], [0.0, 82.0, 30.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    at_structure = np.array([[0.10, -0.20, 3.0], [0.50, 0.10, 4.0], [0.0, 0.0, np.nan]])
    u, v = np.array([48.0, 50.0, 41.0]), np.array([22.0, np.nan, 29.0])
    placed, count = at_their_features(at_structure, u, v, p)
    assert count == 1
    np.testing.assert_allclose(placed[0], [(48 - 40) * 3.0 / 80, (22 - 30) * 3.0 / 82, 3.0])
    np.testing.assert_array_equal(placed[1], at_structure[1])          # no pixel: as it is
    assert np.isnan(placed[2, 2])
    unchanged, none = at_their_features(at_structure, None, None, p)
    assert none == 0 and np.array_equal(unchanged, at_structure, equal_nan=True)


def test_a_cloud_without_feature_pixels_is_used_as_it_lies_and_said(ros):
    # An older matcher's cloud (28-byte points, at their features) or one a filter stripped
    # of u, v: used as it is, counted, and a WARN says the people stage may not see what it
    # was tuned on (a review: the old people node on the new default cloud lost sit_down's
    # far walker, recall 0.990 -> 0.856, silently).
    context, executor, add = ros
    node = add(people_node(context))
    node._on_camera_info(camera_info_from_calibration(LEFT, Header()))
    cloud, image = pair_messages(100, person_in_rectified_frame(0.2, 2.0, 0))
    count = cloud.width
    old = PointCloud2(header=cloud.header, height=1, width=count, fields=cloud.fields[:7],
                      is_bigendian=False, point_step=28, row_step=28 * count, is_dense=True,
                      data=np.frombuffer(bytes(cloud.data), '<f4').reshape(count, 9)[:, :7]
                      .astype('<f4').tobytes())
    feed(node, old, image)
    assert node.counts['clouds_without_feature_pixels'] == 1
    assert node.counts['points_placed_at_their_features'] == 0
    assert node.counts['dropped_bad_input'] == 0
    statuses = {}
    node.diagnostics_pub.publish = lambda msg: statuses.update(
        {status.name: status for status in msg.status})
    node._publish_diagnostics()
    status = next(iter(statuses.values()))
    assert status.level == DiagnosticStatus.WARN
    assert status.message.startswith('points2 without the fields u, v')
    cloud.header.stamp.sec = image.header.stamp.sec = 101
    feed(node, cloud, image)                            # with them: the warning goes
    assert node.counts['points_placed_at_their_features'] == count
    node._publish_diagnostics()
    assert not next(iter(statuses.values())).message.startswith('points2 without')
