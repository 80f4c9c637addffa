"""
People on the floor (st_stereo.core.people), its messages and its scoring, without rclpy.

The geometry is checked against the simulator's own camera model (not the code's), the
detector on synthetic point sets with known people, the tracker on scripted walks, the
scoring against motmetrics on hand-made tracks.
"""

import dataclasses
import math
import pathlib
import types

import numpy as np
import pytest
from st_stereo.core.people import (centred_on_silhouette, detect_people, Detection,
                                   gated_assignment,
                                   legs_fraction, legs_only_bodies, PeopleConfig, PeopleEstimator,
                                   PeopleTracker, rectified_to_world, silhouette_reaches_top,
                                   silhouette_runs, silhouette_shift_xy, standing_on_legs,
                                   top_edge_height_m, vertical_segment_rows,
                                   walks_steadily, warm_column_gap_m, warm_column_reaches_top,
                                   warm_run_width_m,
                                   WarmBackground, world_from_rectified)
from st_stereo.core.rig_pose import load_rig_pose
from st_stereo.nodes.conversions import point_cloud_fields
from st_stereo.nodes.people_messages import (detection3d_msg, DETECTION_FIELDS,
                                             detections_cloud, markers_msg, poses_msg)
from st_stereo.sim.sequences import standard_sequences
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

REPO = pathlib.Path(__file__).resolve().parents[1]
CAMERA = np.array([0.0, 0.0, 2.9])


def test_rectified_points_go_to_the_room_as_the_simulator_placed_them():
    rig = standard_sequences()['walk_across'].rig
    transform = world_from_rectified(rig.rig_pose(), rig.rectification()[0])
    world = np.array([[0.5, 2.0, 1.0], [-1.0, 3.0, 1.7], [0.2, 4.0, 0.0], [1.3, 2.5, 0.4]])
    back = rectified_to_world(rig.to_rectified_left(world), transform)
    np.testing.assert_allclose(back, world, atol=1e-9)


def test_the_bundled_recording_ships_its_true_rig_pose():
    pose = load_rig_pose(REPO / 'data' / 'recordings' / 'office' / 'rig_pose.yaml')
    assert pose == standard_sequences()['office'].rig.rig_pose()


@pytest.mark.parametrize('field, value, message', [
    ('min_points', 0, 'min_points: expected an integer >= 1'),
    ('gate_m', -1.0, 'gate_m: expected a number > 0'),
    ('publish_coast_s', 9.0, 'publish_coast_s: expected 0 .. max_coast_s'),
    ('unconfirmed_coast_s', -1.0, 'unconfirmed_coast_s: expected 0 .. max_coast_s'),
    ('min_confidence', 1.5, 'min_confidence: expected 0..1'),
    ('legs_min_fraction', -0.1, 'legs_min_fraction: expected 0..1'),
    ('legs_depth_tolerance_m', 0.0, 'legs_depth_tolerance_m: expected a number > 0'),
    ('legs_max_gap_m', -1.0, 'legs_max_gap_m: expected a number > 0'),
    ('far_legs_min_height_m', 0.6, r'far_legs_min_height_m: expected 0 \(off\) or a value '
     r'below min_point_height_m \(0.6\)'),
    ('far_legs_max_width_m', 0.0, 'far_legs_max_width_m: expected a number > 0'),
    ('object_min_hits', -1, r'object_min_hits: expected an integer >= 0 \(0: off\), got -1'),
    ('object_min_hits', 2.0, r'object_min_hits: expected an integer >= 0'),
    ('object_radius_m', 0.0, 'object_radius_m: expected a number > 0'),
    ('confirm_on_legs', 'false', "confirm_on_legs: expected true or false, got 'false'"),
    ('require_warm', 1, 'require_warm: expected true or false, got 1'),
    ('legs_lapse_s', -1.0, r'legs_lapse_s: expected a number >= 0 \(0: never\), got -1.0'),
    ('legs_lapse_s', True, r'legs_lapse_s: expected a number >= 0 \(0: never\), got True'),
    ('legs_lapse_s', '5', r"legs_lapse_s: expected a number >= 0 \(0: never\), got '5'"),
    ('legs_lapse_s', float('nan'), r'legs_lapse_s: expected a number >= 0'),
    ('body_half_depth_m', float('nan'), 'body_half_depth_m: expected a finite number, got nan'),
    ('cut_body_offset_m', float('inf'), 'cut_body_offset_m: expected a finite number'),
    ('head_offset_m', float('nan'), 'head_offset_m: expected a finite number'),
    ('min_head_height_m', float('nan'), 'min_head_height_m: expected a finite number'),
    ('edge_px', float('nan'), 'edge_px: expected a finite number'),
    ('warm_margin_counts', -1000.0, r'warm_margin_counts: expected a number >= 0, got -1000.0'),
    ('min_travel_m', -1.0, 'min_travel_m: expected a number >= 0'),
    ('reacquire_cut_s', float('inf'), 'reacquire_cut_s: expected a finite number'),
])
def test_a_bad_people_parameter_names_itself(field, value, message):
    with pytest.raises(ValueError, match=message):
        PeopleConfig(**{field: value})


def person_points(x, y, head=1.7, count=120, seed=0, radius=0.12):
    """Points on a standing person's front (the side facing a camera at the origin)."""
    rng = np.random.default_rng(seed)
    heights = rng.uniform(0.2, head + 0.08, count)
    angle = rng.uniform(-1.2, 1.2, count) + math.atan2(-y, -x)
    return np.column_stack([x + radius * np.cos(angle), y + radius * np.sin(angle), heights])


def floor_and_furniture(seed=1):
    rng = np.random.default_rng(seed)
    floor = np.column_stack([rng.uniform(-2, 2, 400), rng.uniform(1.5, 5, 400),
                             rng.normal(0, 0.02, 400)])
    desk = np.column_stack([rng.uniform(1.0, 1.8, 60), rng.uniform(4.0, 4.6, 60),
                            np.full(60, 0.74)])
    return np.vstack([floor, desk])


def test_two_people_among_floor_and_desk_points_are_two_detections_where_they_stand():
    points = np.vstack([person_points(-0.8, 2.8, seed=2), person_points(0.9, 3.6, 1.6, seed=3),
                        floor_and_furniture()])
    detections = detect_people(points, CAMERA)
    found = sorted((round(d.x, 1), round(d.y, 1)) for d in detections)
    assert len(detections) == 2, detections
    assert np.allclose(found, [(-0.8, 2.8), (0.9, 3.6)], atol=0.15)
    heads = sorted(d.head_height for d in detections)
    assert heads == pytest.approx([1.6, 1.7], abs=0.08)
    # Every point of a person above min_point_height_m (0.6 m), none of the floor's.
    assert all(d.head_visible and 75 <= d.points <= 120 for d in detections)


def test_no_points_or_only_floor_points_are_no_detection():
    assert detect_people(np.zeros((0, 3)), CAMERA) == []
    assert detect_people(floor_and_furniture(), CAMERA) == []


def test_depth_uncertainty_widens_the_covariance_along_the_view():
    points = person_points(0.0, 3.5, seed=4)
    z = np.full(len(points), 4.0)
    plain = detect_people(points, CAMERA)[0].covariance
    with_depth = detect_people(points, CAMERA, disparity=np.full(len(points), 11.0),
                               depth=z)[0].covariance
    # The view is along y here: y's variance grows, x's does not.
    assert with_depth[1, 1] > plain[1, 1]
    assert with_depth[0, 0] == pytest.approx(plain[0, 0], rel=1e-3)


def test_a_body_cut_by_the_top_edge_is_kept_and_marked():
    points = person_points(0.3, 4.3, head=1.7, seed=5)
    points = points[points[:, 2] < 0.95]          # the head and shoulders above the image
    pixels = np.column_stack([np.full(len(points), 40.0),
                              np.where(points[:, 2] > 0.8, 5.0, 30.0)])
    without_edge = detect_people(points, CAMERA)
    assert without_edge == []                     # too low for a whole person
    cut = detect_people(points, CAMERA, pixels=pixels, image_shape=(60, 80))
    assert len(cut) == 1 and cut[0].cut_top and not cut[0].head_visible


def _rig_geometry():
    rig = standard_sequences()['walk_across'].rig
    p1 = rig.rectification()[2]
    return rig, world_from_rectified(rig.rig_pose(), rig.rectification()[0]), \
        (p1[0, 0], p1[1, 1], p1[0, 2], p1[1, 2])


def _painted(rig, surfaces, shape=(60, 80)):
    """
    Warm mask and matched points of world surface samples, by the simulator's camera model.

    ``surfaces``: (n, 3) world points; each lands on its rectified left pixel (the rig's true
    rectified projection P1), which becomes warm and holds a match at its true depth.
    """
    p1 = rig.rectification()[2]
    camera = rig.to_rectified_left(surfaces)
    u = p1[0, 0] * camera[:, 0] / camera[:, 2] + p1[0, 2]
    v = p1[1, 1] * camera[:, 1] / camera[:, 2] + p1[1, 2]
    inside = (np.rint(u) >= 0) & (np.rint(u) < shape[1]) & (np.rint(v) >= 0) & \
        (np.rint(v) < shape[0])
    warm = np.zeros(shape, dtype=bool)
    warm[np.rint(v[inside]).astype(int), np.rint(u[inside]).astype(int)] = True
    return warm, camera[inside], np.column_stack([u, v])[inside]


def _legs(x, y, top=0.85):
    """World samples of two legs 0.18 m apart, from the floor up to ``top``."""
    heights = np.linspace(0.0, top, 60)
    return np.vstack([np.column_stack([np.full(60, x + dx), np.full(60, y), heights])
                      for dx in (-0.09, -0.05, 0.05, 0.09)])


def test_legs_are_seen_under_a_cut_body_not_under_a_screen_nor_behind_a_nearer_body():
    rig, transform, intrinsics = _rig_geometry()
    legs = _legs(-1.0, 4.3)
    screen = np.array([[x, 4.5, z] for x in np.linspace(1.05, 1.65, 30)
                       for z in np.linspace(0.78, 1.15, 20)])
    warm, points, pixels = _painted(rig, np.vstack([legs, screen]))
    assert legs_fraction(warm, (-1.0, 4.3), transform, intrinsics, points, pixels) >= 0.9
    # 0.15 m off (a cut body's position error) still finds the legs; 0.5 m aside does not.
    assert legs_fraction(warm, (-0.88, 4.4), transform, intrinsics, points, pixels) >= 0.5
    assert legs_fraction(warm, (-0.5, 4.3), transform, intrinsics, points, pixels) == 0.0
    # Under the screen: the cool desk.
    assert legs_fraction(warm, (1.35, 4.5), transform, intrinsics, points, pixels) == 0.0
    # The same warm legs, but their matches 1.5 m nearer: a body in front, not these legs;
    # or 1 m farther: something behind.
    for shift in (-1.5, 1.0):
        moved = points * (1.0 + shift / np.linalg.norm(points, axis=1))[:, None]
        assert legs_fraction(warm, (-1.0, 4.3), transform, intrinsics, moved, pixels) == 0.0
    # Warm pixels without a single match on them are no evidence.
    assert legs_fraction(warm, (-1.0, 4.3), transform, intrinsics, points[:0],
                         pixels[:0]) == 0.0
    # Under the image (behind the rig) there is nothing to see.
    assert math.isnan(legs_fraction(warm, (0.0, -1.0), transform, intrinsics, points,
                                    pixels))


def test_a_warm_computer_under_a_screen_is_not_legs_under_a_body():
    rig, transform, intrinsics = _rig_geometry()
    # A computer on the floor under a desk (top 0.70-0.74 m, cool) with a screen on it, both
    # warm and 4.5-4.8 m away; the same place once more with a person standing there.
    computer = np.array([[x, y, z] for x in np.linspace(1.3, 1.5, 8)
                         for y in (4.45,) for z in np.linspace(0.0, 0.45, 30)])
    screen = np.array([[x, 4.75, z] for x in np.linspace(1.1, 1.7, 30)
                       for z in np.linspace(0.78, 1.15, 20)])
    desk_warm, points, pixels = _painted(rig, np.vstack([computer, screen]))
    body = _legs(1.4, 4.55, top=1.1)
    body_warm, body_points, body_pixels = _painted(rig, body)
    assert legs_fraction(desk_warm, (1.4, 4.55), transform, intrinsics, points, pixels) >= 0.5
    assert warm_column_gap_m(desk_warm, (1.4, 4.55), transform, intrinsics, points,
                             pixels) > 0.25
    assert warm_column_gap_m(body_warm, (1.4, 4.55), transform, intrinsics, body_points,
                             body_pixels) <= 0.05
    cut = Detection(1.4, 4.55, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                    cut_top=True)
    counts = {}
    assert not standing_on_legs([cut], desk_warm, transform, intrinsics, points, pixels,
                                counts=counts)[0].legs_seen
    assert counts['cut_legs_gap'] == 1
    assert standing_on_legs([cut], body_warm, transform, intrinsics, body_points,
                            body_pixels)[0].legs_seen


def test_a_cool_cart_in_front_of_the_body_is_not_a_gap_in_it():
    # A cart's handle 0.75-1.05 m high, 0.6 m in front: its image covers the body's column
    # from about 0.5 m up; the legs below still show.
    rig, transform, intrinsics = _rig_geometry()
    body = _legs(0.3, 4.5, top=1.1)
    box = np.array([[x, 4.5 - 0.6, z] for x in np.linspace(0.1, 0.5, 20)
                    for z in np.linspace(0.75, 1.05, 20)])
    body_warm, body_points, body_pixels = _painted(rig, body)
    box_cells, box_points, box_pixels = _painted(rig, box)
    warm = body_warm & ~box_cells                   # the cart hides the body, cool itself
    hidden = box_cells[np.rint(body_pixels[:, 1]).astype(int),
                       np.rint(body_pixels[:, 0]).astype(int)]
    points = np.vstack([body_points[~hidden], box_points])
    pixels = np.vstack([body_pixels[~hidden], box_pixels])
    assert legs_fraction(warm, (0.3, 4.5), transform, intrinsics, points, pixels) >= 0.5
    assert warm_column_gap_m(warm, (0.3, 4.5), transform, intrinsics, points, pixels) <= 0.05
    # Without the cart's matches the cool rows are a gap (as under a desk's knee space).
    assert warm_column_gap_m(warm, (0.3, 4.5), transform, intrinsics, body_points[~hidden],
                             body_pixels[~hidden]) > 0.25


