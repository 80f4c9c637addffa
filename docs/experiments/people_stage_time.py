"""
What the people stage's first-detection, legs-only, warm-object and silhouette mechanisms cost.

Every pair of three tuning sequences goes through the matcher as ``st-stereo eval people``
does (each camera at its own instant, the skew corrected); the matcher's outputs are kept,
then ``PeopleEstimator.process`` alone is timed on them with the first two mechanisms off,
``confirm_on_legs`` only, the defaults without the warm-object rule (``object_min_hits`` 0),
the defaults without the silhouette's shift (``centre_on_silhouette`` false) and the
defaults, one after the other in one process (a second round is reported, the first
warms the caches). One core, prints a Markdown table.
Run: ``.venv/bin/python docs/experiments/people_stage_time.py``.
"""

import time

import numpy as np
from st_stereo.core.people import PeopleConfig, PeopleEstimator, world_from_rectified
from st_stereo.core.rectification import StereoRectifier
from st_stereo.sim.sequences import SequenceRenderer, standard_sequences
from st_stereo.tools.eval_points import PairMatching

SEQUENCES = ('two_people', 'far_standing', 'far_walker')
CONFIGURATIONS = {
    'both off': PeopleConfig(confirm_on_legs=False, far_legs_min_height_m=0.0),
    'confirm_on_legs only': PeopleConfig(far_legs_min_height_m=0.0),
    'defaults but object_min_hits 0': PeopleConfig(object_min_hits=0),
    'defaults but centre_on_silhouette false': PeopleConfig(centre_on_silhouette=False),
    'defaults': PeopleConfig(),
}


def matched_pairs(name):
    """Return the sequence's world transform and, per pair, what ``process`` is given."""
    spec = standard_sequences()[name]
    renderer = SequenceRenderer(spec)
    rectifier = StereoRectifier(*spec.rig.calibrations())
    matching = PairMatching(rectifier)
    model = rectifier.model
    intrinsics = (model.fx, model.fy, model.cx, model.cy)
    pairs = []
    for t_left, t_right in spec.pair_times():
        frame = renderer.frame(t_left, right_t=t_right)
        result = matching.match(frame['left'], frame['right'], t_left, t_right - t_left)
        left = rectifier.rectify(frame['left'], frame['left'])[0]
        pairs.append((t_left, result.points, result.x_point, result.y_point, result.disparity,
                      result.confidence, left, intrinsics))
    transform = world_from_rectified(spec.rig.rig_pose(),
                                     spec.rig.calibrations()[0].rectification)
    return transform, pairs


def main():
    """Print the table."""
    inputs = {name: matched_pairs(name) for name in SEQUENCES}
    print('| sequence | configuration | median ms | p95 ms |')
    print('|---|---|---:|---:|')
    for round_ in range(2):
        for name, (transform, pairs) in inputs.items():
            for label, config in CONFIGURATIONS.items():
                estimator = PeopleEstimator(transform, config)
                times = []
                for stamp, points, x, y, disparity, confidence, left, intrinsics in pairs:
                    start = time.perf_counter()
                    estimator.process(stamp, points, x, y, disparity, confidence, left,
                                      intrinsics=intrinsics)
                    times.append(1e3 * (time.perf_counter() - start))
                if round_:
                    print(f'| {name} | {label} | {np.median(times):.2f} | '
                          f'{np.percentile(times, 95):.2f} |')


if __name__ == '__main__':
    main()
