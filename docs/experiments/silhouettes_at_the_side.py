"""
Silhouettes cut by the image's side: what the search back confirms, right or wrong.

Made images (``eval_subpixel.layered_bodies_pair``: textured bodies 120 counts over a
textured wall, the right camera's gain and offset, 3 counts of noise), the rig's
disparities (``fx B`` 46.3 px m: far bodies 9-10 px, 4.6-5.1 m; nearer ones 13-16 px,
2.9-3.6 m), 20 rows of the far shape, 3 noise seeds each:

- **cut**: a far body running on past the image's right side, its last ``w`` columns in
  the left image, nothing nearer;
- **hidden**: the same, and a nearer body, 40 rows tall, standing just beyond the left
  image's right side, which hides the far body's columns in the right image (the left
  image does not show it); **hidden, warmer**: that nearer body 300 counts over the wall;
- **left, negative**: a body cut by the left side with a negative disparity (``cx_left -
  cx_right < 0``: the right image sees further on the left).

Each shape's fate as ``people.silhouette_detections`` decides it: at side
(``reaches_the_unseen``: not searched), no disparity (ZNCC under
``silhouette_min_correlation``), not back (``right_to_left_agrees``), kept within 1 px of
the truth, kept wrong. ``--search-all``: the side shapes searched too (what the search and
the search back alone make of them).
Run: ``.venv/bin/python docs/experiments/silhouettes_at_the_side.py``.
"""

import sys

import numpy as np
from st_stereo.core.people import PeopleConfig, reaches_the_unseen
from st_stereo.core.silhouette_stereo import right_to_left_agrees, silhouette_disparity
from st_stereo.tools.eval_subpixel import layered_bodies_pair

SHAPE = (60, 80)
FAR_NEAR = ((9.0, 13.0), (9.5, 14.0), (10.0, 16.0), (9.0, 15.0))
SEEDS = range(3)


def fate(left, right, mask, low, high, truth, min_correlation, search_all=False):
    """Return what becomes of one shape: at_side, no_disparity, not_back, kept, kept_wrong."""
    if not search_all and reaches_the_unseen(mask):
        return 'at_side'
    found, correlation = silhouette_disparity(left, right, mask, low, high, exclude=mask)
    if not correlation >= min_correlation:
        return 'no_disparity'
    if not right_to_left_agrees(left, right, mask, found, low, high, exclude=mask):
        return 'not_back'
    return 'kept' if abs(found - truth) <= 1.0 else 'kept_wrong'


def tally(case, width, config, search_all=False):
    """Fates of the shapes of one case at one visible width, over the grid and the seeds."""
    fates = {}
    for far, near in FAR_NEAR:
        for seed in SEEDS:
            mask = np.zeros(SHAPE, dtype=bool)
            if case == 'left, negative':
                disparity = -far / 3.0
                bodies = [(width - 9, width, 20, 120.0, disparity)]
                left, right = layered_bodies_pair(bodies, disparity - 3.0, seed)
                mask[:20, :width] = True
                low, high, truth = -20.0, 20.0, disparity
            else:
                bodies = [(80 - width, 89 - width, 20, 120.0, far)]
                if case.startswith('hidden'):
                    bodies.append((80, 95, 40, 300.0 if 'warmer' in case else 120.0, near))
                left, right = layered_bodies_pair(bodies, far - 5.0, seed)
                mask[:20, 80 - width:] = True
                low, high, truth = 3.1, 46.3, far
            outcome = fate(left, right, mask, low, high, truth,
                           config.silhouette_min_correlation, search_all)
            fates[outcome] = fates.get(outcome, 0) + 1
    return fates


def main():
    """Print the table: per case and visible width, the shapes' fates."""
    config = PeopleConfig()
    search_all = '--search-all' in sys.argv[1:]
    keys = ('at_side', 'no_disparity', 'not_back', 'kept', 'kept_wrong')
    print('| case | visible columns | shapes | ' + ' | '.join(keys) + ' |')
    print('|---|---:|---:|' + '---:|' * len(keys))
    for case in ('cut', 'hidden', 'hidden, warmer', 'left, negative'):
        for width in (2, 3, 4, 5, 6, 8):
            fates = tally(case, width, config, search_all)
            print(f'| {case} | {width} | {sum(fates.values())} | ' +
                  ' | '.join(str(fates.get(key, 0)) for key in keys) + ' |')


if __name__ == '__main__':
    main()