def test_a_segment_off_the_image_side_gives_no_rows_and_no_crash():
    rig, transform, intrinsics = _rig_geometry()
    p1 = rig.rectification()[2]
    for x in np.linspace(-3.5, -2.0, 61):
        heights = np.linspace(0.1, 0.8, 29)
        rows = vertical_segment_rows((x, 4.3), heights, transform, intrinsics, (60, 80), 0.15)
        # The simulator's own projection of the segment: no row may come from a window
        # wholly left of column 0 (its right edge, u + half, below -0.5 rounds off the image).
        camera = rig.to_rectified_left(np.column_stack([np.full(29, x), np.full(29, 4.3),
                                                        heights]))
        u = p1[0, 0] * camera[:, 0] / camera[:, 2] + p1[0, 2]
        v = np.rint(p1[1, 1] * camera[:, 1] / camera[:, 2] + p1[1, 2]).astype(int)
        half = 0.15 * p1[0, 0] / camera[:, 2]
        for _, row, low, high, _ in rows:
            assert 0 <= low <= high <= 79
            assert (u[v == row] + half[v == row]).max() >= low, (x, row)
    warm = np.ones((60, 80), dtype=bool)
    assert legs_fraction(warm, (-2.0, 4.3), transform, intrinsics, np.zeros((0, 3)),
                         np.zeros(0)) == 0.0


def test_cut_bodies_not_checked_for_legs_are_counted():
    rig, transform, intrinsics = _rig_geometry()
    world = _legs(-1.0, 4.6, top=1.75)
    camera = rig.to_rectified_left(world)
    p1 = rig.rectification()[2]
    u = p1[0, 0] * camera[:, 0] / camera[:, 2] + p1[0, 2]
    v = p1[1, 1] * camera[:, 1] / camera[:, 2] + p1[1, 2]
    seen = (u >= 0) & (u <= 79) & (v >= 0) & (v <= 59)
    image = np.full((60, 80), 8000.0)
    image[np.rint(v[seen]).astype(int), np.rint(u[seen]).astype(int)] += 400
    for intrinsics_given, key in ((None, 'cut_legs_not_checked'), (intrinsics, 'cut_legs_seen')):
        estimator = PeopleEstimator(transform)
        for t in (0.0, 0.115):
            estimator.process(t, camera[seen], u[seen], v[seen], left_image=image,
                              intrinsics=intrinsics_given)
        assert estimator.counts[key] >= 2, (key, estimator.counts)
        assert bool(estimator.tracker.tracks and estimator.tracker.tracks[0].confirmed) == \
            (intrinsics_given is not None)


def test_a_cut_body_on_its_legs_is_published_at_once_and_a_screen_never():
    tracker = PeopleTracker()
    person = [Detection(-1.0, 4.3 - 0.1 * i, 0.95, 20, 1.0, np.eye(2) * 1e-3,
                        head_visible=False, cut_top=True, legs_seen=True) for i in range(3)]
    screen = Detection(1.3, 4.5, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True)
    published = [tracker.update([p, screen], t) for t, p in zip((0.0, 0.115, 0.23), person)]
    assert [len(tracks) for tracks in published] == [0, 1, 1]
    assert all(t.state[0] == pytest.approx(-1.0, abs=0.05) for t in published[-1])
    # Passers-by lending the screen legs for one pair, now and then, do not make it a person.
    lent = dataclasses.replace(screen, legs_seen=True)
    for index, t in enumerate(np.arange(0.345, 6.0, 0.115)):
        tracks = tracker.update([lent if index % 3 == 0 else screen], t)
        assert all(track.state[0] < 0 for track in tracks), t
    assert tracker.counts['started'] == 1


PAIR_S = 0.115


@pytest.mark.parametrize('places, times, expected', [
    # A walker advancing 0.1 m per detection, with a few centimetres of jitter across.
    ([(1.0, 4.5), (0.98, 4.4), (1.01, 4.3), (0.99, 4.2), (1.0, 4.1)], None, True),
    # Uneven steps, 0.08 to 0.13 m; one short by the detections' jitter (0.04 m of 0.11).
    ([(1.0, 4.5), (1.0, 4.42), (1.0, 4.3), (1.0, 4.21), (1.0, 4.08)], None, True),
    ([(1.0, 4.5), (1.0, 4.46), (1.0, 4.32), (1.0, 4.2), (1.0, 4.06)], None, True),
    # A pause (a centimetre back) before walking fast: not steady (yet).
    ([(1.0, 4.5), (1.0, 4.51), (1.0, 4.4), (1.0, 4.25), (1.0, 4.05)], None, False),
    # A screen's two pieces 0.4 m apart: one jump is not a walk, nor is going back and forth.
    ([(1.2, 4.6), (1.2, 4.6), (1.21, 4.6), (1.6, 4.6), (1.6, 4.6)], None, False),
    ([(1.2, 4.6), (1.2, 4.6), (1.2, 4.6), (1.2, 4.6), (1.6, 4.6)], None, False),
    ([(1.2, 4.6), (1.6, 4.6), (1.2, 4.6), (1.6, 4.6), (1.2, 4.6)], None, False),
    # A screen in place, then its other piece after coasting unseen (the step at its pace),
    # within 1 s and beyond it.
    ([(1.62, 4.57)] * 2 + [(1.17, 4.62)] * 3, [0.0, 0.115, 0.69, 0.805, 0.92], False),
    ([(1.62, 4.57)] * 4 + [(1.17, 4.62)], [0.0, 0.115, 0.23, 0.345, 1.4], False),
    # Jitter in place; too short a walk; a step back; a detour.
    ([(1.2, 4.6), (1.23, 4.58), (1.19, 4.62), (1.22, 4.6), (1.2, 4.59)], None, False),
    ([(1.0, 4.5), (1.0, 4.45), (1.0, 4.4), (1.0, 4.35), (1.0, 4.3)], None, False),
    ([(1.0, 4.5), (1.0, 4.35), (1.0, 4.45), (1.0, 4.2), (1.0, 4.0)], None, False),
    ([(1.0, 4.5), (1.3, 4.4), (1.5, 4.3), (1.3, 4.2), (1.0, 4.05)], None, False),
    # Fewer than five detections.
    ([(1.0, 4.5), (1.0, 4.3), (1.0, 4.1), (1.0, 3.9)], None, False),
    # Consecutive pairs of a slower rig (3.3 pairs/s): a walk; a pair missed in the middle: not
    # consecutive (a coasting track may take a detection far off).
    ([(1.0, 4.5), (0.98, 4.3), (1.01, 4.1), (0.99, 3.9), (1.0, 3.7)], [0, 0.3, 0.6, 0.9, 1.2],
     True),
    ([(1.0, 4.5), (0.98, 4.4), (1.01, 4.2), (0.99, 4.1), (1.0, 4.0)],
     [0.0, 0.115, 0.345, 0.46, 0.575], False),
    # One long step at the end (most of the line); a zigzag (the path twice the line).
    ([(0.0, 4.0), (0.06, 4.0), (0.12, 4.0), (0.18, 4.0), (0.62, 4.0)], None, False),
    ([(0.0, 4.0), (0.12, 4.1), (0.24, 3.9), (0.36, 4.1), (0.48, 3.9)], None, False),
])
def test_a_steady_walk_advances_at_every_step_without_a_jump(places, times, expected):
    times = PAIR_S * np.arange(len(places)) if times is None else times
    assert walks_steadily(places, times, 0.4) is expected
    assert walks_steadily(places, times, 0.0) is False                # off


@pytest.mark.parametrize('steady_walk_m, first', [(0.4, 4), (0.0, 10)])
def test_a_cut_body_without_legs_walking_steadily_is_published_before_min_travel(
        steady_walk_m, first):
    # A far walker cut by the top edge whose legs are never seen, 0.1 m nearer per pair,
    # beside a warm screen whose detections jump between its two pieces 0.4 m apart: the
    # walker is published at its fifth detection (0.4 m walked), not after min_travel_m
    # (1.0 m, the eleventh); the screen never.
    tracker = PeopleTracker(PeopleConfig(steady_walk_m=steady_walk_m))
    published = []
    for index, t in enumerate(np.arange(0.0, 2.0, 0.115)):
        walker = Detection(-1.0, 4.6 - 0.1 * index, 0.95, 20, 1.0, np.eye(2) * 1e-3,
                           head_visible=False, cut_top=True)
        piece = 1.2 if index % 6 < 3 else 1.6
        screen = Detection(piece, 4.6, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                           cut_top=True)
        published.append([track.state[0] for track in tracker.update([walker, screen], t)])
    assert all(x < 0 for xs in published for x in xs)
    assert [bool(xs) for xs in published].index(True) == first
    assert tracker.counts['started'] == 1


def _cut(x, y):
    return Detection(float(x), float(y), 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                     cut_top=True)


@pytest.mark.parametrize('seed', range(20))
def test_a_jittering_screen_back_as_its_other_piece_after_a_passer_by_is_not_a_walk(seed):
    # A review's scene: a screen cut by the top edge, its detections jittering (sigma 5 cm),
    # hidden by a passer-by (seen whole) for two pairs, comes back as its other piece 0.45 m
    # away: its track coasted and jumped (the walk would not be consecutive), and it had been
    # a warm object for 12 pairs. Before both guards, 26 of 500 such events published it.
    rng = np.random.default_rng(seed)
    tracker = PeopleTracker(PeopleConfig())
    pieces = [(1.2, 4.6)] * 12 + [None] * 2 + [(1.65, 4.6)] * 12
    for index, piece in enumerate(pieces):
        t = PAIR_S * index
        detections = [] if piece is None else [_cut(*(np.array(piece) + rng.normal(0, 0.05, 2)))]
        passer_x = 2.6 - 1.2 * (t - 8 * PAIR_S)
        if -0.5 < passer_x < 3.0:
            detections.append(Detection(passer_x, 3.6, 1.7, 100, 1.0, np.eye(2) * 1e-3))
        published = tracker.update(detections, t)
        assert all(track.state[1] < 4.0 for track in published), (index, published)


def test_a_screen_whose_detection_a_passer_by_slides_across_is_not_a_walk():
    # A review's scene: a passer-by (seen whole, nearer) slides in front of a screen of two
    # pieces that make one detection, the median of the points left visible, which moves
    # pair after pair across the gap between the pieces (1.57 -> 1.13 m) and back: a steady
    # walk of 0.44 m, but by a track that had been a warm object for 12 pairs.
    tracker = PeopleTracker(PeopleConfig())
    screen_x = [1.4] * 12 + [1.57, 1.49, 1.37, 1.25, 1.13, 1.17, 1.25, 1.32] + [1.4] * 12
    for index, x in enumerate(screen_x):
        t = PAIR_S * index
        detections = [_cut(x, 4.6), Detection(0.2 + 1.2 * t, 3.4, 1.7, 100, 1.0,
                                              np.eye(2) * 1e-3)]
        published = tracker.update(detections, t)
        assert all(track.state[1] < 4.0 for track in published), (index, published)


def test_a_screen_jumping_between_its_pieces_like_a_walk_is_not_published():
    # A review's random scene, one draw: a screen of two pieces (1.2 and 1.65 m), its
    # detections jittering by 5 cm, once 0.63 m from where its track started (so the track is
    # no longer a warm object to is_warm_object), then jumping from one piece to the other in
    # steps that look like a walk (1.16, 1.24, 1.35, 1.5, 1.64: 0.48 m in 5 pairs).
    tracker = PeopleTracker(PeopleConfig())
    xs = [1.65, 1.62, 1.68, 2.28, 1.66, 1.63, 1.7, 1.65, 1.65, 1.55, 1.63, 1.66, 1.16, 1.21,
          1.16, 1.24, 1.35, 1.5, 1.64, 1.66, 1.62]
    for index, x in enumerate(xs):
        published = tracker.update([_cut(x, 4.6)], PAIR_S * index)
        assert not published, index
    assert tracker.tracks[0].farthest_m > PeopleConfig().object_radius_m
    assert not tracker.is_warm_object(tracker.tracks[0])


def test_a_steady_walk_is_judged_on_the_detections_own_stamps():
    # A far walker without legs, 0.11 m per pair, not detected in pair 3: its first five
    # detections are not of consecutive pairs (a coasting track may take a detection far off),
    # so it is published at its eighth pair, once five consecutive ones walk; on stamps one
    # period apart it would have been at its fifth detection.
    tracker = PeopleTracker(PeopleConfig())
    first = None
    for index in range(10):
        detections = [] if index == 3 else [_cut(-1.0, 4.6 - 0.11 * index)]
        if tracker.update(detections, PAIR_S * index) and first is None:
            first = index
    assert first == 8


def test_a_far_person_pacing_without_legs_keeps_one_id():
    # A review's scene: a far presenter cut by the top edge, legs behind desks, pacing 0.9 m
    # back and forth at 1.2 m/s with 1 s pauses for 46 s: each steady stretch renews it (the
    # legs' lapse would withdraw it 5 s after its publication, and the next stretch publish it
    # again under a new id: 8-9 ids). Off, it is never published (never 1 m from its start).
    def run(steady_walk_m):
        rng, tracker, ids = np.random.default_rng(2), PeopleTracker(
            PeopleConfig(steady_walk_m=steady_walk_m)), set()
        leg, pause = 0.9 / 1.2, 1.0
        for index in range(400):
            t = PAIR_S * index
            phase = t % (2 * (leg + pause))
            x = 1.2 * phase if phase < leg else 0.9 if phase < leg + pause else \
                0.9 - 1.2 * (phase - leg - pause) if phase < 2 * leg + pause else 0.0
            published = tracker.update([_cut(-1.5 + x + rng.normal(0, 0.02),
                                             5.0 + rng.normal(0, 0.02))], t)
            ids.update(track.track_id for track in published)
        return tracker, ids
    tracker, ids = run(0.4)
    assert ids == {1} and tracker.counts['legs_lapsed'] == 0
    tracker, ids = run(0.0)
    assert ids == set()


