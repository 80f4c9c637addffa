"""
Where does the disparity bias on people come from? (issue 12: median abs dZ/Z on people).

``st-stereo eval points`` measures a median signed disparity error of -0.12 to -0.18 px on
people even when they stand still (docs/results.md, the skew tables): a person comes out a few
centimetres too far. This script renders a tuning sequence (the same frames whatever the
options: every 6th pair, 10 pairs), matches it with ST and prints the median signed error of
the matches on people against the truth of their own pixel, by the match's distance to the
person's silhouette, and against three other references over the 9 x 9 window (Hann
weights): the mean true disparity of the person's pixels, the same weighted by the squared
image gradient, and the mean over the person's outline pixels (distance <= 1 px).

Options take away one suspect at a time: ``--rig ideal`` (no distortion, no misalignment),
``--no-noise`` (no sensor noise, fixed pattern or drift), ``--synchronous`` (both cameras at
the left camera's instant: no skew), ``--no-grazing`` (no view-dependent emission),
``--set NAME=VALUE`` (an ST parameter, e.g. ``poc_window=7``). ``--flat-disc`` is the
control without a simulated body: a flat warm ellipse (450 counts, weak texture) over a weakly
textured background, the two layers shifted by 13.3 and 8.0 px, blurred (sigma 0.55 px) and
area-sampled from 8x, matched by ST without the depth-edge check.

Run: ``.venv/bin/python docs/experiments/people_disparity_bias.py two_people --rig ideal
--no-noise --synchronous``.
"""

import argparse
import ast
import dataclasses

import numpy as np
from scipy import ndimage
from st_stereo.core.config import STConfig
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.rectification import StereoRectifier
from st_stereo.core.subpixel import half_sample_hann
from st_stereo.sim import scene as sim_scene
from st_stereo.sim.rig import RigGeometry
from st_stereo.sim.scoring import PERSON_LABEL_BASE
from st_stereo.sim.sequences import SequenceRenderer, standard_sequences

HALF = 4          # the 9 x 9 reference window


def parse():
    """Return the command line's options."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('sequence', nargs='?', default='two_people')
    parser.add_argument('--flat-disc', action='store_true')
    parser.add_argument('--rig', choices=('realistic', 'ideal'), default='realistic')
    parser.add_argument('--no-noise', action='store_true')
    parser.add_argument('--synchronous', action='store_true')
    parser.add_argument('--no-grazing', action='store_true')
    parser.add_argument('--set', action='append', default=[], metavar='NAME=VALUE')
    return parser.parse_args()


def weighted_mean(values, weights):
    """Return ``sum(w v) / sum(w)`` (nan when the weights are all zero)."""
    total = weights.sum()
    return float((weights * values).sum() / total) if total > 0 else float('nan')


def window_references(truth, gradient, silhouette_distance, v, u):
    """Return the 9 x 9 window references at (v, u): person mean, gradient^2, outline."""
    window = np.s_[v - HALF:v + HALF + 1, u - HALF:u + HALF + 1]
    hann = half_sample_hann(2 * HALF + 1)
    person = truth.labels[window] >= PERSON_LABEL_BASE
    disparity = truth.disparity[window]
    return (weighted_mean(disparity, hann * person),
            weighted_mean(disparity, hann * person * gradient[window] ** 2),
            weighted_mean(disparity, hann * (person & (silhouette_distance[window] <= 1.0))))


def flat_disc_pair(person_d, background_d, supersample=8, seed=0):
    """Return a left and right 80x60 pair of a flat warm ellipse over a textured background."""
    rng = np.random.default_rng(seed)
    rows, cols, margin = 60, 80, 40
    shape = (rows * supersample, (cols + margin) * supersample)

    def texture(counts):
        field = ndimage.gaussian_filter(rng.normal(size=shape), supersample)
        return counts * field / field.std()
    background, person_texture = texture(20.0), texture(20.0)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] / supersample

    def view(person_shift, background_shift):
        def moved(image, shift):
            return ndimage.shift(image, (0, -shift * supersample), order=1, mode='nearest')
        inside = ((xx - 40 + person_shift) / 5) ** 2 + ((yy - 30) / 9) ** 2 <= 1
        image = np.where(inside, 450 + moved(person_texture, person_shift),
                         moved(background, background_shift))
        image = ndimage.gaussian_filter(image, 0.55 * supersample)
        return 8000 + image.reshape(rows, supersample, -1, supersample).mean(axis=(1, 3))[
            :, :cols]
    return view(0.0, 0.0), view(person_d, background_d)


def flat_disc_control():
    """Print ST's median error on a flat warm disc in front of a farther background."""
    person_d, background_d = 13.3, 8.0
    left, right = flat_disc_pair(person_d, background_d)
    matcher = StereoMatcher(STConfig(depth_edge_check=False, min_range_m=0.01,
                                     max_range_m=1e6))
    result = matcher.match(left, right)
    x, y = np.rint(result.x_left), np.rint(result.y)
    on_disc = ((x - 40) / 5) ** 2 + ((y - 30) / 9) ** 2 <= 1
    error = result.disparity[on_disc] - person_d
    print(f'flat disc (d {person_d} px over a background at {background_d} px): '
          f'{int(on_disc.sum())} matches on the disc, median signed error {np.median(error):+.3f}'
          f' px, median abs {np.median(np.abs(error)):.3f} px')


