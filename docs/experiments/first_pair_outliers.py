"""
How much of a sequence's 3-D outliers its first scored pair holds.

The first pair has no pair before it (as the matcher node's first pair after its start or a
gap), so its moving features are not skew-corrected. ``st-stereo eval points``'s scoring of
one sequence (every 4th pair, each camera at its own instant), its tally split per frame:
all frames, the first alone, from the second on; outliers over all points and on people.
Run: ``.venv/bin/python docs/experiments/first_pair_outliers.py walk_across [NAME=VALUE ...]``
(ST parameters, as ``--set``).
"""

import sys

import numpy as np
from st_stereo.core.config import config_from_assignments
from st_stereo.sim.scoring import OUTLIER_M, PERSON_LABEL_BASE
from st_stereo.sim.sequences import load_textures, standard_sequences
from st_stereo.tools.eval_points import evaluate_sequence


def outliers(tally, frames):
    """Return the points, 3-D outlier share, people points, people outlier share of frames."""
    label = np.concatenate([tally.columns['label'][f] for f in frames])
    distance = np.concatenate([tally.columns['distance_3d'][f] for f in frames])
    people = label >= PERSON_LABEL_BASE
    return (len(label), float(np.mean(distance > OUTLIER_M)), int(people.sum()),
            float(np.mean(distance[people] > OUTLIER_M)))


def main(name, assignments):
    """Print the Markdown table of one sequence."""
    config = config_from_assignments(assignments) if assignments else None
    tally, _, _ = evaluate_sequence(standard_sequences()[name], config, 4, load_textures())
    print(f'{name} {" ".join(assignments) or "(defaults)"}, {tally.frames} frames scored\n')
    print('| frames | points | outliers 3-D | people points | on people |')
    print('|---|---:|---:|---:|---:|')
    for title, frames in (('all', range(tally.frames)), ('the first', [0]),
                          ('from the second', range(1, tally.frames))):
        points, share, people, people_share = outliers(tally, frames)
        print(f'| {title} | {points} | {100 * share:.2f} % | {people} | '
              f'{100 * people_share:.2f} % |')


if __name__ == '__main__':
    main(sys.argv[1], sys.argv[2:])