def _screen_lent_legs(config, lent_pairs=(10, 11), end_s=12.0, far_person_legs=True,
                      screen_hidden=()):
    """
    Run a screen cut by the top edge, lent legs in ``lent_pairs``, beside a far person.

    The screen is not detected in ``screen_hidden`` (pair indices). Returns the tracker and,
    per pair, the stamp, the published tracks' (id, x) and the ids that ended.
    """
    tracker = PeopleTracker(config)
    screen = Detection(1.3, 4.5, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True)
    person = Detection(-1.0, 5.2, 0.9, 14, 1.0, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True, legs_seen=far_person_legs)
    published = []
    for index, t in enumerate(np.arange(0.0, end_s, 0.115)):
        lent = dataclasses.replace(screen, legs_seen=index in lent_pairs)
        tracks = tracker.update(([] if index in screen_hidden else [lent]) + [person], t)
        published.append((t, [(track.track_id, track.state[0]) for track in tracks],
                          list(tracker.ended)))
    return tracker, published


def _first_published(published, on_screen=True):
    """Return {track id: index of the first pair it was published in} for one side."""
    first = {}
    for index, (_, tracks, _) in enumerate(published):
        for track_id, x in tracks:
            if (x > 0) == on_screen:
                first.setdefault(track_id, index)
    return first


def test_a_screen_lent_legs_in_two_pairs_is_withdrawn_once_its_legs_lapse():
    # A passer-by's legs in front of a warm screen cut by the top edge, in two of three
    # pairs, make it a person (min_hits of min_hits + 1 on legs); nothing else ever
    # withdrew it, and its pixels, a published person's, were kept from the background.
    config = PeopleConfig()
    tracker, published = _screen_lent_legs(config)
    first = _first_published(published)
    assert list(first.values()) == [11], 'the lent legs no longer publish the screen'
    screen_id = next(iter(first))
    # Withdrawn at the first pair more than legs_lapse_s after the last whose three last
    # detections held two on legs (pair 12); its id ends there, once (the node deletes its
    # markers).
    times = [t for t, _, _ in published]
    withdrawn = next(i for i, t in enumerate(times) if t - times[12] > config.legs_lapse_s)
    assert [i for i, (_, _, ended) in enumerate(published) if screen_id in ended] == \
        [withdrawn]
    assert all(any(x > 0 for _, x in tracks) for _, tracks, _ in published[11:withdrawn])
    assert not any(x > 0 for _, tracks, _ in published[withdrawn:] for _, x in tracks)
    assert tracker.counts['legs_lapsed'] == 1
    # The far person standing on its legs all along keeps one id to the end.
    assert _first_published(published, on_screen=False) == {1: 1} and screen_id != 1
    assert all(any(x < 0 for _, x in tracks) for _, tracks, _ in published[1:])
    # The screen's track goes on, unpublished: a warm object again.
    screen_track = [track for track in tracker.tracks if track.state[0] > 0]
    assert len(screen_track) == 1 and tracker.is_warm_object(screen_track[0])
    # Without the lapse (0: never) the screen is published to the end.
    _, kept = _screen_lent_legs(PeopleConfig(legs_lapse_s=0.0))
    assert all(any(x > 0 for _, x in tracks) for _, tracks, _ in kept[11:])


def test_a_screen_not_detected_at_its_lapse_is_withdrawn_at_its_next_detection():
    config = PeopleConfig()
    times = np.arange(0.0, 12.0, 0.115)
    due = next(i for i, t in enumerate(times) if t - times[12] > config.legs_lapse_s)
    # Not detected for two pairs from its due one (coasting: no evidence either way).
    tracker, published = _screen_lent_legs(config, screen_hidden=(due, due + 1))
    ended = [i for i, (_, _, ids) in enumerate(published) if ids]
    assert ended == [due + 2] and tracker.counts['legs_lapsed'] == 1


def test_single_lends_now_and_then_do_not_keep_a_withdrawn_screen_published():
    # Lent legs in two of three pairs publish it; a single lend every 4 s afterwards (a
    # passer-by's one stride in front of it) neither renews it nor publishes it again.
    config = PeopleConfig()
    lends = (10, 11) + tuple(range(45, 1000, 35))
    tracker, published = _screen_lent_legs(config, lent_pairs=lends, end_s=60.0)
    on_screen = [index for index, (_, tracks, _) in enumerate(published)
                 if any(x > 0 for _, x in tracks)]
    assert on_screen and max(on_screen) < 12 + config.legs_lapse_s / 0.115 + 1
    assert tracker.counts['legs_lapsed'] == 1 and len(_first_published(published)) == 1


def test_a_withdrawn_screen_lent_legs_again_is_published_again_under_a_new_id():
    config = PeopleConfig(legs_lapse_s=2.0)
    # Lent again at pair 60 alone (not published), then at 70 and 72 (two of three: 72).
    tracker, published = _screen_lent_legs(config, lent_pairs=(10, 11, 60, 70, 72),
                                           end_s=9.0)
    first = _first_published(published)
    assert sorted(first.values()) == [11, 72]
    assert tracker.counts['legs_lapsed'] >= 1


def test_a_far_person_whose_legs_stay_hidden_loses_the_id_and_gets_a_new_one():
    # The documented cost: a far person, head above the image, never seen whole, standing
    # on legs for ten pairs, then with the legs hidden (a chair pushed in front), is a warm
    # object to the tracker once legs showed in under 30 % of its detections and none for
    # legs_lapse_s; back on legs (two of three), it is published again, under a new id.
    config = PeopleConfig()
    tracker = PeopleTracker(config)
    published, times = [], np.arange(0.0, 10.0, 0.115)
    for index, t in enumerate(times):
        legs = index < 10 or index >= 70
        person = Detection(-1.0, 5.2, 0.9, 14, 1.0, np.eye(2) * 1e-3, head_visible=False,
                           cut_top=True, legs_seen=legs)
        published.append([track.track_id for track in tracker.update([person], t)])
    # Pair 10's three last detections still hold two on legs.
    lapse = int(np.argmax(times - times[10] > config.legs_lapse_s))
    assert all(ids == [1] for ids in published[1:lapse])
    assert all(ids == [] for ids in published[lapse:71])
    assert all(ids == [2] for ids in published[71:])
    assert tracker.counts['legs_lapsed'] == 1


def test_a_far_person_on_legs_in_a_third_of_the_pairs_keeps_the_id():
    # Legs in 30 pairs, then hidden for 50 (37.5 %): a person standing on them, not lent.
    tracker = PeopleTracker(PeopleConfig())
    for index, t in enumerate(np.arange(0.0, 80 * 0.115, 0.115)):
        person = Detection(-1.0, 5.2, 0.9, 14, 1.0, np.eye(2) * 1e-3, head_visible=False,
                           cut_top=True, legs_seen=index < 30)
        ids = [track.track_id for track in tracker.update([person], t)]
    assert ids == [1] and tracker.counts['legs_lapsed'] == 0


def test_a_track_published_by_one_whole_detection_gets_the_lapse_from_its_publication():
    # Seen whole once (its head in the image), then cut by the top edge, legs never seen,
    # never walking: thin evidence, but the lapse runs from its publication, not from never.
    config = PeopleConfig()
    tracker = PeopleTracker(config)
    times = np.arange(0.0, 8.0, 0.115)
    published = []
    for index, t in enumerate(times):
        detection = Detection(0.5, 3.9, 1.6 if index == 0 else 1.05, 30, 1.0,
                              np.eye(2) * 1e-3, head_visible=index == 0, cut_top=index > 0)
        published.append([track.track_id for track in tracker.update([detection], t)])
    lapse = int(np.argmax(times - times[1] > config.legs_lapse_s))
    assert all(ids == [1] for ids in published[1:lapse])
    assert all(ids == [] for ids in published[lapse:])
    assert tracker.counts['legs_lapsed'] == 1


@pytest.mark.parametrize('whole_pairs', [1, 2, 9])
def test_a_person_standing_up_in_front_of_a_screen_keeps_it_only_for_the_lapse(whole_pairs):
    # A person standing up in front of a published screen for a moment (the screen's track,
    # published first, takes the whole detections) then sitting down again: the screen is a
    # person while seen whole and for legs_lapse_s after, not for good.
    config = PeopleConfig()
    tracker = PeopleTracker(config)
    screen = Detection(1.3, 4.5, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True)
    standing = Detection(1.3, 4.3, 1.6, 40, 1.0, np.eye(2) * 1e-3)
    times = np.arange(0.0, 14.0, 0.115)
    ended = []
    for index, t in enumerate(times):
        detection = dataclasses.replace(screen, legs_seen=index in (10, 11))
        if 20 <= index < 20 + whole_pairs:
            detection = standing
        tracker.update([detection], t)
        if tracker.ended:
            ended.append(index)
    last_whole = 20 + whole_pairs - 1
    assert ended == [int(np.argmax(times - times[last_whole] > config.legs_lapse_s))]
    assert tracker.counts['legs_lapsed'] == 1


@pytest.mark.parametrize('far_pairs, lapsed', [(1, 1), (3, 0)])
def test_a_screen_that_took_one_far_detection_has_not_walked(far_pairs, lapsed):
    # A published screen, hidden for 1 s (its gate grows while it coasts), takes a
    # passer-by's whole detections, ``far_pairs`` of them 1.1 m away, follows the passer back
    # to it and takes the screen's detections again: one detection that far is not walking
    # min_travel_m (it would exempt the screen from the lapse for good); min_hits or more
    # that far are.
    tracker = PeopleTracker(PeopleConfig())
    screen = Detection(1.3, 4.5, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True)
    back_from = 29 + far_pairs
    for index, t in enumerate(np.arange(0.0, 14.0, 0.115)):
        detections = [dataclasses.replace(screen, legs_seen=index in (10, 11))]
        if 20 <= index < 29:
            detections = []
        elif 29 <= index < back_from + 4:
            away = 1.0 if index < back_from else 1.0 - 0.2 * (index - back_from + 1)
            detections = [Detection(1.3 - 0.4 * away, 4.5 - 1.03 * away, 1.6, 40, 1.0,
                                    np.eye(2) * 1e-3)]
        tracker.update(detections, t)
    # One track took every detection (none started another, none coasted to its end).
    assert tracker.counts['unassigned_detections'] == 1 and tracker.counts['ended'] == 0
    assert tracker.counts['legs_lapsed'] == lapsed


@pytest.mark.parametrize('far_person_legs', [True, False])
def test_the_legs_lapse_spares_people_seen_whole_or_walking(far_person_legs):
    # A person seen whole, or one that walked min_travel_m, is a person by that, not by
    # legs: their legs hidden for long (behind a desk) do not withdraw them.
    # Seen whole in 12 of its 35 detections, then behind a desk (head above the image, legs
    # hidden) for 23 pairs, 2.6 s (legs_lapse_s 1 s): a person by its share of whole ones.
    config = PeopleConfig(legs_lapse_s=1.0)
    tracker = PeopleTracker(config)
    whole = Detection(-1.0, 3.0, 1.6, 40, 1.0, np.eye(2) * 1e-3)
    behind_desk = Detection(-1.0, 3.0, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                            cut_top=True, legs_seen=False)
    times = np.arange(0.0, 4.0, 0.115)
    for t in times[:12]:
        tracker.update([whole], t)
    for t in times[12:]:
        assert [track.track_id for track in tracker.update([behind_desk], t)] == [1]
    walker = PeopleTracker(config)
    for index, t in enumerate(times):
        x = min(-2.0 + t, 0.0)      # walks 2 m, then stands, legs seen at first only
        detection = Detection(x, 4.8, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                              cut_top=True, legs_seen=far_person_legs and index < 3)
        published = walker.update([detection], t)
    assert [track.track_id for track in published] == [1]
    assert tracker.counts['legs_lapsed'] == walker.counts['legs_lapsed'] == 0


def test_a_body_with_its_head_on_warm_legs_is_published_at_its_first_detection():
    rig, transform, intrinsics = _rig_geometry()
    # A person 2.8 m off, head in the image; a warm screen on a desk (cool knee space below).
    body_warm, body_points, body_pixels = _painted(rig, _legs(-0.6, 2.8, top=1.6))
    screen = np.array([[x, 3.0, z] for x in np.linspace(0.7, 1.3, 30)
                       for z in np.linspace(0.78, 1.15, 20)])
    screen_warm, screen_points, screen_pixels = _painted(rig, screen)
    warm = body_warm | screen_warm
    points, pixels = np.vstack([body_points, screen_points]), np.vstack([body_pixels,
                                                                         screen_pixels])

    def whole(x, y, head):
        return Detection(x, y, head, 60, 1.0, np.eye(2) * 1e-3)
    counts = {}
    marked = standing_on_legs([whole(-0.6, 2.8, 1.55), whole(1.0, 3.0, 1.1),
                               whole(-0.6, 2.8, 0.8)], warm, transform, intrinsics, points,
                              pixels, counts=counts)
    # The body stands on its legs; the screen has none; a head too low is not checked.
    assert [d.legs_under_head for d in marked] == [True, False, False]
    assert counts['head_legs_checked'] == 2 and counts['head_legs_seen'] == 1
    assert not any(d.legs_seen for d in marked)     # the cut bodies' flag is not touched
    off = PeopleConfig(confirm_on_legs=False)
    assert not standing_on_legs([whole(-0.6, 2.8, 1.55)], warm, transform, intrinsics,
                                points, pixels, off)[0].legs_under_head
    # Published at the first detection on legs; without legs (or the option off) at min_hits.
    for config, detection, first in ((None, marked[0], 1), (None, whole(-0.6, 2.8, 1.55), 0),
                                     (off, marked[0], 0)):
        tracker = PeopleTracker(config)
        published = [len(tracker.update([detection], t)) for t in (0.0, 0.115)]
        assert published == [first, 1], (config, detection)
    # Not beside a published track (a body's fragment thrown back by wrong disparities
    # stands on the body's own legs): it waits for min_hits too.
    tracker = PeopleTracker()
    for t in (0.0, 0.115):
        tracker.update([whole(-0.6, 2.8, 1.55)], t)
    fragment = dataclasses.replace(marked[0], x=-0.6, y=3.4)
    assert len(tracker.update([whole(-0.6, 2.8, 1.55), fragment], 0.23)) == 1
    # Time going back (a replay restarting): no track is predicted, the tracker starts over
    # and a body on its legs is published at once again.
    assert tracker.predicted_xy(0.5) and tracker.predicted_xy(0.0) == []
    assert len(tracker.update([marked[0]], 0.0)) == 1
    # Only a track's first detection: one that starts without legs waits for min_hits.
    tracker = PeopleTracker(PeopleConfig(min_hits=3))
    published = [len(tracker.update([d], t)) for d, t in
                 ((whole(-0.6, 2.8, 1.55), 0.0), (marked[0], 0.115), (marked[0], 0.23))]
    assert published == [0, 0, 1]