def main():
    """Print the bias table for one sequence under the options."""
    options = parse()
    if options.flat_disc:
        flat_disc_control()
        return
    if options.no_grazing:
        grazing = sim_scene.ThermalMaterial.__post_init__

        def without_grazing(material):
            material.grazing = 0.0
            grazing(material)
        sim_scene.ThermalMaterial.__post_init__ = without_grazing
    spec = standard_sequences()[options.sequence]
    if options.rig == 'ideal':
        spec = dataclasses.replace(spec, rig=RigGeometry())
    renderer = SequenceRenderer(spec, noise=not options.no_noise)
    rectifier = StereoRectifier(*spec.rig.calibrations())
    config = STConfig.from_mapping({name: ast.literal_eval(value) for name, value in
                                    (item.split('=', 1) for item in options.set)})
    matcher = StereoMatcher(config, model=rectifier.model)
    rows = []
    for t_left, t_right in spec.pair_times()[::6][:10]:
        frame = renderer.frame(t_left, right_t=t_left if options.synchronous else t_right)
        left, right = rectifier.rectify(frame['left'], frame['right'])
        result = matcher.match(left, right, **rectifier.valid_keywords())
        truth = frame['truth']
        image = left.astype(np.float64)
        gradient = np.hypot(ndimage.sobel(image, 0), ndimage.sobel(image, 1))
        silhouette_distance = ndimage.distance_transform_edt(truth.labels >= PERSON_LABEL_BASE)
        own = result.disparity - rectifier.model.disparity_offset
        rows_n, cols_n = truth.labels.shape
        for x, y, d in zip(np.rint(result.x_left).astype(int), np.rint(result.y).astype(int),
                           own):
            inside = HALF <= y < rows_n - HALF and HALF <= x < cols_n - HALF
            if not (inside and truth.labels[y, x] >= PERSON_LABEL_BASE
                    and truth.visible_right[y, x]):
                continue
            references = window_references(truth, gradient, silhouette_distance, y, x)
            rows.append((silhouette_distance[y, x], d - truth.disparity[y, x],
                         *(d - reference for reference in references)))
    table = np.array(rows)
    print(f'{options.sequence}, rig {options.rig}, noise {not options.no_noise}, '
          f'synchronous {options.synchronous}, grazing {not options.no_grazing}, '
          f'{" ".join(options.set) or "default ST"}: median signed error (px) against')
    print('| distance to silhouette (px) | matches | own pixel | window: person | '
          'gradient^2 | outline |')
    print('|---|---:|---:|---:|---:|---:|')
    for low, high, label in ((0, 99, 'all'), (0, 1.5, '1'), (1.5, 2.5, '2'), (2.5, 99, '>= 3')):
        chosen = table[(table[:, 0] >= low) & (table[:, 0] < high)]
        if len(chosen):
            medians = ' | '.join(f'{np.nanmedian(chosen[:, k]):+.3f}' for k in range(1, 5))
            print(f'| {label} | {len(chosen)} | {medians} |')


if __name__ == '__main__':
    main()
