"""
The silhouettes' disparity on a real thermal frame's people, at a depth of their own.

``people_lab_180x180.png`` (five people in a laboratory, FLIR i60; ../shared/data/thermal)
cropped below the heads (rows 45-179, so the bodies rise out of the top edge as far bodies
do under a ceiling rig) and resized to 80x60; its warm bodies (more than a quarter of the
way from the 20th to the 95th percentile) are moved by a front disparity and the rest by a
back one (``eval_subpixel.make_layered_pair``: 3 counts of noise, the right camera's gain
1.03 and offset +37 counts). The frame is scaled so that its 95th percentile lies
``contrast`` counts above its 20th (the wall): a warm room's far bodies are 35-145 counts
above the wall behind them (docs/people.md). The silhouettes are the people stage's: the
difference to the wall level over ``silhouette_margin_counts`` seeded by
``warm_margin_counts`` (``top_silhouettes``); one that reaches the image's side is not
searched (``people.reaches_the_unseen``), the others are searched
(``silhouette_disparity``, other warm pixels out of the ring) and checked back
(``right_to_left_agrees``) as ``people.silhouette_detections`` does. Front disparities
8.0, 9.4, 10.7, 12.3 px (5.8-3.8 m on the simulated rig), back ones 4.2 and 6.5 px, 5 noise
seeds each.
Run: ``.venv/bin/python docs/experiments/silhouettes_on_a_real_frame.py``.
"""

import numpy as np
from st_stereo.core.image_io import read_thermal_image, resize_area
from st_stereo.core.people import PeopleConfig, reaches_the_unseen
from st_stereo.core.silhouette_stereo import (right_to_left_agrees, silhouette_disparity,
                                              top_silhouettes)
from st_stereo.package_data import shared_thermal_dir
from st_stereo.tools.eval_subpixel import make_layered_pair

FRONT_SHIFTS = (8.0, 9.4, 10.7, 12.3)
BACK_SHIFTS = (4.2, 6.5)
SEEDS = range(5)
WALL_COUNTS = 8000.0
SEARCH = (2.0, 30.0)


def real_bodies(contrast):
    """Return the cropped frame scaled to ``contrast`` counts over the wall, its bodies."""
    frame = read_thermal_image(shared_thermal_dir() / 'people_lab_180x180.png')
    frame = resize_area(np.asarray(frame, dtype=np.float64)[45:180, :], 80, 60)
    wall = np.percentile(frame, 20)
    span = np.percentile(frame, 95) - wall
    return WALL_COUNTS + (frame - wall) * contrast / span, frame - wall > 0.25 * span


def silhouette_errors(contrast, config=None):
    """
    Return one row per silhouette found: ``(columns, error px or nan, fate)``.

    ``fate``: ``at_side``, ``kept``, ``no_disparity`` or ``not_back``, as
    ``silhouette_detections`` counts them.
    """
    config = config or PeopleConfig()
    frame, bodies = real_bodies(contrast)
    rows = []
    for front_shift in FRONT_SHIFTS:
        for back_shift in BACK_SHIFTS:
            for seed in SEEDS:
                left, right = make_layered_pair(frame, bodies, front_shift, back_shift,
                                                np.random.default_rng(seed))
                weak = left - WALL_COUNTS > config.silhouette_margin_counts
                strong = left - WALL_COUNTS > config.warm_margin_counts
                for mask in top_silhouettes(weak, strong):
                    columns = int(mask.any(axis=0).sum())
                    if reaches_the_unseen(mask):
                        rows.append((columns, float('nan'), 'at_side'))
                        continue
                    disparity, correlation = silhouette_disparity(left, right, mask, *SEARCH,
                                                                  exclude=weak)
                    if not correlation >= config.silhouette_min_correlation:
                        rows.append((columns, float('nan'), 'no_disparity'))
                    elif not right_to_left_agrees(left, right, mask, disparity, *SEARCH,
                                                  exclude=weak):
                        rows.append((columns, float('nan'), 'not_back'))
                    else:
                        rows.append((columns, disparity - front_shift, 'kept'))
    return rows


def main():
    """Print the table: per contrast and silhouette width, fates and errors."""
    print('| contrast (counts) | silhouette width | found | at side | no disparity | not back | '
          'kept | median abs error (px) | p90 (px) | max (px) |')
    print('|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|')
    for contrast in (300.0, 150.0, 110.0):
        rows = silhouette_errors(contrast)
        for label, low, high in (('2-3 columns', 2, 3), ('4+ columns', 4, 10 ** 6)):
            chosen = [r for r in rows if low <= r[0] <= high]
            errors = np.abs([r[1] for r in chosen if r[2] == 'kept'])
            fates = [r[2] for r in chosen]
            stats = ' | '.join(f'{np.percentile(errors, q):.3f}' if len(errors) else '-'
                               for q in (50, 90, 100))
            print(f'| {contrast:.0f} | {label} | {len(chosen)} | {fates.count("at_side")} | '
                  f'{fates.count("no_disparity")} | {fates.count("not_back")} | '
                  f'{len(errors)} | {stats} |')


if __name__ == '__main__':
    main()