def test_the_legs_only_pass_can_be_turned_off_and_min_point_height_then_goes_low():
    assert PeopleConfig(min_point_height_m=0.0, far_legs_min_height_m=0.0)
    assert PeopleConfig(confirm_on_legs=np.False_).confirm_on_legs == np.False_
    with pytest.raises(ValueError, match='far_legs_min_height_m: expected 0 .off. or a value'):
        PeopleConfig(min_point_height_m=0.1)


def _box(x0, x1, y, z0, z1, nx=30, nz=25):
    """World samples of a vertical warm rectangle facing the rig."""
    return np.array([[x, y, z] for x in np.linspace(x0, x1, nx)
                     for z in np.linspace(z0, z1, nz)])


def _far_scene(surfaces, pairs=4, config=None):
    """
    Run painted surfaces through a PeopleEstimator; return it and the per-pair outputs.

    The warm image is the painted mask (400 counts over a flat room); the points are the
    painted samples at their true depth (``_painted``), except those in the top four rows,
    where no feature is found (half a POC window).
    """
    rig, transform, intrinsics = _rig_geometry()
    warm, points, pixels = _painted(rig, surfaces)
    found = pixels[:, 1] >= 4.5
    image = np.full((60, 80), 8000.0)
    image[warm] += 400.0
    estimator = PeopleEstimator(transform, config)
    # A pair every 0.115 s, then every second (a long run: the background's minutes).
    frames = [estimator.process(0.115 * k if k < 10 else k - 8.85, points[found],
                                pixels[found, 0], pixels[found, 1],
                                0.1 * 84.0 / points[found, 2], left_image=image,
                                intrinsics=intrinsics) for k in range(pairs)]
    return estimator, frames


def test_a_body_so_far_off_that_only_its_legs_show_is_found_and_a_radiator_is_not():
    rig, transform, intrinsics = _rig_geometry()
    # 5.6 m off the image's top edge is about 0.8 m above the floor: the body rises out of the
    # image and its matches end below min_point_height_m (0.6 m).
    body = _legs(0.4, 5.6, top=1.2)
    estimator, frames = _far_scene(body)
    assert estimator.counts['legs_only_detections'] == 4
    published = frames[-1].tracks
    assert len(published) == 1 and published[0].detection.legs_only
    assert math.hypot(published[0].state[0] - 0.4, published[0].state[1] - 5.6) < 0.25
    # Its height: where the top edge crosses it (the body goes on above), not its legs' top.
    edge = top_edge_height_m((0.4, 5.6), transform, intrinsics)
    assert 0.7 < edge < 0.9 and published[0].head_height == pytest.approx(edge, abs=0.05)
    assert not published[0].head_visible
    # Its pixels stay learnable by the background (a panel radiator looks the same, below).
    assert not estimator.protect.any()
    # Off: nothing.
    assert not _far_scene(body, config=PeopleConfig(far_legs_min_height_m=0.0))[1][-1].tracks
    # Low warm things far off, never a person: a dog or a fan heater wholly in view (cool rows
    # above them), a 1.3 m radiator rising out of the image, one running off its side.
    for name, surfaces, count in (
            ('dog', _box(0.25, 0.55, 6.0, 0.05, 0.5, 12), 'legs_only_below_top'),
            ('heater', _box(-0.9, -0.6, 5.8, 0.05, 0.45, 12), 'legs_only_below_top'),
            ('radiator', _box(-1.6, -0.3, 6.0, 0.15, 0.9, 60), 'cut_legs_wide'),
            ('radiator at the side', _box(2.2, 3.7, 6.0, 0.15, 0.9, 60), 'cut_legs_wide')):
        estimator, frames = _far_scene(surfaces)
        assert not any(frame.tracks for frame in frames), name
        assert estimator.counts[count] >= 1, (name, estimator.counts)
    # What it cannot tell: a 0.5 m panel radiator rising out of the image stands like legs.
    # Its pixels are not kept from the background (as a seated person's are), so it fades
    # into it within minutes (absorb_time_s 300 s, the 400 counts below 100 after 416 s).
    estimator, frames = _far_scene(_box(-1.0, -0.5, 6.0, 0.15, 0.9, 20), pairs=600)
    assert frames[3].tracks and not frames[-1].tracks
    # Beyond where the top edge crosses 0.5 m, the legs are not all in view: not checked.
    far = _legs(0.0, 6.8, top=1.2)
    far_warm, _, far_pixels = _painted(rig, far)
    assert top_edge_height_m((0.0, 6.8), transform, intrinsics) < 0.5
    counts = {}
    assert not legs_only_bodies([Detection(0.0, 6.8, 0.4, 20, 1.0, np.eye(2) * 1e-3, False,
                                           True, members=np.arange(len(far_pixels)),
                                           legs_only=True)],
                                far_warm, transform, intrinsics, far_pixels, counts)
    assert counts == {'legs_only_detections': 1, 'legs_only_below_top': 0,
                      'legs_only_too_far': 1}
    # Without the camera matrix nothing tells legs from a low warm thing: none, counted.
    warm, points, pixels = _painted(rig, body)
    image = np.full((60, 80), 8000.0)
    image[warm] += 400.0
    found = pixels[:, 1] >= 4.5
    estimator = PeopleEstimator(transform)
    frame = estimator.process(0.0, points[found], pixels[found, 0], pixels[found, 1],
                              left_image=image)
    assert estimator.counts['legs_only_not_checked'] == 1 and not frame.detections
    # The legs are narrow, a radiator as wide as it is, one off the image's side unknown.
    legs_warm = _painted(rig, _legs(0.4, 5.6, top=0.58))[0]
    assert 0.0 < warm_run_width_m(legs_warm, (0.4, 5.6), transform, intrinsics) < 0.5
    hot_warm = _painted(rig, _box(-1.6, -0.3, 6.38, 0.15, 0.75, 60))[0]
    assert warm_run_width_m(hot_warm, (-1.0, 6.38), transform, intrinsics) > 1.0
    side_warm = _painted(rig, _box(2.4, 3.7, 6.38, 0.15, 0.75, 60))[0]
    assert math.isnan(warm_run_width_m(side_warm, (2.6, 6.38), transform, intrinsics))
    assert math.isnan(warm_run_width_m(np.zeros((60, 80), dtype=bool), (0.4, 5.6),
                                       transform, intrinsics))


def _painted_run(scene, pairs, config=None):
    """Run ``scene(k)`` (world surface samples of pair k) through a PeopleEstimator."""
    rig, transform, intrinsics = _rig_geometry()
    estimator, frames = PeopleEstimator(transform, config), []
    for k in range(pairs):
        warm, points, pixels = _painted(rig, scene(k))
        found = pixels[:, 1] >= 4.5
        image = np.full((60, 80), 8000.0)
        image[warm] += 400.0
        frames.append(estimator.process(0.115 * k, points[found], pixels[found, 0],
                                        pixels[found, 1], 0.1 * 84.0 / points[found, 2],
                                        left_image=image, intrinsics=intrinsics))
    return estimator, frames


def test_low_warm_points_rising_out_of_view_start_a_track_only_on_legs():
    # A warm thing 5.6 m off rising out of the image's top edge, from ``bottom`` up to 0.9 m,
    # whose image slides across the view by 0.12 m a pair (a radiator's top seen past a
    # walker who hides more or less of it): 1.3 m in 12 pairs.
    def sliding(bottom):
        return lambda k: _box(-0.2 + 0.12 * k, 0.1 + 0.12 * k, 5.6, bottom, 0.9, 12)
    # Cool below 0.45 m: no legs. Its legs-only detections used to build a track that
    # travelled min_travel_m and was published from the 5th pair; they start none now.
    estimator, frames = _painted_run(sliding(0.45), 12)
    assert estimator.counts['legs_only_detections'] == 12
    assert estimator.counts['cut_legs_seen'] == 0
    assert estimator.tracker.counts['legs_only_not_started'] == 12
    assert not any(frame.tracks for frame in frames)
    # Warm down to 0.3 m, in the legs' rows: it stands on them and is published.
    estimator, frames = _painted_run(sliding(0.3), 12)
    assert estimator.counts['cut_legs_seen'] == 12
    assert estimator.tracker.counts['legs_only_not_started'] == 0
    assert all(frame.tracks for frame in frames[1:])


def test_a_published_far_person_whose_legs_are_hidden_a_while_keeps_the_id():
    def standing(hidden):
        # Only the legs show (5.6 m off); in the ``hidden`` pairs their lower part is cool (a
        # chair in front): the legs-only detection continues the published track.
        return lambda k: _legs(0.4, 5.6, top=1.2)[
            _legs(0.4, 5.6, top=1.2)[:, 2] >= (0.45 if k in hidden else 0.0)]
    estimator, frames = _painted_run(standing(set(range(10, 30))), 40)
    assert estimator.counts['cut_legs_seen'] == 20
    ids = [[t.track_id for t in frame.tracks] for frame in frames]
    assert ids[1:] == [[1]] * 39
    # With the legs test off (legs_min_fraction 0) nothing tells legs from a low warm thing:
    # legs-only bodies are not kept, and counted.
    estimator, frames = _painted_run(standing(set()), 5, PeopleConfig(legs_min_fraction=0.0))
    assert estimator.counts['legs_only_not_checked'] == 5
    assert not any(frame.tracks or frame.detections for frame in frames)


def test_the_top_edge_height_is_where_the_simulator_projects_the_top_row():
    rig, transform, intrinsics = _rig_geometry()
    p1 = rig.rectification()[2]
    for y in (2.0, 3.5, 5.1, 6.4):
        height = top_edge_height_m((0.3, y), transform, intrinsics)
        camera = rig.to_rectified_left(np.array([[0.3, y, height], [0.3, y, height + 0.01]]))
        rows = p1[1, 1] * camera[:, 1] / camera[:, 2] + p1[1, 2]
        assert rows[0] >= -0.5 > rows[1], (y, height, rows)
    # Behind the rig, or below the image near it: the top edge does not cross there.
    assert math.isnan(top_edge_height_m((0.0, -2.0), transform, intrinsics))


def test_a_silhouette_reaching_the_top_row_is_one_rising_out_of_the_image():
    warm = np.zeros((60, 80), dtype=bool)
    warm[0:25, 30:37] = True                    # a body rising out of the image
    warm[0:8, 50:60] = True                     # something else at the top, apart
    points = np.array([[31.0, 12.0], [35.0, 18.0], [33.0, 24.0]])
    assert silhouette_reaches_top(warm, points)
    lower = warm.copy()
    lower[0:3, 30:37] = False                   # its top in view, cool rows above
    assert not silhouette_reaches_top(lower, points)
    # Joined to a warm region on row 0 only beside its points' columns: not its own top.
    bridge = lower.copy()
    bridge[3, 37:50] = True
    assert not silhouette_reaches_top(bridge, points)
    assert not silhouette_reaches_top(warm, np.zeros((0, 2)))


def _published(detection):
    """Return where a track taking ``detection`` publishes it: moved by its ``across``."""
    return detection.x + detection.across[0], detection.y + detection.across[1]


def _one_sided(x, y, surfaces, member_below_x):
    """Return a detection of the painted ``surfaces``: its points left of ``member_below_x``."""
    rig, transform, intrinsics = _rig_geometry()
    warm, points, pixels = _painted(rig, surfaces)
    world = rectified_to_world(points, transform)
    members = np.flatnonzero((world[:, 0] < member_below_x) & (np.abs(world[:, 1] - y) < 0.05))
    detection = Detection(float(np.median(world[members, 0])), y, 1.5, len(members), 1.0,
                          np.eye(2) * 1e-3, members=members)
    return detection, warm, transform, intrinsics, points, pixels


def test_a_body_matched_on_one_outline_is_placed_at_its_silhouettes_middle():
    body = _box(0.2, 0.6, 4.0, 0.0, 1.5, nx=40, nz=80)        # 0.4 m wide, its middle at 0.4
    detection, *scene = _one_sided(0.4, 4.0, body, member_below_x=0.28)
    assert detection.x < 0.3                                    # its points: the left outline
    counts = {}
    [centred] = centred_on_silhouette([detection], *scene, counts=counts)
    assert (centred.x, centred.y) == (detection.x, detection.y)     # what the tracker follows
    x, y = _published(centred)
    assert abs(x - 0.4) <= 0.03 and abs(y - 4.0) <= 0.03, (x, y)
    assert counts == {'silhouette_centred': 1, 'silhouette_not_found': 0,
                      'silhouette_shared': 0}
    # Matched on both outlines already: it stays where it is.
    whole, *scene = _one_sided(0.4, 4.0, body, member_below_x=1.0)
    [kept] = centred_on_silhouette([whole], *scene)
    assert abs(_published(kept)[0] - whole.x) <= 0.03 and abs(whole.x - 0.4) <= 0.03


def test_a_silhouette_joined_to_a_wide_warm_thing_or_the_image_side_moves_nothing():
    body = _box(0.2, 0.6, 4.0, 0.3, 1.5, nx=40, nz=80)
    # A warm wall 1.2 m wide right behind the body, as warm: one run, wider than a person.
    wall = _box(0.2, 1.4, 4.05, 0.0, 1.7, nx=120, nz=90)
    detection, *scene = _one_sided(0.4, 4.0, np.vstack([body, wall]), member_below_x=0.28)
    counts = {}
    assert centred_on_silhouette([detection], *scene, counts=counts) == [detection]
    assert counts == {'silhouette_centred': 0, 'silhouette_not_found': 1,
                      'silhouette_shared': 0}
    # A body running off the image's side: its width beyond it is not seen.
    rig, transform, intrinsics = _rig_geometry()
    edge = _box(-3.5, -1.8, 4.0, 0.0, 1.5, nx=200, nz=80)
    detection, *scene = _one_sided(-2.0, 4.0, edge, member_below_x=-1.9)
    assert centred_on_silhouette([detection], *scene) == [detection]
    # A body cut by the rectification's invalid border (no data, never warm) likewise.
    body, *scene = _one_sided(0.4, 4.0, _box(0.2, 0.6, 4.0, 0.3, 1.5, nx=40, nz=80), 1.0)
    warm, pixels = scene[0], scene[4]
    border = int(np.rint(pixels[:, 0].min())) + 3
    cut, valid = warm.copy(), np.ones(warm.shape, dtype=bool)
    cut[:, :border] = valid[:, :border] = False
    inside = np.flatnonzero(np.rint(pixels[body.members, 0]) >= border)
    body = dataclasses.replace(body, members=body.members[inside])
    assert centred_on_silhouette([body], cut, *scene[1:], valid=valid) == [body]
    [moved] = centred_on_silhouette([body], cut, *scene[1:])     # (without: the cut middle)
    assert _published(moved)[0] - body.x > 0.03
    # No matched point on a warm pixel: nothing to go by.
    [same] = centred_on_silhouette([dataclasses.replace(detection, members=np.zeros(0, int))],
                                   *scene)
    assert same.across == (0.0, 0.0)


