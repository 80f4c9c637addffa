"""
How long each published track goes without legs: the evidence for ``legs_lapse_s``.

Every pair of the named sequences (default: the tuning sequences and the bundled recording)
goes through ``st-stereo eval people``'s scoring; after each pair, each track's detection is
looked at: whole (not cut by the top edge, head high enough), standing on legs
(``legs_seen``). For each track that was published, prints whether it was ever seen whole,
how far it went (``farthest_m``), its detections on legs of all its detections, and the
longest stretch between two detections on legs (seconds).
Run: ``.venv/bin/python docs/experiments/legs_stretches.py [sequence ...]``
(``recording`` for the bundled recording).
"""

import sys

from st_stereo.core import people
from st_stereo.package_data import bundled_recording
from st_stereo.sim.sequences import standard_sequences
from st_stereo.tools import eval_people

DEFAULT = ('walk_across', 'two_people', 'sit_down', 'far_standing', 'far_walker', 'recording')


def watch(records):
    """Patch ``PeopleTracker.update`` to keep per-track records in ``records`` (by object)."""
    update = people.PeopleTracker.update

    def recorded(self, detections, stamp_s):
        published = update(self, detections, stamp_s)
        for track in self.tracks:
            record = records.setdefault(id(track), {
                'id': None, 'whole': False, 'legs': 0, 'detections': 0, 'last_legs': None,
                'longest_without': 0.0, 'farthest_m': 0.0})
            if track.updated and track.detection is not None:
                detection = track.detection
                record['detections'] += 1
                record['whole'] |= not detection.cut_top and \
                    detection.head_height >= self.config.min_head_height_m
                if detection.legs_seen:
                    record['legs'] += 1
                    record['last_legs'] = stamp_s
                elif record['last_legs'] is not None:
                    record['longest_without'] = max(record['longest_without'],
                                                    stamp_s - record['last_legs'])
            if track.confirmed and record['id'] is None:
                record['id'] = track.track_id
            record['farthest_m'] = track.farthest_m
        return published
    people.PeopleTracker.update = recorded


def main(names):
    """Print one Markdown table of the published tracks of each named sequence."""
    records = {}
    watch(records)
    print('| sequence | track | seen whole | farthest (m) | detections on legs | longest '
          'stretch without legs (s) |')
    print('|---|---:|---|---:|---:|---:|')
    for name in names:
        records.clear()
        if name == 'recording':
            eval_people.evaluate_recording(bundled_recording())
        else:
            eval_people.evaluate_sequence(standard_sequences()[name])
        for record in sorted((r for r in records.values() if r['id'] is not None),
                             key=lambda r: r['id']):
            print(f'| {name} | {record["id"]} | {"yes" if record["whole"] else "no"} | '
                  f'{record["farthest_m"]:.2f} | {record["legs"]} of '
                  f'{record["detections"]} | {record["longest_without"]:.2f} |', flush=True)


if __name__ == '__main__':
    main(sys.argv[1:] or DEFAULT)
