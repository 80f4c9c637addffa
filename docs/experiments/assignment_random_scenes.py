"""
The tracker's assignment on random scripted scenes: the cost of leaving a track out.

``PeopleTracker`` runs on detections scripted from random scenes (no images, no matcher):
two or three people in a 3 x 2.5 m patch 2.5-5 m from the rig, standing or walking at
0.6-1.6 m/s, each changing course or stopping (or starting) once, hidden up to twice for
0.2-1.3 s, detections with 2-8 cm of noise, missed at random (0, 5 or 10 % of pairs), people
closer than 0.45 m merged into one detection, a ghost detection 0.3-0.9 m from a person
in 0, 5 or 15 % of the pairs; 40 pairs of 0.115 s each. Each scene runs under each
assignment: ``old`` (infeasible pairs at a large finite cost: the solver first maximises the
number of pairs) and ``gated_assignment`` with ``miss_cost`` 1.6 m (the tracker's, twice
``gate_m``), 2.0, 2.4 and 3.2 m. Scored per pair: truths paired with the published tracks
within 0.5 m (``linear_sum_assignment``); an id switch when a person's track id differs from
its last one; a miss when a person has none; a false track when a published track has no
person. Prints one Markdown table (totals over the scenes).
Run: ``.venv/bin/python docs/experiments/assignment_random_scenes.py [SEED [SCENES]]``
(default seed 1, 1000 scenes; about 2 min).
"""

import math
import sys

import numpy as np
from scipy.optimize import linear_sum_assignment
import st_stereo.core.people as people

PERIOD_S = 0.115
PAIRS = 40
MATCH_M = 0.5
MISS_COSTS = (1.6, 2.0, 2.4, 3.2)
GATED_ASSIGNMENT = people.gated_assignment      # before ``score`` swaps it


def old_assignment(distance, gate, miss_cost):
    """Return the pairs of the assignment before 2026-12-07 (``miss_cost`` unused)."""
    distance = np.asarray(distance, dtype=np.float64)
    gate = np.asarray(gate, dtype=np.float64).reshape(-1)
    if not distance.size:
        return []
    cost = np.where(distance <= gate[:, None], distance, 1e6)
    return [(int(row), int(col)) for row, col in zip(*linear_sum_assignment(cost))
            if distance[row, col] <= gate[row]]


def with_miss_cost(miss_cost):
    """Return ``gated_assignment`` with a fixed ``miss_cost`` (at least every gate)."""
    def assignment(distance, gate, _):
        return GATED_ASSIGNMENT(distance, gate, max(miss_cost, float(np.max(gate, initial=0.0))))
    return assignment


def detection(x, y, head_height=1.7):
    """Return a whole detection, its head in view, at a floor position."""
    return people.Detection(float(x), float(y), head_height, 100, 1.0, np.eye(2) * 1e-3)


def random_scene(rng):
    """Return ``[(t, {person: (x, y)}, [Detection])]`` of one random scene (docstring)."""
    walkers = []
    for _ in range(int(rng.integers(2, 4))):
        start = rng.uniform([-1.5, 2.5], [1.5, 5.0])
        velocities = []
        for _ in range(2):
            speed = rng.choice([0.0, rng.uniform(0.6, 1.6)])
            heading = rng.uniform(0.0, 2.0 * math.pi)
            velocities.append(speed * np.array([math.cos(heading), math.sin(heading)]))
        hidden = [(begin, begin + rng.uniform(0.2, 1.3))
                  for begin in rng.uniform(0.3, 3.5, int(rng.integers(0, 3)))]
        walkers.append((start, velocities, rng.uniform(0.5, 3.5), hidden))
    noise = rng.uniform(0.02, 0.08)
    ghost_rate = rng.choice([0.0, 0.05, 0.15])
    miss_rate = rng.choice([0.0, 0.05, 0.1])
    frames = []
    for index in range(PAIRS):
        t = index * PERIOD_S
        truth = {person: tuple(start + first * min(t, change) + second * max(0.0, t - change))
                 for person, (start, (first, second), change, _) in enumerate(walkers)}
        seen = [person for person, (*_, hidden) in enumerate(walkers)
                if not any(begin <= t < end for begin, end in hidden) and
                rng.random() >= miss_rate]
        detections, merged = [], set()
        for person in seen:
            if person in merged:
                continue
            group = [other for other in seen if other not in merged and
                     math.dist(truth[person], truth[other]) < 0.45]
            merged.update(group)
            xy = np.mean([truth[other] for other in group], axis=0) + rng.normal(0, noise, 2)
            detections.append(detection(*xy))
        if rng.random() < ghost_rate:
            person = int(rng.integers(0, len(walkers)))
            angle, radius = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(0.3, 0.9)
            detections.append(detection(truth[person][0] + radius * math.cos(angle),
                                        truth[person][1] + radius * math.sin(angle),
                                        rng.uniform(1.0, 1.7)))
        rng.shuffle(detections)
        frames.append((t, truth, detections))
    return frames


def score(frames, assignment):
    """Return (id switches, misses, false tracks) of the tracker on one scene."""
    saved = people.gated_assignment
    people.gated_assignment = assignment
    try:
        tracker = people.PeopleTracker()
        last, switches, misses, false = {}, 0, 0, 0
        for t, truth, detections in frames:
            published = tracker.update(detections, t)
            persons = list(truth)
            found = {}
            if persons and published:
                cost = np.array([[math.hypot(truth[p][0] - track.state[0],
                                             truth[p][1] - track.state[1])
                                  for track in published] for p in persons])
                for row, col in zip(*linear_sum_assignment(np.where(cost <= MATCH_M, cost,
                                                                    1e6))):
                    if cost[row, col] <= MATCH_M:
                        found[persons[row]] = published[col].track_id
            for person in persons:
                if person not in found:
                    misses += 1
                    continue
                switches += int(person in last and last[person] != found[person])
                last[person] = found[person]
            false += len(published) - len(found)
        return np.array([switches, misses, false])
    finally:
        people.gated_assignment = saved


def main(seed=1, scenes=1000):
    """Print the totals of every assignment over ``scenes`` random scenes."""
    assignments = {'old (pairs first)': old_assignment,
                   **{f'miss_cost {cost} m': with_miss_cost(cost) for cost in MISS_COSTS}}
    totals = dict.fromkeys(assignments, 0)
    rng = np.random.default_rng(seed)
    for _ in range(scenes):
        frames = random_scene(rng)
        for name, assignment in assignments.items():
            totals[name] = totals[name] + score(frames, assignment)
    print(f'seed {seed}, {scenes} scenes of {PAIRS} pairs\n')
    print('| assignment | id switches | misses | false tracks |')
    print('|---|---:|---:|---:|')
    for name, (switches, misses, false) in totals.items():
        print(f'| {name} | {switches} | {misses} | {false} |')


if __name__ == '__main__':
    main(*(int(value) for value in sys.argv[1:3]))