def test_what_stands_on_a_stronger_bodys_silhouette_keeps_its_own_position():
    body = _box(0.2, 0.6, 4.0, 0.3, 1.5, nx=40, nz=80)
    other = _box(1.4, 1.8, 4.0, 0.3, 1.5, nx=40, nz=80)       # another person, 0.8 m aside
    behind = _box(0.3, 0.7, 4.6, 0.3, 1.8, nx=40, nz=90)      # and one 0.6 m behind the first
    strong, warm, transform, intrinsics, points, pixels = _one_sided(
        0.4, 4.0, np.vstack([body, other, behind]), member_below_x=0.3)
    world = rectified_to_world(points, transform)
    # The first body's upper right outline matched 0.7 m too far: a fragment on its
    # silhouette, which centred would stand on the body's bearing.
    upper_right = np.flatnonzero((world[:, 0] > 0.5) & (world[:, 0] < 0.6) &
                                 (world[:, 2] > 1.0) & (np.abs(world[:, 1] - 4.0) < 0.05))
    fragment = Detection(0.6, 4.7, 1.5, 6, 1.0, np.eye(2) * 1e-3, members=upper_right)
    # The person behind, matched on its own right outline, its rows joined to the first's.
    right = np.flatnonzero((world[:, 0] > 0.6) & (np.abs(world[:, 1] - 4.6) < 0.05))
    person_behind = Detection(0.65, 4.6, 1.8, 7, 1.0, np.eye(2) * 1e-3, members=right[::20])
    beside = np.flatnonzero(world[:, 0] > 1.3)
    second = Detection(1.6, 4.0, 1.5, 8, 1.0, np.eye(2) * 1e-3, members=beside[::50])
    counts = {}
    given = [fragment, strong, person_behind, second]
    out = centred_on_silhouette(given, warm, transform, intrinsics, points, pixels, counts)
    assert [d.points for d in out] == [d.points for d in given]      # nobody left out
    assert out[0] == fragment and out[2] == person_behind
    assert abs(_published(out[1])[0] - 0.4) <= 0.03 and abs(_published(out[3])[0] - 1.6) <= 0.03
    assert counts == {'silhouette_centred': 2, 'silhouette_not_found': 0,
                      'silhouette_shared': 2}


def test_a_limb_a_pixel_apart_is_the_bodys_and_one_row_moves_nothing():
    body = _box(0.2, 0.6, 4.0, 0.3, 1.5, nx=40, nz=80)
    detection, warm, transform, intrinsics, points, pixels = _one_sided(0.4, 4.0, body, 0.28)
    # An arm one cool pixel apart from the body, its points on the arm alone.
    rows = np.unique(np.rint(pixels[detection.members, 1]).astype(int))
    arm_cols = np.array([np.flatnonzero(warm[r]).min() - 2 for r in rows])
    arm = warm.copy()
    arm[rows, arm_cols] = True
    arm_pixels = np.column_stack([arm_cols, rows]).astype(float)
    member_rows = np.rint(pixels[detection.members, 1]).astype(int)
    arm_points = np.array([points[detection.members[member_rows == r]].mean(axis=0)
                           for r in rows])
    on_arm = dataclasses.replace(detection, members=len(points) + np.arange(len(arm_points)))
    [bridged] = centred_on_silhouette([on_arm], arm, transform, intrinsics,
                                      np.vstack([points, arm_points]),
                                      np.vstack([pixels, arm_pixels]))
    assert abs(_published(bridged)[0] - 0.4) <= 0.08       # the body's middle, and the arm's
    # Most of its rows joined to a neighbour's (too wide): the few left do not decide.
    runs, rows_with_points = silhouette_runs(warm, detection, intrinsics, points, pixels)
    assert rows_with_points == len(runs) >= 10
    assert silhouette_shift_xy(runs, detection, transform, intrinsics) is not None
    assert silhouette_shift_xy(runs, detection, transform, intrinsics,
                               rows_with_points=2 * len(runs) + 1) is None
    # Only one row of the body in view holds its points: too little to go by.
    one = np.flatnonzero(member_rows == rows[0])
    few = dataclasses.replace(detection, members=detection.members[one])
    assert centred_on_silhouette([few], warm, transform, intrinsics, points, pixels) == [few]


def test_one_pair_of_legs_holds_up_one_body_and_what_is_not_checked_is_counted():
    rig, transform, intrinsics = _rig_geometry()
    warm, points, pixels = _painted(rig, _legs(-1.0, 4.3))

    def cut(x, y, strength):
        return Detection(x, y, 0.95, 20, strength, np.eye(2) * 1e-3, head_visible=False,
                         cut_top=True)
    # A fragment 0.2 m aside of the same body holds one leg in its window: alone, it stands.
    fragment = cut(-0.8, 4.3, 0.5)
    assert legs_fraction(warm, (-0.8, 4.3), transform, intrinsics, points, pixels) >= 0.5
    counts = {}
    marked = standing_on_legs([cut(-1.0, 4.3, 1.0), fragment, cut(0.0, -1.0, 0.4)], warm,
                              transform, intrinsics, points, pixels, counts=counts)
    assert [d.legs_seen for d in marked] == [True, False, False]
    assert counts == {'cut_legs_checked': 2, 'cut_legs_seen': 1, 'cut_legs_out_of_image': 1,
                      'cut_legs_fragment': 1, 'cut_legs_gap': 0, 'cut_legs_wide': 0,
                      'head_legs_checked': 0,
                      'head_legs_seen': 0}
    assert standing_on_legs([fragment], warm, transform, intrinsics, points,
                            pixels)[0].legs_seen


def test_the_warm_background_sees_a_person_there_from_the_first_frame_and_ignores_an_ffc():
    rng = np.random.default_rng(0)
    room = 8000 + rng.normal(0, 5, (60, 80))
    person = np.zeros((60, 80), dtype=bool)
    person[20:45, 30:38] = True
    background = WarmBackground(PeopleConfig(warm_margin_counts=100.0))
    for index in range(30):
        image = room + rng.normal(0, 5, room.shape) + 250 * person
        if index >= 20:
            image += 400                          # a flat-field correction's offset jump
        warm = background.update(image, 0.115 * index)
        assert warm[person].mean() > 0.95, index
        assert warm[~person].mean() < 0.01, index


def test_the_warm_background_learns_a_cool_change_and_ignores_pixels_without_data():
    background = WarmBackground(PeopleConfig(background_time_s=1.0))
    image = np.full((60, 80), 8000.0)
    image[:, :5] = 0                              # outside the raw image after rectification
    background.update(image, 0.0)
    image[30:, :] += 300                          # the floor warms up (sun), no one there
    image[:, :5] = 0
    warmed = [background.update(image, 0.0 + t).mean() for t in np.arange(0.1, 6.0, 0.1)]
    assert warmed[0] > 0.3
    assert warmed[-1] < 0.01                      # stays warm only while learning


def walk(start, velocity, times, head=1.7):
    return [Detection(start[0] + velocity[0] * t, start[1] + velocity[1] * t, head, 100, 1.0,
                      np.eye(2) * 1e-3) for t in times]


def _walker_stops_beside(still, leaves_s=None, end_s=6.0, config=None, still_cut=False,
                         walker_cut=False, walker_stop=None, walker_start=(-1.0, 3.2),
                         walks_from_s=0.0, screen=None, screen_from_s=0.0):
    """
    Run a walker up to a still person, stopping 0.28 m beside them (one detection then).

    The still person's warm points stay at their place (``support``) until ``leaves_s``
    (they leave unseen, inside the walker's cluster). Returns the tracker and, per pair,
    ``(t, {id: position})`` of the published tracks.
    """
    tracker, times = PeopleTracker(config), np.arange(0, end_s, 0.115)
    start = np.array(walker_start)     # the still person is seen whole for 1.5 s first
    stop = np.array(walker_stop if walker_stop is not None else
                    (still[0] - 0.2, still[1] + 0.2))
    travel = float(np.hypot(*(stop - start)))
    published = []
    for index, t in enumerate(times):
        walker = start + (stop - start) * min(1.0, max(0.0, t - walks_from_s) / travel)
        jitter = 0.03 * (index % 3 - 1)          # a still person's detections wander a little
        there = leaves_s is None or t < leaves_s
        detections = [Detection(*walker, 1.5, 90, 1.0, np.eye(2) * 1e-3,
                                head_visible=not walker_cut, cut_top=walker_cut)]
        if math.dist(walker, still) > 0.6 and there:     # closer, one cluster
            detections.append(Detection(still[0] + jitter, still[1], 1.6, 60, 1.0,
                                        np.eye(2) * 1e-3,
                                        head_visible=not still_cut, cut_top=still_cut,
                                        legs_seen=still_cut))
        if screen is not None and t >= screen_from_s:   # the still person hid it
            detections.append(Detection(*screen, 1.0, 20, 1.0, np.eye(2) * 1e-3,
                                        head_visible=False, cut_top=True))

        def support(x, y, others=()):
            return 20 if there and math.dist((x, y), still) < 0.15 else 0
        published.append((t, {track.track_id: tuple(track.position)
                              for track in tracker.update(detections, t, support)}))
    return tracker, published


def test_a_still_person_merged_into_a_neighbours_detection_keeps_the_id():
    # The recording: a walker stops 0.28 m beside a person who sits down; from 0.5 m apart
    # the two make one detection, and the still person's track ended.
    still = (1.0, 2.4)
    tracker, published = _walker_stops_beside(still)
    ids = published[3][1]
    still_id = min(ids, key=lambda k: math.dist(ids[k], still))
    for t, tracks in published[3:]:
        assert still_id in tracks and math.dist(tracks[still_id], still) < 0.05, (t, tracks)
        assert len(tracks) == 2
    assert tracker.counts['held_beside'] > 20
    # Off: the still person's track is withdrawn once it coasts publish_coast_s.
    _, off = _walker_stops_beside(still, config=PeopleConfig(hold_beside_points=0))
    assert len(off[-1][1]) == 1


@pytest.mark.parametrize('case', ['left', 'neighbour_far', 'neighbour_unpublished',
                                  'head_never_seen', 'left_screen'])
def test_a_still_track_is_held_only_while_its_person_and_a_neighbour_are_there(case):
    # A review's scripted scenes: without each condition, a ghost stayed published beside
    # the walker for as long as the walker stayed (a minute), or a warm object's track was.
    config = PeopleConfig()
    still = (1.0, 2.4)
    if case == 'left':              # leaves unseen at 4 s: no warm points at its place
        tracker, published = _walker_stops_beside(still, leaves_s=4.0, end_s=8.0)
    elif case == 'left_screen':     # leaves; a warm screen it hid shows 0.46 m off
        tracker, published = _walker_stops_beside(still, leaves_s=4.0, end_s=8.0,
                                                  screen=(1.3, 2.05), screen_from_s=4.2)
        walker_id = {track_id for t, tracks in published if 3.0 < t < 4.0
                     for track_id, xy in tracks.items() if math.dist(xy, (0.8, 2.6)) < 0.1}
        assert len(walker_id) == 1
        for t, tracks in published:
            if t > 4.2:     # the walker keeps its id; nothing is published on the screen
                assert [k for k, xy in tracks.items() if math.dist(xy, (0.8, 2.6)) < 0.1] == \
                    list(walker_id), (t, tracks)
                assert not any(math.dist(xy, (1.3, 2.05)) < 0.3 for xy in tracks.values())
    elif case == 'neighbour_far':   # the walker stops 1 m away; the still one vanishes then
        tracker, published = _walker_stops_beside(still, leaves_s=2.5,
                                                  walker_stop=(0.0, 2.6))
    elif case == 'neighbour_unpublished':   # cut, no legs, under 1 m walked: never published
        # (its steady walk would publish it: steady_walk_m off keeps the neighbour unpublished)
        tracker, published = _walker_stops_beside(still, walker_cut=True,
                                                  walker_start=(0.2, 3.0), walks_from_s=1.5,
                                                  config=PeopleConfig(steady_walk_m=0.0))
    else:                           # published on legs under a cut body, never seen whole
        tracker, published = _walker_stops_beside(still, still_cut=True)
    end = published[-1][0]
    lasting = [tracks for t, tracks in published
               if t > end - 1.0 and any(math.dist(xy, still) < 0.1 for xy in tracks.values())]
    if case in ('left', 'left_screen'):
        assert tracker.counts['held_beside'] > 10     # held while they were there
        late = [tracks for t, tracks in published if t > 4.0 + config.publish_coast_s + 0.12]
        assert late and not any(math.dist(xy, still) < 0.1 for tracks in late
                                for xy in tracks.values())
        assert tracker.counts['ended'] >= 1           # ended after max_coast_s
    else:
        assert tracker.counts['held_beside'] == 0, case
        assert not lasting, case


def test_a_short_lived_track_beside_a_still_person_is_not_held():
    # A review's scene: a fragment beside a person standing still, published by two whole
    # detections, its points still there when its detections stop: it was held for good.
    tracker, times = PeopleTracker(), np.arange(0, 8.0, 0.115)
    person = Detection(1.0, 2.4, 1.7, 90, 1.0, np.eye(2) * 1e-3)
    fragment = Detection(1.35, 2.4, 1.2, 12, 1.0, np.eye(2) * 1e-3)
    published = []
    for index, t in enumerate(times):
        detections = [person] + ([fragment] if 20 <= index < 24 else [])
        published.append(len(tracker.update(detections, t, lambda x, y, o=(): 20)))
    assert max(published) == 2                       # the fragment was published
    assert published[-1] == 1 and tracker.counts['held_beside'] == 0


