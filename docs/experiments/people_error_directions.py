"""
Which way the people stage's position errors point: along the view (depth) or across it.

Each named sequence goes through ``st-stereo eval people``'s path (``evaluate_sequence``,
each camera at its own instant, the skew corrected, the rig's true pose); every hit's error
(published position less the true head centre, on the floor) is split into its component
along the horizontal viewing direction from the left camera ("radial", positive: farther
than the truth) and across it ("lateral"). Per person: the medians while it walks (the
truth moved more than 0.3 m/s since the pair before) and while it stands, the standing
ones' median absolute lateral error and their median horizontal distance from the camera.
Run: ``.venv/bin/python docs/experiments/people_error_directions.py [--no-silhouette]
[SEQUENCE ...]`` (default: the tuning sequences; ``--no-silhouette``: with
``centre_on_silhouette`` false, the points' positions published).
"""

import sys

import numpy as np
from st_stereo.core.people import camera_centre_in_world, PeopleConfig, world_from_rectified
from st_stereo.sim.sequences import load_textures, standard_sequences
from st_stereo.tools import eval_people


def error_rows(name, textures, specs, config=None):
    """Return one row per hit: person, range, radial, lateral, truth speed (m/s)."""
    spec = specs[name]
    tally = eval_people.evaluate_sequence(spec, people_config=config, textures=textures)
    transform = world_from_rectified(spec.rig.rig_pose(),
                                     spec.rig.calibrations()[0].rectification)
    centre = camera_centre_in_world(transform)[:2]
    rows, previous = [], {}
    for truth_ids, truth_xy, _, track_xy in tally.frames:
        for r, c, _ in eval_people.pair_estimates(truth_xy, track_xy):
            away = truth_xy[r] - centre
            distance = float(np.hypot(*away))
            away /= distance
            error = track_xy[c] - truth_xy[r]
            step = truth_xy[r] - previous.get(truth_ids[r], truth_xy[r])
            rows.append((truth_ids[r], distance, error @ away,
                         error @ np.array([-away[1], away[0]]), np.hypot(*step) / 0.115))
        previous = dict(zip(truth_ids, truth_xy))
    return np.array(rows).reshape(-1, 5)


def main(names, config=None):
    """Print one Markdown table over the sequences."""
    textures, specs = load_textures(), standard_sequences()
    print('| sequence | person | hits | walking: radial / lateral median (m) | standing: '
          'hits | radial / lateral median (m) | abs lateral median (m) | distance (m) |')
    print('|---|---:|---:|---|---:|---|---:|---:|')
    for name in names:
        rows = error_rows(name, textures, specs, config)
        for person in np.unique(rows[:, 0]):
            mine = rows[rows[:, 0] == person]
            walking, standing = mine[mine[:, 4] > 0.3], mine[mine[:, 4] <= 0.3]

            def medians(part):
                if not len(part):
                    return '-'
                return f'{np.median(part[:, 2]):+.3f} / {np.median(part[:, 3]):+.3f}'
            still = f'{np.median(np.abs(standing[:, 3])):.3f}' if len(standing) else '-'
            print(f'| {name} | {int(person)} | {len(mine)} | {medians(walking)} | '
                  f'{len(standing)} | {medians(standing)} | {still} | '
                  f'{np.median(mine[:, 1]):.2f} |')


if __name__ == '__main__':
    arguments = sys.argv[1:]
    off = '--no-silhouette' in arguments
    names = [a for a in arguments if a != '--no-silhouette']
    main(names or eval_people.TUNING_SEQUENCES,
         PeopleConfig(centre_on_silhouette=False) if off else None)