def test_the_support_of_a_place_leaves_out_the_points_nearer_a_neighbour():
    # The support counts the warm body points at a place nearer to it than to the
    # neighbours' detections: of a walker's points spilling towards an empty seat 0.2 m away,
    # only those past the middle count (a documented limit: a neighbour that near, spread
    # that wide, can still hold the seat).
    estimator = PeopleEstimator(np.eye(4))
    rng = np.random.default_rng(7)
    walker = np.column_stack([rng.normal(0.8, 0.08, 200), rng.normal(2.6, 0.08, 200),
                              rng.uniform(0.7, 1.6, 200)])
    seated = np.column_stack([rng.normal(1.0, 0.05, 40), rng.normal(2.45, 0.05, 40),
                              rng.uniform(0.7, 1.1, 40)])
    empty = estimator._warm_support(walker)
    alone, beside = empty(0.95, 2.47), empty(0.95, 2.47, [(0.8, 2.6)])
    assert alone >= 2 * beside > 0
    taken = estimator._warm_support(np.vstack([walker, seated]))
    assert taken(0.95, 2.47, [(0.8, 2.6)]) >= beside + 30
    # Points below min_point_height_m (the floor, legs) are no support.
    assert estimator._warm_support(seated * [1, 1, 0.5])(1.0, 2.45) == 0


def test_a_moving_track_is_not_held_beside_another():
    # A walker whose detections stop next to a standing person's is not at rest: it coasts
    # and is withdrawn after publish_coast_s as before.
    config = PeopleConfig()
    tracker, times = PeopleTracker(config), np.arange(0, 4.0, 0.115)
    still = Detection(1.0, 2.4, 1.6, 60, 1.0, np.eye(2) * 1e-3)
    walker = walk((-0.5, 2.6), (1.0, 0.0), times, head=1.5)
    last = {}
    for t, moving in zip(times, walker):
        detections = [still] + ([moving] if t < 1.1 else [])     # last 0.5 m from it
        last[t] = {track.track_id for track in tracker.update(detections, t,
                                                              lambda x, y, o=(): 20)}
    assert len(last[times[times < 1.1][-1]]) == 2
    assert all(len(ids) == 1 for t, ids in last.items() if t > 1.1 + config.publish_coast_s)
    assert tracker.counts['held_beside'] == 0


def test_two_people_crossing_keep_their_ids_and_velocity():
    times = np.arange(0, 4, 0.115)
    a = walk((-1.5, 3.0), (1.0, 0.1), times)
    b = walk((1.5, 3.3), (-1.0, -0.1), times)
    tracker = PeopleTracker()
    seen = {}
    for t, da, db in zip(times, a, b):
        for track in tracker.update([da, db], t):
            seen.setdefault(track.track_id, []).append((t, track.state.copy()))
    assert len(seen) == 2
    for states in seen.values():
        xs = [s[0] for _, s in states]
        assert abs(xs[-1] - xs[0]) > 3.0           # each id follows one walker across
        assert abs(abs(states[-1][1][2]) - 1.0) < 0.1   # vx


def test_a_short_occlusion_keeps_the_id_and_a_long_one_ends_the_track():
    config = PeopleConfig()
    tracker = PeopleTracker(config)
    times = np.arange(0, 6, 0.115)
    detections = walk((0.0, 3.0), (0.5, 0.0), times)
    ids, ended = set(), []
    for t, detection in zip(times, detections):
        occluded = 1.0 <= t < 1.4 or t >= 3.0
        for track in tracker.update([] if occluded else [detection], t):
            ids.add(track.track_id)
        ended += tracker.ended
    assert ids == {1}
    assert ended == [1]
    assert tracker.tracks == []


def test_a_static_warm_object_cut_by_the_top_edge_is_never_a_person():
    tracker = PeopleTracker()
    screen = Detection(1.3, 4.5, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True)
    for t in np.arange(0, 5, 0.115):
        assert tracker.update([screen], t) == []
    assert tracker.counts['started'] == 0


def test_an_unconfirmed_track_does_not_coast_on_to_take_a_stray_detection():
    # walk_across: a screen fragment's unconfirmed track took a passer-by's detection, coasted
    # across the room with that velocity for 1.3 s with a growing gate, took a ghost (the
    # walker's lower body, head 1.0 m) 0.9 m from its prediction and was published with it.
    tracker = PeopleTracker()
    screen = Detection(1.1, 4.6, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True)
    times = np.arange(0, 4.6, 0.115)
    for t in times[times < 3.5]:
        assert tracker.update([screen], t) == []
    kicked = dataclasses.replace(screen, x=1.0, y=4.3)     # a passer-by in front of it
    assert tracker.update([kicked], 3.5) == []
    for t in times[(times > 3.5) & (times < 4.5)]:
        assert tracker.update([], t) == []
    ghost = Detection(0.55, 3.0, 1.0, 23, 1.0, np.eye(2) * 1e-3)
    assert tracker.update([ghost], 4.6) == []
    assert tracker.counts['started'] == 0


def test_the_assignment_leaves_a_track_out_rather_than_push_another_off_its_detection():
    # A coasting track allowed only the detection another track sits on (0.01 m from it),
    # 1.3 m from its own prediction: leaving it out costs the largest gate (1.6 m), less than
    # the 1.3 + 0.7 m of pushing the other track onto a detection 0.7 m off.
    assert gated_assignment([[np.inf, 1.3], [0.7, 0.01]], [1.6, 0.8], 1.6) == [(1, 1)]
    # Nothing lost where every track has its own detection, and none beyond its gate.
    assert sorted(gated_assignment([[0.1, 0.9], [0.7, 0.2]], [0.8, 0.8], 1.6)) == \
        [(0, 0), (1, 1)]
    assert gated_assignment([[0.9]], [0.8], 1.6) == []
    assert gated_assignment(np.zeros((2, 0)), [0.8, 0.8], 1.6) == []
    # Two tracks wanting one detection: the nearer takes it, whatever their gates (crossing:
    # with each track's own gate as its cost, the one with the larger gate took it).
    assert gated_assignment([[0.5], [0.3]], [0.8, 0.8], 1.6) == [(1, 0)]
    assert gated_assignment([[0.09], [0.16]], [0.9, 0.99], 1.6) == [(0, 0)]
    with pytest.raises(ValueError, match='miss_cost'):
        gated_assignment([[0.1]], [0.9], 0.8)


def test_two_people_standing_side_by_side_keep_their_ids_while_a_walker_hides_one():
    # open_office, traced: two people cut by the top edge stand 0.73 m apart; a walker in
    # front hides part of the right one (its detection 0.2 m off, giving its track a
    # velocity), then all of it for five pairs. When it shows again, without its legs, its
    # track, coasting 0.6 m away and lost for a body without legs, took the left person's
    # detection and pushed the left person's track onto the right one: the ids swapped.
    def standing(x, y, legs=True):
        return Detection(x, y, 1.2, 30, 1.0, np.eye(2) * 1e-3, head_visible=False,
                         cut_top=True, legs_seen=legs)

    right, left = (0.20, 4.29), (-0.50, 4.49)
    tracker = PeopleTracker()
    times = np.arange(0, 3.1, 0.115)
    ids = {}
    for t in times:
        if t < 2.25:
            detections = [standing(*right), standing(*left)]
        elif t < 2.4:
            detections = [standing(0.42, 4.35, legs=False), standing(*left)]
        elif t < 2.95:
            detections = [standing(-0.60, 4.62)]
        else:
            detections = [standing(-0.60, 4.60), standing(0.09, 4.35, legs=False)]
        published = tracker.update(detections, t)
        if t < 2.25 and len(published) == 2:
            ids = {track.track_id: tuple(track.state[:2]) for track in published}
    assert len(ids) == 2
    left_id = min(ids, key=lambda k: math.hypot(ids[k][0] - left[0], ids[k][1] - left[1]))
    on_left = [track.track_id for track in tracker.tracks if track.updated and
               math.hypot(track.state[0] - left[0], track.state[1] - left[1]) < 0.3]
    assert on_left == [left_id]


def _walker_past_a_split_screen(config, walker_stops_s=2.0, end_s=5.0):
    """Run a published walker towards a screen that makes two cut detections 0.45 m apart."""
    tracker = PeopleTracker(config)
    halves = [Detection(1.62, 4.57, 0.99, 24, 1.0, np.eye(2) * 1e-3, head_visible=False,
                        cut_top=True),
              Detection(1.17, 4.62, 0.97, 22, 1.0, np.eye(2) * 1e-3, head_visible=False,
                        cut_top=True)]
    published = []
    for index, t in enumerate(np.arange(0, end_s, 0.115)):
        screen = halves if index % 3 else halves[:1]        # one half missing now and then
        walker = walk((-0.9, 3.3), (0.9, 0.5), [t])[0]
        detections = screen + ([walker] if t < walker_stops_s else [])
        published.append((t, walker, [(track.track_id, track.state[:2].copy())
                                      for track in tracker.update(detections, t)]))
    return tracker, published


def test_a_published_walker_passing_a_warm_screen_does_not_take_it():
    # far_walker, and walk_across with the POC velocities: a walker's detections stopped
    # beside a warm screen cut by the top edge, its track took the screen's detection
    # (within gate_m of its prediction) and stayed on the screen for good.
    config = PeopleConfig()
    tracker, published = _walker_past_a_split_screen(config)
    assert any(tracks for t, _, tracks in published if t < 2.0)
    late = [tracks for t, _, tracks in published if t > 2.0 + config.publish_coast_s + 0.05]
    assert late and not any(late)               # coasted, then ended: nothing on the screen
    assert tracker.counts['object_detections'] > 0
    hijacked = PeopleConfig(object_min_hits=0)
    _, before = _walker_past_a_split_screen(hijacked)
    assert all(tracks for t, _, tracks in before if t > 2.0 + config.publish_coast_s + 0.05)


@pytest.mark.parametrize('walker_y, lost_at_x', [(4.0, 1.3), (4.1, 2.0)])
def test_a_walker_who_hid_the_screen_does_not_take_it_either(walker_y, lost_at_x):
    # The walker hides one half of the screen for a few pairs, then its own detections stop:
    # the hidden half's track ends (an unpublished track coasts unconfirmed_coast_s), or
    # moves to the other half, and a new one is an object only after object_min_hits; where
    # the object was is remembered for max_coast_s (an independent review's scenes).
    def run(config):
        tracker, last = PeopleTracker(config), []
        halves = [(1.62, 4.57), (1.17, 4.62)]
        for t in np.arange(0, 4.5, 0.115):
            walker_x = -0.5 + 0.9 * t
            detections = [Detection(x, y, 0.99, 24, 1.0, np.eye(2) * 1e-3, head_visible=False,
                                    cut_top=True) for x, y in halves
                          if not (abs(walker_x - x * walker_y / y) < 0.3 and
                                  walker_x < lost_at_x)]
            if walker_x < lost_at_x:
                detections += walk((walker_x, walker_y), (0.0, 0.0), [0.0])
            last = tracker.update(detections, t)
        return tracker, last
    tracker, last = run(PeopleConfig())
    assert last == [] and tracker.counts['object_detections'] > 0
    assert [track.track_id for track in run(PeopleConfig(object_min_hits=0))[1]] == [1]


def test_withheld_counts_only_what_a_track_could_have_taken():
    tracker = PeopleTracker()
    screen = Detection(1.62, 4.57, 0.99, 24, 1.0, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True)
    for t in np.arange(0, 3, 0.115):        # a walker 2.6 m from the screen
        published = tracker.update([screen] + walk((-1.0, 2.0), (0.9, 0.0), [t]), t)
    assert [track.track_id for track in published] == [1]
    assert any(tracker.is_warm_object(track) for track in tracker.tracks)
    assert tracker.counts['object_detections'] == 0


def test_a_published_walker_reaching_a_warm_screen_keeps_its_id():
    # Only what the screen alone makes (cut, no legs) is the screen's: the walker's own
    # detections, head in view, are the walker's up to the screen.
    _, published = _walker_past_a_split_screen(PeopleConfig(), walker_stops_s=2.6, end_s=2.6)
    for t, walker, tracks in published[2:]:
        assert [key for key, _ in tracks] == [1]
        assert math.hypot(*(tracks[0][1] - (walker.x, walker.y))) < 0.1


def test_a_far_person_beside_one_whose_legs_are_hidden_keeps_the_track():
    # Two people standing far off 0.7 m apart, heads above the image: one on legs (published),
    # one with its legs hidden (never published: to the tracker a warm object). The
    # published one's own detections without legs stay its own.
    config = PeopleConfig()
    tracker = PeopleTracker(config)
    rng = np.random.default_rng(3)
    ids = set()
    for index, t in enumerate(np.arange(0, 6, 0.115)):
        jitter = rng.normal(0.0, 0.05, 4)
        seen = Detection(0.2 + jitter[0], 4.3 + jitter[1], 1.1, 20, 1.0, np.eye(2) * 1e-3,
                         head_visible=False, cut_top=True, legs_seen=index < 4 or index % 2)
        hidden = Detection(-0.5 + jitter[2], 4.5 + jitter[3], 1.1, 20, 1.0, np.eye(2) * 1e-3,
                           head_visible=False, cut_top=True)
        tracks = tracker.update([seen, hidden], t)
        if index >= 2:
            assert len(tracks) == 1 and abs(tracks[0].state[0] - 0.2) < 0.2
        ids.update(track.track_id for track in tracks)
    assert ids == {1}


def test_time_going_back_starts_over():
    tracker = PeopleTracker()
    for t, d in zip((0.0, 0.115, 0.23), walk((0, 3), (0, 0), (0.0, 0.115, 0.23))):
        tracker.update([d], t)
    assert tracker.update([], 0.0) == []
    assert tracker.ended == [1] and tracker.counts['time_backwards'] == 1


def _tracks():
    tracker = PeopleTracker()
    for t, d in zip((0.0, 0.115), walk((0.5, 3.0), (1.0, 0.0), (0.0, 0.115), head=1.65)):
        tracks = tracker.update([d], t)
    return tracks


def test_the_detections_cloud_holds_every_documented_field():
    tracks = _tracks()
    header = Header(frame_id='map')
    header.stamp.sec = 12
    cloud = detections_cloud(header, tracks)
    assert cloud.header.frame_id == 'map' and cloud.width == 1
    fields = point_cloud_fields(cloud, DETECTION_FIELDS)
    assert fields['id'][0] == tracks[0].track_id
    assert fields['height'][0] == pytest.approx(1.65)
    assert fields['x'][0] == pytest.approx(tracks[0].state[0], abs=1e-6)
    assert fields['cov_xx'][0] > 0 and fields['z'][0] == 0.0
    empty = detections_cloud(header, [])
    assert empty.width == 0 and point_cloud_fields(empty, ('x',))['x'].size == 0


def test_a_track_follows_the_points_and_publishes_the_silhouettes_middle():
    tracker = PeopleTracker()
    shifted = [dataclasses.replace(d, across=(0.0, -0.12)) for d in
               walk((0.5, 3.0), (1.0, 0.0), (0.0, 0.115), head=1.65)]
    for t, d in zip((0.0, 0.115), shifted):
        tracks = tracker.update([d], t)
    plain = _tracks()
    # The filter saw the same detections; what is published moves by the last one's shift.
    assert np.allclose(tracks[0].state, plain[0].state)
    assert np.allclose(tracks[0].position, plain[0].state[:2] + [0.0, -0.12])
    header = Header(frame_id='map')
    cloud = point_cloud_fields(detections_cloud(header, tracks), DETECTION_FIELDS)
    assert cloud['y'][0] == pytest.approx(tracks[0].position[1], abs=1e-6)
    assert poses_msg(header, tracks).poses[0].position.y == pytest.approx(tracks[0].position[1])


def test_poses_face_the_walking_direction_and_ended_tracks_delete_their_markers():
    tracks = _tracks()
    header = Header(frame_id='map')
    pose = poses_msg(header, tracks).poses[0]
    yaw = 2 * math.atan2(pose.orientation.z, pose.orientation.w)
    assert yaw == pytest.approx(math.atan2(tracks[0].state[3], tracks[0].state[2]), abs=1e-6)
    markers = markers_msg(header, tracks, ended=[7]).markers
    assert [(m.ns, m.id, m.action) for m in markers] == [
        ('people', 1, Marker.ADD), ('people_ids', 1, Marker.ADD),
        ('people', 7, Marker.DELETE), ('people_ids', 7, Marker.DELETE)]
    assert markers[1].text == '1'


def test_detection3d_array_with_a_stand_in_vision_msgs_module():
    """vision_msgs does not install from the package index: a stand-in with its fields."""
    def message(**fields):
        return lambda: types.SimpleNamespace(**{k: v() for k, v in fields.items()})
    point = message(x=float, y=float, z=float)
    quaternion = message(x=float, y=float, z=float, w=float)
    pose = message(position=point, orientation=quaternion)
    fake = types.SimpleNamespace(
        Detection3DArray=message(header=Header, detections=list),
        Detection3D=message(header=Header, id=str, results=list,
                            bbox=message(center=pose, size=point)),
        ObjectHypothesisWithPose=message(
            hypothesis=message(class_id=str, score=float),
            pose=message(pose=pose, covariance=list)))
    tracks = _tracks()
    msg = detection3d_msg(fake, Header(frame_id='map'), tracks)
    detection = msg.detections[0]
    assert detection.id == str(tracks[0].track_id)
    assert detection.results[0].hypothesis.class_id == 'person'
    assert detection.bbox.center.position.x == pytest.approx(tracks[0].state[0])
    assert len(detection.results[0].pose.covariance) == 36


def _scored(frames):
    from st_stereo.tools.eval_people import PeopleTally
    tally = PeopleTally()
    for truth, estimates in frames:
        tracks = [types.SimpleNamespace(position=np.array([x, y]), head_height=h,
                                        track_id=i, depth_spread_m=0.2)
                  for i, x, y, h in estimates]
        tally.add(list(range(len(truth))), np.array(truth).reshape(-1, 3), tracks)
    return tally.row()


def test_the_people_scores_count_hits_misses_false_people_and_id_switches():
    heads = [(0.0, 3.0, 1.7), (1.0, 3.0, 1.6)]
    perfect = _scored([(heads, [(1, 0.05, 3.0, 1.7), (2, 1.0, 3.1, 1.5)])] * 4)
    assert perfect['recall'] == perfect['precision'] == perfect['mota'] == 1.0
    assert perfect['horizontal_median_m'] == pytest.approx(0.075, abs=1e-9)
    assert perfect['height_median_m'] == pytest.approx(0.05, abs=1e-9)
    # The second person missed in one pair, a false one 2 m away, then an id switch.
    row = _scored([(heads, [(1, 0.0, 3.0, 1.7), (2, 1.0, 3.0, 1.6)]),
                   (heads, [(1, 0.0, 3.0, 1.7), (3, 3.0, 1.0, 1.6)]),
                   (heads, [(4, 0.0, 3.0, 1.7), (2, 1.0, 3.0, 1.6)])])
    assert row['recall'] == pytest.approx(5 / 6) and row['precision'] == pytest.approx(5 / 6)
    assert row['id_switches'] == 1
    assert row['mota'] == pytest.approx(1 - (1 + 1 + 1) / 6)


def test_a_cool_change_over_a_third_of_the_image_is_learned_and_nan_pixels_are_ignored():
    background = WarmBackground(PeopleConfig(background_time_s=1.0))
    image = np.full((60, 80), 8000.0)
    background.update(image, 0.0)
    changed = image.copy()
    changed[40:, :] += 60                         # a third of the image, below the margin
    changed[0, :3] = np.nan                       # a float image with holes
    for t in np.arange(0.1, 6.0, 0.1):
        warm = background.update(changed, t)
    assert not warm.any()
    assert np.isfinite(background.background).all()
    assert np.allclose(background.background[40:], 8060.0, atol=5.0)


def test_where_a_person_is_published_the_background_does_not_absorb_them():
    config = PeopleConfig(absorb_time_s=2.0)
    person = np.zeros((60, 80), dtype=bool)
    person[20:45, 30:38] = True
    image = np.full((60, 80), 8000.0) + 300 * person
    free, guarded = WarmBackground(config), WarmBackground(config)
    for t in np.arange(0.0, 20.0, 0.115):
        warm_free = free.update(image, t)
        warm_guarded = guarded.update(image, t, protect=person)
    assert warm_guarded[person].all()
    assert not warm_free[person].any()            # absorbed after many absorb_time_s


def test_noise_that_never_becomes_a_track_uses_no_id():
    tracker = PeopleTracker()
    for index, t in enumerate(np.arange(0.0, 3.0, 0.115)):
        # One false detection per pair, each far from every other (never two hits).
        noise = [Detection(10.0 + 3.0 * index, 6.0, 1.5, 10, 0.5, np.eye(2) * 1e-3)]
        assert tracker.update(noise, t) == []
    person = walk((0.0, 3.0), (0.5, 0.0), np.arange(3.0, 4.0, 0.115))
    for t, detection in zip(np.arange(3.0, 4.0, 0.115), person):
        tracks = tracker.update([detection], t)
    assert [track.track_id for track in tracks] == [1]


def test_points_kilometres_away_are_not_used():
    person = person_points(0.0, 3.0, seed=6)
    points = np.vstack([person, [[0.0, 4000.0, 1.5]]])
    detections = detect_people(points, CAMERA)
    assert len(detections) == 1
    assert detections[0].points == np.count_nonzero(person[:, 2] >= 0.6)
    assert len(person) not in detections[0].members


def test_point_cloud_fields_name_what_they_cannot_read():
    cloud = detections_cloud(Header(), _tracks())
    cloud.row_step = 3
    with pytest.raises(ValueError, match='row_step: expected >= width x point_step'):
        point_cloud_fields(cloud, ('x',))
    cloud = detections_cloud(Header(), _tracks())
    cloud.fields[0].count = 3
    with pytest.raises(ValueError, match='field x: count 3, expected 1'):
        point_cloud_fields(cloud, ('x',))


def test_people_parameters_from_the_command_line_are_typed_and_checked():
    from st_stereo.core.people import people_config_from_assignments
    config = people_config_from_assignments(['min_hits=3', 'gate_m=1', 'require_warm=false'])
    assert (config.min_hits, config.gate_m, config.require_warm) == (3, 1.0, False)
    with pytest.raises(ValueError, match="--people: expected NAME=VALUE.*got 'radius=1'"):
        people_config_from_assignments(['radius=1'])
    with pytest.raises(ValueError, match="--people min_hits: expected a int, got '2.5'"):
        people_config_from_assignments(['min_hits=2.5'])


def test_a_track_is_not_confirmed_by_where_it_is_predicted_to_go():
    tracker = PeopleTracker()
    cut = [Detection(0.4 * i, 4.5, 0.95, 20, 1.0, np.eye(2) * 1e-3, head_visible=False,
                     cut_top=True) for i in range(3)]        # 0.8 m, then nothing
    for t, detection in zip((0.0, 0.115, 0.23), cut):
        assert tracker.update([detection], t) == []
    for t in np.arange(0.345, 1.4, 0.115):                  # coasting on at 3.5 m/s
        assert tracker.update([], t) == []
    assert tracker.counts['started'] == 0 and tracker.next_id == 1


def test_a_far_person_cut_by_the_top_edge_is_found_in_rendered_frames_from_the_second_pair():
    from st_stereo.sim.sequences import load_textures
    from st_stereo.tools.eval_people import evaluate_sequence
    # sit_down starts with its person 4.6 m away, the head above the image, a warm screen
    # cut by the top edge too (the simulator renders both cameras, ST matches them).
    spec, textures = standard_sequences()['sit_down'], load_textures()
    found = evaluate_sequence(spec, textures=textures, max_pairs=10)
    assert found.truths == 10
    assert found.hits >= 8 and found.estimates == found.hits
    without_legs = evaluate_sequence(spec, textures=textures, max_pairs=10,
                                     people_config=PeopleConfig(legs_min_fraction=0.0))
    # It must walk first (min_travel_m, or steady_walk_m in 5 detections within 1 s: its
    # detections, walking in at 0.5 m/s, are not that steady in these pairs).
    assert without_legs.estimates == 0


def test_eval_people_places_people_with_the_rig_pose_it_is_given():
    import dataclasses

    from st_stereo.sim.sequences import load_textures
    from st_stereo.tools.eval_people import evaluate_sequence
    # A rig pose turned 20 deg about the vertical (a wrong yaw) leaves the detections as they
    # are but moves each one 0.35 x its horizontal range: none stays within 0.5 m of its truth.
    spec, textures = standard_sequences()['two_people'], load_textures()
    truth = evaluate_sequence(spec, textures=textures, max_pairs=6)
    turned = dataclasses.replace(spec.rig.rig_pose(), yaw_deg=spec.rig.rig_pose().yaw_deg + 20)
    wrong = evaluate_sequence(spec, textures=textures, max_pairs=6, rig_pose=turned)
    assert truth.hits >= 8 and wrong.estimates == truth.estimates
    assert wrong.hits == 0
    # What the tracker did is reported with the scores (the node's diagnostics' counts).
    from st_stereo.tools.eval_people import markdown_tracker
    row = truth.row()
    assert row['tracks_started'] == truth.tracker_counts['started'] >= 1
    assert row['legs_lapsed'] == 0
    assert row['held_beside'] == truth.tracker_counts['held_beside']
    table = markdown_tracker({'two_people': row})
    assert f'| two_people | {row["tracks_started"]} | 0 | ' in table


def test_the_silhouettes_short_median_is_numpys_bit_for_bit():
    from st_stereo.core.people import _median
    rng = np.random.default_rng(3)
    for count in range(1, 30):
        values = rng.normal(4.5, 0.3, count)
        assert _median(values) == float(np.median(values))


def test_a_head_without_matches_in_one_pair_does_not_pull_the_height_down():
    # Would catch (the recording, 2026-12-06): a walker whose one whole detection had its
    # points' top on the shoulders (1.36 m for a head at 1.62 m) and whose next 36 were cut
    # by the image's edge kept 1.36 m for all of them.
    def seen(head, whole=True):
        return Detection(0.0, 3.0, head, 60, 1.0, np.eye(2) * 1e-3, head_visible=whole)
    tracker = PeopleTracker()
    heights = [1.61, 1.62, 1.55, 1.60, 1.36]
    for index, head in enumerate(heights):
        tracks = tracker.update([seen(head)], 0.115 * index)
    assert tracks[0].head_height == pytest.approx(1.60)       # median of the last five
    # Cut by the edge: the points' top is a lower bound (head_visible 0 while it raises the
    # height), held for five pairs, then lapsed: back to the whole detections' median.
    t = 0.115 * len(heights)
    published = []
    for k, head in enumerate((1.64, 1.10, 1.10, 1.10, 1.10, 1.10)):
        track = tracker.update([seen(head, whole=False)], t + 0.115 * k)[0]
        published.append((track.head_height, track.head_visible))
    assert published == [(pytest.approx(1.64), False)] * 5 + [(pytest.approx(1.60), True)]
    t += 0.115 * 4
    # Sitting down is followed within three pairs (whole again, the lower bound goes).
    for k in range(2):
        tracks = tracker.update([seen(1.10)], t + 0.115 * (2 + k))
    assert tracks[0].head_height == pytest.approx(1.36)
    tracks = tracker.update([seen(1.10)], t + 0.115 * 4)
    assert tracks[0].head_height == pytest.approx(1.10)
    # head_height_pairs 1: the last whole one.
    tracker = PeopleTracker(PeopleConfig(head_height_pairs=1))
    for index, head in enumerate((1.6, 1.36)):
        tracks = tracker.update([seen(head)], 0.115 * index)
    assert tracks[0].head_height == pytest.approx(1.36)
    # A track never seen whole: the highest bound of its last head_height_pairs detections.
    tracker = PeopleTracker(PeopleConfig(min_travel_m=0.0, head_height_pairs=2))
    heights = []
    for index, head in enumerate((1.2, 0.9, 0.8)):
        heights += [t.head_height for t in tracker.update([seen(head, whole=False)],
                                                          0.115 * index)]
    assert heights == [pytest.approx(1.2), pytest.approx(0.9)]
    with pytest.raises(ValueError, match='head_height_pairs'):
        PeopleConfig(head_height_pairs=0)


def test_a_whole_body_warm_up_to_the_top_row_above_its_points_keeps_its_height():
    # Would catch (far_standing, 2026-12-06): a walker whose head is in the image's top three
    # rows, its matches ending 10-12 rows below, counted as seen whole with its points' top
    # (1.1 m) as the head height of a head at 1.62 m.
    warm = np.zeros((60, 80), dtype=bool)
    warm[0:40, 30:38] = True                     # the head in the top rows, the body below
    warm[0:6, 30:32] = False                     # the head narrower than the shoulders
    points = np.array([[31.0, 14.0], [36.0, 15.0], [33.0, 30.0], [34.0, 38.0]])
    assert warm_column_reaches_top(warm, points)
    lower = warm.copy()
    lower[0:6, :] = False                        # the head's top in view: cool rows above
    assert not warm_column_reaches_top(lower, points)
    beside = lower.copy()
    beside[0:10, 45:55] = True                   # warm up to the top beside it: not its own
    assert not warm_column_reaches_top(beside, points)
    screen = lower.copy()
    screen[0:10, 20:50] = True                   # a wide warm screen behind, above the head
    assert not warm_column_reaches_top(screen, points)
    scattered = lower.copy()
    scattered[np.arange(10), 30 + 7 * (np.arange(10) % 2)] = True    # not connected
    assert not warm_column_reaches_top(scattered, points)
    assert not warm_column_reaches_top(warm, np.zeros((0, 2)))
    # In the tracker such a detection is a lower bound, for its own pair only.

    def seen(head, above=False, whole=True):
        return Detection(0.0, 3.0, head, 60, 1.0, np.eye(2) * 1e-3, head_visible=whole,
                         head_above=above)
    tracker = PeopleTracker()
    sequence = ((1.62, False), (1.60, False), (1.10, True), (1.12, True), (1.95, True)) + \
        ((1.15, True),) * 5
    published = []
    for index, (head, above) in enumerate(sequence):
        tracks = tracker.update([seen(head, above)], 0.115 * index)
        published.append((tracks[0].head_height, tracks[0].head_visible) if tracks else None)
    # Below the whole median the bounds change nothing; 1.95 (two bodies merged, say) holds
    # for five pairs, published as a bound (head_visible 0), then lapses.
    assert published[2:] == [(pytest.approx(1.61), True)] * 2 + \
        [(pytest.approx(1.95), False)] * 5 + [(pytest.approx(1.61), True)]
    # A track started on a lower bound publishes it as one until it is seen whole.
    tracker = PeopleTracker(PeopleConfig(min_travel_m=0.0))
    for index, head in enumerate((1.1, 1.2)):
        tracks = tracker.update([seen(head, above=True)], 0.115 * index)
    assert (tracks[0].head_height, tracks[0].head_visible) == (pytest.approx(1.2), False)
    tracks = tracker.update([seen(1.55)], 0.23)
    assert (tracks[0].head_height, tracks[0].head_visible) == (pytest.approx(1.55), True)


def test_the_estimator_marks_a_body_whose_head_is_in_the_top_rows_without_matches():
    # The wiring of warm_column_reaches_top: a body 1.75 m tall at 3.4 m (the top edge
    # crosses it at 1.65 m) matched only 12 rows and more below the top, as far_standing's
    # walker was; and one 1.3 m tall (cool rows above it), which is not marked.
    rig, transform, intrinsics = _rig_geometry()
    marked = {}
    for name, top in (('head in the top rows', 1.75), ('wholly in view', 1.3)):
        warm, points, pixels = _painted(rig, _box(0.2, 0.6, 3.4, 0.0, top, nx=30, nz=60))
        found = pixels[:, 1] >= 12.0
        image = np.full((60, 80), 8000.0)
        image[warm] += 400.0
        estimator = PeopleEstimator(transform, PeopleConfig(min_head_height_m=0.9))
        for k in range(3):
            frame = estimator.process(0.115 * k, points[found], pixels[found, 0],
                                      pixels[found, 1], 0.1 * 84.0 / points[found, 2],
                                      left_image=image, intrinsics=intrinsics)
        assert len(frame.detections) == 1 and frame.detections[0].head_visible, name
        marked[name] = (frame.detections[0].head_above,
                        estimator.counts['head_above_detections'])
    assert marked == {'head in the top rows': (True, 3), 'wholly in view': (False, 0)}


def _track(track_id, x, y, height=1.7):
    return types.SimpleNamespace(position=np.array([x, y]), head_height=height,
                                 track_id=track_id, depth_spread_m=0.2)


def test_a_track_kept_on_a_person_hidden_in_view_is_not_scored_and_others_are_false():
    # Person 0 stands in view; person 1 is visible for two pairs (track 2 its hit), then
    # hidden behind another. Track 2 kept on them is neither a hit nor a false person while
    # the occlusion is short; a ghost born there (track 5), a track 0.6 m off (track 6) and
    # one on nobody (track 3) are false; after SHORT_OCCLUSION_PAIRS so is track 2.
    from st_stereo.tools.eval_people import PeopleTally, SHORT_OCCLUSION_PAIRS
    tally = PeopleTally()
    seen, hidden = (0.0, 3.0, 1.7), (0.7, 3.1, 1.6)
    for _ in range(2):
        tally.add([0, 1], np.array([seen, hidden]), [_track(1, 0.05, 3.0), _track(2, 0.7, 3.2)])
    # The excused track first in the list: the hits' indices must follow the removal.
    tally.add([0], np.array([seen]), [_track(2, 0.75, 3.1, 1.2), _track(1, 0.05, 3.0, 1.5)],
              None, [1], np.array([hidden]))
    assert (tally.on_hidden, tally.hits, tally.estimates) == (1, 5, 5)
    assert tally.horizontal[-1] == pytest.approx(0.05) and tally.height[-1] == pytest.approx(0.2)
    for ghost in (_track(5, 0.7, 3.1), _track(6, 0.7, 3.7), _track(3, 3.0, 1.0)):
        tally.add([0], np.array([seen]), [_track(1, 0.05, 3.0), ghost], None, [1],
                  np.array([hidden]))
    assert (tally.on_hidden, tally.estimates) == (1, 11)
    # Track 2 last hit person 1 in pair 1: it is excused up to pair 1 + SHORT_OCCLUSION_PAIRS.
    later = SHORT_OCCLUSION_PAIRS - 2               # pairs 6 on: the last two come too late
    for _ in range(later):
        tally.add([0], np.array([seen]), [_track(1, 0.05, 3.0), _track(2, 0.7, 3.1)], None,
                  [1], np.array([hidden]))
    row = tally.row()
    excused, false = 1 + (later - 2), 3 + 2
    hits = 2 * 2 + 1 + 3 + later
    assert (row['on_hidden'], tally.hits, row['estimates']) == (excused, hits, hits + false)
    assert row['precision'] == pytest.approx(hits / (hits + false))
    assert row['precision_strict'] == pytest.approx(hits / (hits + false + excused))
    assert row['mota'] == pytest.approx(1 - false / hits)
    assert row['mota_strict'] < row['mota'] and row['id_switches'] == 0
    # A track near a visible person is that person's hit, even near a hidden one too.
    tally = PeopleTally()
    tally.add([0], np.array([seen]), [_track(1, 0.3, 3.0)], None, [1],
              np.array([(0.5, 3.0, 1.6)]))
    assert tally.hits == 1 and tally.on_hidden == 0


def test_a_person_hidden_in_view_is_one_behind_another_not_one_gone_out_at_a_side():
    from st_stereo.tools.eval_people import hidden_in_view
    model = types.SimpleNamespace(fx=80.0, fy=80.0, cx=39.5, cy=29.5)
    heads = np.array([(0.0, -1.0, 3.0), (0.3, -1.0, 3.0), (2.0, -1.0, 3.0), (0.0, 0.0, -1.0)])
    visible = np.array([True, False, False, False])
    np.testing.assert_array_equal(hidden_in_view(visible, heads, model, 80),
                                  [False, True, False, False])


def test_the_scoring_of_a_pair_passes_the_people_hidden_in_view_to_the_tally():
    # PeopleScoring.pair's wiring, with stand-ins for ST and the people stage. All three are
    # seen in the first pair; in the second, person 1 is hidden behind person 0 (10 pixels,
    # head in the image) and person 2 has walked out at the side (head beyond the image's
    # columns): the track kept on person 1 is excused, the one kept on person 2 is false.
    from st_stereo.sim.sequences import PERSON_LABEL_BASE
    from st_stereo.tools.eval_people import PeopleScoring, PeopleTally
    model = types.SimpleNamespace(fx=80.0, fy=80.0, cx=39.5, cy=29.5, baseline=0.55,
                                  disparity_offset=0.0)
    scoring = PeopleScoring.__new__(PeopleScoring)
    scoring.rectifier = types.SimpleNamespace(model=model,
                                              rectify=lambda a, b: (np.zeros((60, 80)), b))
    empty = types.SimpleNamespace(points=np.zeros((0, 3)), x_point=np.zeros(0),
                                  y_point=np.zeros(0), x_left=np.zeros(0), y=np.zeros(0),
                                  disparity=np.zeros(0),
                                  confidence=np.zeros(0))
    scoring.matching = types.SimpleNamespace(match=lambda *args: empty)
    tracks = [_track(1, 0.0, 3.0), _track(2, 0.7, 3.1), _track(3, 1.3, 3.0)]
    scoring.estimator = types.SimpleNamespace(
        process=lambda *args, **kwargs: types.SimpleNamespace(tracks=tracks),
        tracker=types.SimpleNamespace(counts={'started': 3}))
    scoring.tally = PeopleTally()
    world = [(0.0, 3.0, 1.7), (0.7, 3.1, 1.6), (1.3, 3.0, 1.7)]
    for columns, person2_x in ((6, 1.0), (1, 2.0)):
        labels = np.zeros((60, 80), dtype=np.int32)
        labels[20:30, 30:36] = PERSON_LABEL_BASE
        labels[40:50, 50:50 + columns] = PERSON_LABEL_BASE + 1
        if columns == 6:
            labels[40:50, 70:76] = PERSON_LABEL_BASE + 2
        rectified = [(0.0, -0.5, 3.0), (0.5, -0.5, 3.0), (person2_x, -0.5, 3.0)]
        scoring.pair(None, None, 0.0, 0.03, labels, world, rectified)
    row = scoring.tally.row()
    assert (row['on_hidden'], scoring.tally.hits, row['estimates']) == (1, 4, 5)


@pytest.mark.parametrize('missed_pairs', [0, 1, 2])
def test_a_person_missed_beside_a_warm_screen_s_silhouette_does_not_stay_on_it(missed_pairs):
    # A published person walks away from a warm screen at (1.2, 4.6) whose silhouette (no
    # points of its own) shows again as they leave. Seen every pair, the track follows the
    # person; missed for a pair or two, the track may take the screen, but not for longer
    # than the lapse (legs_lapse_s, 5 s): the screen's track is withdrawn, the person
    # published under a new id.
    tracker = PeopleTracker(PeopleConfig())
    screen = Detection(1.2, 4.6, 1.1, 0, 0.9, np.eye(2) * 1e-3, head_visible=False,
                       cut_top=True, silhouette=True)
    on_screen = []
    for index, t in enumerate(np.arange(0.0, 10.0, 0.115)):
        x = 0.8 + 0.1 * max(0, index - 20)          # stands beside it, then walks away
        person = Detection(min(x, 2.5), 4.0, 1.7, 60, 1.0, np.eye(2) * 1e-3)
        seen = [] if 21 <= index < 21 + missed_pairs else [person]
        tracks = tracker.update(seen + ([screen] if index >= 21 else []), t)
        on_screen.append(any(math.hypot(track.state[0] - 1.2, track.state[1] - 4.6) < 0.3
                             for track in tracks))
    assert any(track.state[0] > 2.3 for track in tracks)     # the person, published
    assert not any(on_screen[-20:])
    assert sum(on_screen) * 0.115 <= tracker.config.legs_lapse_s + 1.0
    if not missed_pairs:
        assert not any(on_screen)
        assert tracker.counts['shape_lapsed'] == 0


@pytest.mark.parametrize('speed', [0.3, 0.6, 1.2])
def test_a_far_walker_on_silhouettes_alone_keeps_its_id(speed):
    # Published from its whole detections near the rig, then far off on silhouettes only for
    # 20 s, walking back and forth: never withdrawn (it does not stand still).
    tracker = PeopleTracker(PeopleConfig())
    ids = set()
    x = 0.0
    direction = 1.0
    for index, t in enumerate(np.arange(0.0, 22.0, 0.115)):
        if index < 10:
            detection = Detection(0.0, 2.5 + 0.2 * index, 1.7, 80, 1.0, np.eye(2) * 1e-3)
        else:
            x += direction * speed * 0.115
            if abs(x) > 1.5:
                direction = -direction
            detection = Detection(x, 4.5, 1.1, 0, 0.9, np.eye(2) * 1e-3, head_visible=False,
                                  cut_top=True, silhouette=True)
        ids.update(track.track_id for track in tracker.update([detection], t))
    assert ids == {1}
    assert tracker.counts['shape_lapsed'] == 0


def test_the_pixels_of_a_published_silhouette_are_kept_from_the_background():
    shape = np.flatnonzero(np.pad(np.ones((5, 3), bool), ((0, 55), (40, 37))))
    detection = Detection(0.0, 4.6, 1.1, 0, 0.9, np.eye(2) * 1e-3, head_visible=False,
                          cut_top=True, members=np.array([], dtype=int), silhouette=True,
                          shape_pixels=shape)
    track = types.SimpleNamespace(updated=True, detection=detection)
    hold = PeopleEstimator._shape_pixels([track], (60, 80))
    assert hold.reshape(-1)[shape].all() and hold.sum() == len(shape)
    track.updated = False
    assert not PeopleEstimator._shape_pixels([track], (60, 80)).any()
    # Held pixels are not learned, warm or not (a silhouette is mostly under the margin).
    background = WarmBackground(PeopleConfig())
    room = np.full((60, 80), 8000.0)
    background.update(room, 0.0)
    body = room.copy()
    body.reshape(-1)[shape] += 60.0                 # under warm_margin_counts (100)
    for k in range(1, 40):
        background.update(body, 0.115 * k, hold=hold)
    assert np.allclose(background.background.reshape(-1)[shape], 8000.0)
    for k in range(40, 80):
        background.update(body, 0.115 * k)
    assert (background.background.reshape(-1)[shape] > 8020.0).all()     # learned
