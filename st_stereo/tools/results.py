"""
The paper-reproduction report: every table and figure of the paper, with our code, in one file.

``st-stereo eval all --out docs/results.md`` runs the four evaluations (features, illumination,
sub-pixel accuracy, whole pipeline in 3-D) on the shared real frames and on simulated frames and
sequences, and writes the Markdown report, its PNG figures (``docs/results/``) and the raw
numbers (``docs/results/results.json``).
"""

import json
import pathlib
import platform
import tempfile
import time

import cv2

SIM_FRAME_TIMES = (2.0, 6.0, 10.0)


def simulated_frames(times=SIM_FRAME_TIMES):
    """Raw left frames of the office sequence at ``times`` (uint16, 80x60)."""
    from st_stereo.sim.sequences import SequenceRenderer, standard_sequences
    renderer = SequenceRenderer(standard_sequences()['office'])
    frames = []
    for t in renderer.spec.frame_times:
        if any(abs(t - wanted) < 0.5 / renderer.spec.fps for wanted in times):
            frames.append(renderer.frame(t, with_truth=False)['left'])
        elif len(frames) == len(times):
            break
        else:
            renderer.frame(t, with_truth=False)     # keep the noise stream in order
    return frames


def run_all(out_path, quick=False, progress_factory=None, log=print):
    """Run every evaluation and write the report; returns the results dict."""
    from st_stereo.tools import eval_features as ef
    from st_stereo.tools import eval_pipeline as ep
    from st_stereo.tools import eval_subpixel as es
    from st_stereo.package_data import FRAMES, shared_frame

    out_path = pathlib.Path(out_path)
    figures = out_path.parent / 'results'
    figures.mkdir(parents=True, exist_ok=True)
    started = time.time()
    results = {'quick': quick}

    def bar(total, name):
        return progress_factory(total, name) if progress_factory else None

    real_names = list(FRAMES)
    real = ef.frames_80x60([shared_frame(name) for name in real_names])
    log('rendering simulated frames')
    simulated = simulated_frames()
    sim_names = [f'sim office t={t:g} s' for t in SIM_FRAME_TIMES]

    # 1. Features (Table 1, Fig. 5).
    repeats = 10 if quick else 100
    tables = {}
    for label, images, names in (('real', real, real_names), ('simulated', simulated,
                                                              sim_names)):
        progress = bar(11, f'features ({label})')
        rows, missing = ef.feature_table(images, repeats=repeats,
                                         progress=progress.update if progress else None)
        if progress:
            progress.close()
        tables[label] = {'rows': rows, 'missing': missing, 'images': names}
    results['features'] = tables
    ef.overlay_figure(real[0], figures / 'features_people_lab.png')
    ef.overlay_figure(simulated[1], figures / 'features_sim_office.png')

    # 2. Illumination (Figs. 6-7).
    progress = bar(9, 'illumination')
    curves = ef.illumination_curves(real + simulated,
                                    progress=progress.update if progress else None)
    if progress:
        progress.close()
    results['illumination'] = curves
    ef.plot_illumination(curves, figures / 'illumination.png')

    # 3. Sub-pixel accuracy (Figs. 8-10): ST on every shared frame and the simulated frames.
    shifts = es.parse_shifts('0:30:1.0' if quick else '0:30:0.25')
    subpixel = {}
    with tempfile.TemporaryDirectory() as scratch:
        paths = [str(shared_frame(name)) for name in real_names]
        for name, frame in zip(sim_names, simulated):
            path = pathlib.Path(scratch) / (name.replace(' ', '_').replace('=', '') + '.png')
            cv2.imwrite(str(path), frame)
            paths.append(str(path))
        for name, path in zip(real_names + sim_names, paths):
            protocol = es.SubpixelProtocol(image_path=path, windows=(9,), gammas=(0.1,),
                                           shifts=shifts, realistic=True, peers=False)
            report = es.evaluate(protocol, progress_factory=lambda total, n=name: bar(total, n))
            report['image'] = name
            subpixel[name] = report
    results['subpixel'] = subpixel

    # 4. Whole pipeline in 3-D (Table 2, Figs. 11-12).
    report, tallies = ep.evaluate(stride=8 if quick else 2, progress_factory=bar,
                                  max_frames=4 if quick else None)
    results['pipeline'] = report
    ep.plot_boxes(tallies, figures / 'pipeline_z_error.png')

    # 5. Every point a tracker receives, per surface (issue 12), and error overlays.
    from st_stereo.tools import eval_points
    from st_stereo.package_data import bundled_recording
    log('scoring every point per surface')
    results['points'], results['points_motion'] = eval_points.evaluate(
        stride=8 if quick else 2, recording=bundled_recording(),
        max_frames=4 if quick else None)
    eval_points.error_figure(figures / 'points_error.png')

    results['seconds'] = time.time() - started
    with open(figures / 'results.json', 'w', encoding='utf-8') as stream:
        json.dump(results, stream, indent=1, default=float)
    out_path.write_text(render_markdown(results, figures.name), encoding='utf-8')
    return results


def _subpixel_rows(subpixel):
    from st_stereo.tools.eval_subpixel import markdown_table
    blocks = []
    for name, report in subpixel.items():
        blocks.append(f'**{name}**\n\n{markdown_table(report)}')
    return '\n'.join(blocks)


def illumination_summary(curves):
    """One sentence, computed from the curves, on how phase congruency compares."""
    pc = curves['PhaseCong(0.1)']
    others = {m: c for m, c in curves.items() if m != 'PhaseCong(0.1)'}
    most = all(pc['count'][i] >= max(c['count'][i] for c in others.values())
               for i in range(len(pc['count'])))
    best = [i for i in range(len(pc['redetection']))
            if pc['redetection'][i] >= max(c['redetection'][i] for c in others.values())]
    rate = pc['redetection'][-1] * 100
    runner = max(others, key=lambda m: others[m]['redetection'][-1])
    verdict = 'keeps' if most else 'does not keep'
    return (f'PhaseCong(0.1) {verdict} the most features at every beta; its re-detection rate '
            f'is the highest (or tied) at {len(best)} of {len(pc["redetection"])} beta values, '
            f'and at beta = 100 it is {rate:.0f} % against '
            f'{others[runner]["redetection"][-1] * 100:.0f} % for '
            f'the best other detector ({runner}).')


def pipeline_summary(report):
    """Sentences, computed from the table, on ST against the baseline."""
    from st_stereo.tools.eval_pipeline import checks
    rows = checks(report)
    ratios = [r[2] for r in rows if 'ORB' in r[1]]
    medians = [r[2] * 100 for r in rows if r[1].startswith('median')]
    missed = [f'{r[0]} {r[1]}: {r[2] * 100:.2f} % (target {r[3]}, short by '
              f'{(r[2] - 0.02) * 100:.2f} points)' for r in rows if not r[4] and 'outlier' in r[1]]
    text = (f'Reading the table: ST finds {min(ratios):.0f} to {max(ratios):.0f} times the '
            f'correct matches of ORB + KNN; its median depth error at 2.5-4.5 m is '
            f'{min(medians):.2f} to {max(medians):.2f} % of the range.')
    if missed:
        text += ' Where it falls short: ' + '; '.join(missed) + '.'
    return text


def render_markdown(results, figures):
    """Return the report's Markdown."""
    from st_stereo.tools import eval_features as ef
    from st_stereo.tools import eval_pipeline as ep
    from st_stereo.tools import eval_points
    features = results['features']
    quick = ' (quick run: fewer repeats, shifts and frames)' if results['quick'] else ''
    return f"""# Paper reproduction: every table and figure with our code{quick}

Regenerate with `st-stereo eval all --out docs/results.md` ({results["seconds"] / 60:.1f} min
on this machine: {platform.processor() or platform.machine()}, one process). Raw numbers:
`{figures}/results.json`. Real frames: `../shared/data/thermal` (see its README for authors and
licences), area-resized to 80x60; simulated frames and sequences: `st_stereo.sim` (the
ceiling rig with ground truth, `st-stereo sim list`).

## 1. Features at 80x60 (paper Table 1, Fig. 5)

{ef.__doc__.split(chr(10) + chr(10))[1]}

Real frames:

{ef.feature_markdown(features["real"]["rows"], features["real"]["missing"],
                     features["real"]["images"])}
Simulated frames (the bundled office sequence, left camera):

{ef.feature_markdown(features["simulated"]["rows"], features["simulated"]["missing"],
                     features["simulated"]["images"])}
The paper (C++, i7-3687U) counted 117 (ORB), 34 (BRISK), 77 (FAST), 120 (Shi-Tomasi / GFTT),
14 (SURF), 84 (AGAST), 33 (KAZE), 1734 (gamma = 0.01) and 777 (gamma = 0.1; its table labels
both rows 0.01) on one Lepton frame. As there, phase congruency at gamma = 0.1 finds several
times more features than any corner detector, and costs more time than FAST-type detectors
(our phase congruency is numpy, not C++).

![features, real]({figures}/features_people_lab.png)
![features, simulated]({figures}/features_sim_office.png)

## 2. Robustness to brightness changes (paper Figs. 6-7)

g = f + beta on the 8-bit frames (all real and simulated frames above), clipped at 255;
features per image / re-detection rate within 1 pixel of the beta = 0 features:

{ef.illumination_markdown(results["illumination"])}
![illumination]({figures}/illumination.png)

{illumination_summary(results["illumination"])} What phase congruency loses comes from the
clipping at 255 (saturated warm regions become flat). On the raw 14-bit counts the matcher uses,
an offset beta changes nothing: the log-Gabor filters have no DC response.

## 3. Sub-pixel accuracy (paper Figs. 8-10)

The core's protocol (`st-stereo eval subpixel`: shift a frame by known sub-pixel amounts,
match, compare) for ST alone (W = 9, gamma = 0.1, realistic degradations: 1 % noise, gain 1.05
and offset 2 % on the right image) on every shared frame and on the simulated frames. The
comparison with the peers (OpenCV phaseCorrelate, its iterative variant, scikit-image, SAD +
parabola) on all five shared frames is in `docs/accuracy.md`.

{_subpixel_rows(results["subpixel"])}

## 4. Whole pipeline in 3-D with ground truth (paper Table 2, Figs. 11-12)

{ep.__doc__.split(chr(10) + chr(10), 1)[1]}

Sequences (`st-stereo sim list`): rendered through the realistic rig (barrel distortion, a
misaligned right camera, Lepton noise, drift, FFC and brightness differences), rectified with
their true calibration; every second frame scored.

{ep.markdown_tables(results["pipeline"])}
![Z error]({figures}/pipeline_z_error.png)

{pipeline_summary(results["pipeline"])} The
strict outlier rate is dominated by matches one pixel off a depth edge, that carry the
disparity of the warmer (foreground) side: the lens blur (sigma 0.55 px) and rectification
interpolation put the person's radiance in the floor pixel next to it, so the pixel is matched
where it looks like the person. The +-1 px column counts what remains when such edge pixels are
allowed either side's depth. StereoSGBM, dense, matches every pixel but most of them badly on
textureless thermal surfaces.

## 5. Every point a tracker receives, per surface

{eval_points.__doc__.split(chr(10) + chr(10), 1)[1]}
{scoring_doc()}

{eval_points.markdown_report(results["points"])}

The tables above include the depth-edge check (``depth_edge_check``,
``st_stereo.core.depth_edges``): a match on the cool side of a strong edge is kept only when a
POC window moved into its own side finds its disparity. Without it (measured 2026-12-02,
`st-stereo eval points --stride 4 [--set depth_edge_check=false]`), 3-D outliers over all
points were 7.3 / 2.6 / 4.0 % on walk_across / two_people / sit_down, 4.9 % on the held-out
meeting_room and 3.1 % on the recording; with it 7.0 / 1.8 / 3.3 %, 3.4 % and 2.4 %. Correct
points on people per frame are kept (recording 151.1 -> 150.4), but background points go
with the wrong ones: correct floor points per frame on the recording 109.0 -> 83.0. The
meeting_room figures were seen while the check was designed, so that sequence is no longer
strictly held out for this mechanism. The check assumes the nearer object is the warmer one:
in front of a warmer background it removes nothing (``st_stereo.core.depth_edges``).

**Consistency with the previous pair** (``temporal_tolerance_px``, since 2026-12-06, off by
default, ``st_stereo.core.temporal``; the tables above are without it): with a tolerance, a
match whose window did not change since the previous pair beyond the noise sees the same
scene, so it is kept only when the previous pair matched the same pixel within that many
pixels; moving features and the first pair (or one after a gap) are not checked. It costs
0.13 ms per 80x60 pair. Measured with `st-stereo eval points --stride 4 [--set
temporal_tolerance_px=0.3]` (2026-12-06; the tolerance chosen on synchronized pairs of
sit_down and two_people, where static matches unmatched in the previous pair were 8.5 / 6.2 %
of the static ones and held 50 / 42 % of their 3-D outliers, and those more than 0.3 px off 2.6
/ 0.5 %, holding 31 / 6 %;
meeting_room run once after the choice):

{temporal_table()}
The evaluation matches the pair before each scored one so the check has its previous pair, as
the node does with every pair (`st-stereo eval skew`, which compares the skew compensation,
runs without it). **Why it is off by default**: `st-stereo eval people --set
temporal_tolerance_px=0.3` (2026-12-06) loses one of two_people's two people from pair 34 on
(recall 97.1 -> 71.4 %, MOTA 0.714): that person shows 4-7 matched points per pair there and
the check takes one or two of them, below what the people stage needs for a detection;
open_office recall 63.2 -> 59.0 % (precision 95.5 -> 100 %); every other row the same
recall, precision and id switches. The people stage needs more than a handful of points per
person before the points can be thinned like this. Measured and not kept (2026-12-08): checking
only the static matches below a confidence (0.6 or 0.5; the floor's ambiguous matches, e.g. a
static feature of sit_down's floor whose disparity jumped between -1.8 and +2.3 px from pair to
pair, have confidences of 0.35-0.55, against a median of 0.74 for correct floor points):
`st-stereo eval points --stride 4 --no-recording --set temporal_tolerance_px=0.3 --set
temporal_max_confidence=0.6` gave 3.3 / 0.5 / 1.3 % outliers on walk_across / two_people /
sit_down (3.3 / 0.4 / 1.1 % checking every static match, 3.9 / 0.9 / 2.3 % without the check),
but `st-stereo eval people --sequences two_people` with it still lost the standing person:
recall 98.6 -> 84.3 % (its few matches are of low confidence too).

**Where the point is placed** (``point_location``, since 2026-12-06,
``st_stereo.core.point_location``; the tables above use the default, ``structure`` since
2026-12-07, ``feature`` before). A 9-pixel POC window spans a whole person at 80x60, and a
feature one to four pixels off a strong edge carries the edge's disparity. With
``point_location: structure`` the point is triangulated at the centroid of the window's squared
Hann weight times squared horizontal gradient (the weight a windowed least-squares shift gives
each pixel's local shift; for POC, which whitens the spectrum, an approximation chosen by
measurement) instead of at the feature's pixel. Disparities and matches are unchanged (and so
the shifted-frame protocol, whose uniform shift cannot show where a point is placed); the
points move by 0.62 px median (p90 1.67, max 3.1 px, every fifth pair of the recording); the
centroids cost 1.0-2.0 ms per 80x60 pair of 556 matches (``structure_offsets`` timed alone, two
runs, the second on a loaded machine; in `st-stereo bench`, part of the triangulation stage,
0.41 ms, 2026-12-07). The ``DisparityImage`` keeps every match at its feature's pixel (placed
at their structure, 26-41 % of the points would share a pixel with another). Measured with
`st-stereo eval points --stride 4 [--set point_location=structure]` (2026-12-06, without the
temporal check above; feature -> structure; the weighting chosen among five on synchronized
pairs of the three tuning sequences, meeting_room run once after the choice):

{point_location_table()}
On the rendered warm box in front of a textured wall (``test/test_point_location.py``, 20
noise seeds), 355 points at their features' pixels carry the box's disparity more than a
pixel off the box (51 with the depth-edge check, which drops 518 matches for it); placed at
their window's structure, none does, with or without the check. The test's wall has 4 counts
of texture against the box's 400: with 15 counts none does either, with 30 counts 2-3 of
about 3,000 matches over the 20 seeds do (at the box's top and bottom edges; a review's
variant of the scene, also with the box's edges a quarter pixel off the pixel grid).

Part of the gain is the scoring's: a pixel on a depth edge accepts either side's depth
(docs: the criteria above), and placed at their structure 37-39 % of the points lie on such
pixels instead of 21-28 % (the pixel's disparity range wider than 1 px; 18 pairs of each
tuning sequence, `st-stereo eval points`'s pairing, a review's script). On the points whose
pixel holds one depth, the strict rate falls from 15.5 / 21.1 / 17.6 % to 10.3 / 14.2 / 11.2 %
and the 3-D rate from 4.5 / 2.0 / 4.5 % to 4.4 / 1.2 / 4.0 % (walk_across / two_people /
sit_down): the strict gain is real, the 3-D one mostly the edge pixels'. Points that were
counted on the floor or a wall beside a person land on the person's outline, where their
disparity belongs (people's point counts grow by 11-20 %, the same measurements relabelled,
not new ones). walk_across's people outliers grow because such points join the walker's own
wrong ones: 15 of its 56 are the first pair's (no previous pair, so no skew correction: the
walker's legs 2 px short); in the three other pairs traced (16, 32, 52) they are moving
features whose skew correction was too small, too large, or, for the walker turning at the
image's right edge, of the wrong sign (+1.9 px
instead of -1.6 px; issue 14).

**Why it was not the default until 2026-12-07, and is since.** The people stage
(docs/people.md) was tuned on points at their features' pixels. `st-stereo eval people --set
point_location=structure` (2026-12-06, against the same day's default run): sit_down recall
99.0 -> 85.6 % (the person walking in from 4.6 m with the head above the image is published 14
pairs later: the legs under a body cut by the top edge are two or three pixels wide there, and
the floor position moving by 1-2 cm moves the legs' window off the warm pixels in one of the
first pairs), horizontal error medians up by 6-55 mm on six of the seven, open_office recall
63.2 -> 72.9 % but precision 95.5 -> 83.3 %, crossing 2 id switches (none). Moving only the
points of features on the cool side of their window's structure was not kept (the same sit_down
recall); re-measured on 2026-12-07 with that day's people stage: sit_down 85.6 %, far_standing
96.3 -> 95.6 %. Since 2026-12-07 ``points2`` carries each match's feature pixel (fields ``u``,
``v``) and the people node puts every point back on its feature's ray at its depth
(``st_stereo.core.triangulation.at_their_features``; `st-stereo eval people` does the same), so
the people stage sees what it was tuned on and every other consumer gets the structure's
points: `st-stereo eval people` (all ten sequences and the recording) gave every row of its
table of record to the digit, and the main job through the node processes recall 98.2 %,
precision 100 %, MOTA 0.982, horizontal error median / p95 0.099 / 0.162 -> 0.099 / 0.158 m
(the node now takes the exact feature pixel where it projected float32 points), while its 3-D
outliers over all points went 2.2 -> 1.5 %. The centroids cost 0.41 ms per 80x60 pair in
`st-stereo bench` (docs/speed.md).

**Both options together** (`st-stereo eval points --stride 4 --set point_location=structure
--set temporal_tolerance_px=0.3`, 2026-12-06): 3-D outliers over all points 3.3 / 0.4 / 1.1 %
on walk_across / two_people / sit_down, 0.4 % on meeting_room (held out), 1.1 % on the
recording; on people 4.2 / 0.4 / 0.8 %, 0.2 %, 0.6 %; strict 6.5 / 8.7 / 5.5 %, 5.9 %, 6.9 %;
median abs dZ/Z 2.39 / 1.85 / 2.02 %, 2.44 %, 2.16 %; 2892 / 5016 / 5435, 4073 and 40404
points (the temporal check's). The 2 % target is then met but on walk_across, whose excess is
its walker's skew-corrected points (issue 14); median abs dZ/Z <= 1 % is met nowhere. The
temporal check passes a pair with a camera in an FFC (``pair_info``'s flags: a frozen frame
looks static everywhere) and the pair after it, counted as ``pairs_in_ffc``. Its known
limits: a live change of another matcher parameter makes the next pair lose its static
matches as unmatched, once; with ``keep_latest`` dropping pairs the previous matched pair may
be older than 0.25 s, and the pair is then not checked (counted).

**With the POC skew velocities as well** (`--set skew_velocity=poc`, docs/skew.md "Velocity by
POC"; `st-stereo eval points --stride 4 --set point_location=structure --set
temporal_tolerance_px=0.3 --set skew_velocity=poc`, 2026-12-07, the structure and temporal run
beside it reproducing the paragraph above to the digit): 3-D outliers over all points 2.1 / 0.4
/ 1.1 % on walk_across / two_people / sit_down, 0.3 % on meeting_room (held out), 1.0 % on the
recording; on people 2.9 / 0.3 / 0.8 %, 0.1 %, 0.5 %; strict 5.1 / 8.7 / 5.5 %, 5.5 %, 6.6 %;
median abs dZ/Z 2.30 / 1.80 / 2.01 %, 2.37 %, 2.10 %; correct points on people per frame 64.3 /
162.7 / 93.5, 163.2, 161.6 (71.4 / 165.1 / 93.8, 167.0, 164.6 without the POC velocities).
walk_across stays over both targets; **its first scored pair** has no pair before it (the
matcher node's first pair after its start or a gap: nothing to measure the motion on, so
nothing is corrected) and, its walker moving at +40 ms of skew, alone holds 21 of its 108
points as outliers (19.4 %) and 15 of its 24 people points (62.5 %). Scored from the second
pair on (`docs/experiments/first_pair_outliers.py`, the same scoring's tally split per frame),
the three options give 1.32 % over all points and 1.63 % on people; the defaults of then
(points at their features) 3.79 % and 2.24 % (4.34 % and 3.05 % with the first pair). The
evaluation keeps scoring the first pair (a tracker receives it), so the table of record is the
one with it; a node publishes such a pair's points uncorrected (counted as `skew
pairs_without_previous`).

**Features in the top rows, tried and not kept** (2026-12-07). A feature within half a POC
window (4 px) of an image border has no window that fits and is dropped
(``features_border``). In a ceiling rig's view the top rows are the far end of the room, where
a far person's head leaves the image and many of their features lie (docs/people.md:
meeting_room's first walker, 39 features in rows 0-3 against 120 below them). Built as an
option (commit 20c68a6, reverted): a top-row feature matched with both POC windows moved down
together until they fit (window row ``max(y, 4)``). `st-stereo eval points --stride 4 --set
top_window_shift=4` against the defaults: points 3065 -> 4390 / 5308 -> 6640 / 5813 -> 7751
(walk_across / two_people / sit_down), 4351 -> 4786 (meeting_room), 42458 -> 52690 (the
recording); 3-D outliers 4.3 -> 4.0 / 1.9 -> 2.3 / 3.2 -> 3.9 %, 3.0 -> 3.3 %, 2.2 -> 2.9 %;
correct points on people per frame 63.7 -> 64.6 / 151.6 -> 154.5 / 79.2 -> 79.7, 159.0 ->
172.2, 146.2 -> 147.7. **An independent review showed that most of the new points are copies**:
the features of rows 0-4 of one column share the same pair of windows (row 4), so on 22 pairs
of four sequences the matches grew by 26.8 % but the distinct measurements (window,
disparity) by 5.4 %; uniqueness, checked on the feature's own row, did not see it. The review
also found that the moved window was not checked against the rectified images' pixels
without data (the valid masks are eroded around the feature's row). The people stage
(`st-stereo eval people --set top_window_shift=4`, six tuning sequences): meeting_room recall
79.0 -> 82.9 %, but far_walker precision 100 -> 73.6 % (a false person behind its standing
person: that person's top-row points were 21 % 3-D outliers, a window moved 4 rows over a
body a few pixels wide being mostly the wall), sit_down 99.0 -> 87.5 % (its far walker's legs
window moved one column off its legs), far_standing 96.3 -> 95.6 %; the same with a move of 2
rows. Moving windows in at every border was measured first: the bottom rows (the floor under
the rig, whose disparity changes along the move) gave 100 % 3-D outliers, the sides 14-23 %.
What remains of it: ``extract_windows`` refuses a window that leaves the image instead of
wrapping a negative index round silently.

Disparity error of the matches on people (what a moving person's points carry), by the pair's
camera skew and the person's image speed; each sequence has its own camera phase, so its skew
bin is its own:

{eval_points.markdown_motion_report(results.get("points_motion") or {})}

Why the people's median abs dZ/Z stays above 1 % (measured 2026-12-03 with
`docs/experiments/people_disparity_bias.py`, 10 pairs of two_people): the matches on people
come out 0.14 to 0.22 px short of their own pixel's true disparity (a person a few centimetres
too far) whatever is taken away: -0.141 px as the evaluation renders it, -0.182 with both
cameras at the same instant, -0.216 with an ideal rig as well, -0.193 without sensor noise,
-0.201 without the view-dependent emission, -0.211 / -0.192 with POC windows of 7 / 11 px.
The bias grows towards the inside of the body (-0.16, -0.32, -0.45 px at 1, 2 and >= 3 px from
the silhouette, ideal noise-free rig) and stays -0.16 px against the true disparity of the
person's outline pixels. On a flat warm disc in front of a farther background (the same blur,
no body) ST's error is -0.04 px. What the windows lock on is the silhouette, the strongest
structure of a warm body at 80x60, and the silhouette of a curved body is its occluding
contour: each camera sees it at another point of the surface, near the body's axis, behind the
front surface the pixels' truth measures. Adaptive support weights (each window weighted by
its pixels' likeness to its centre, Gaussian in units of the window's spread, tried as a
monkey-patch on the ideal noise-free rig, not kept) left it where it was: -0.199 / -0.180 /
-0.231 px at widths 2 / 1 / 0.5 against -0.193 px; the weights follow the silhouette too. A
window matcher at this resolution gives a body the depth of its contour; the 1 % target on
people needs a correction for the body's curvature that is not built.

{points_before(figures)}

![Points coloured by their 3-D error]({figures}/points_error.png)

Points coloured by their 3-D error over the left image (green within 0.1 m, yellow within
0.3 m, red beyond), one frame of each sequence and of the recording.
"""


# `st-stereo eval points --stride 4 [--set point_location=structure]`, 2026-12-06:
# feature -> structure.
POINT_LOCATION_COLUMNS = ('sequence', 'outliers 3-D, all', 'on people', 'strict',
                          'disparity > 1 px', 'median abs dZ/Z', 'correct on people / frame')
POINT_LOCATION_ROWS = (
    ('walk_across', '4.3 -> 3.9 %', '3.0 -> 4.1 %', '12.3 -> 7.1 %', '10.0 -> 5.5 %',
     '2.64 -> 2.43 %', '63.7 -> 72.1'),
    ('two_people', '1.9 -> 0.9 %', '0.3 -> 0.4 %', '15.4 -> 9.3 %', '14.5 -> 8.7 %',
     '2.28 -> 1.88 %', '151.6 -> 170.3'),
    ('sit_down', '3.2 -> 2.3 %', '0.7 -> 0.8 %', '13.2 -> 6.7 %', '11.1 -> 5.1 %',
     '2.32 -> 2.08 %', '79.2 -> 94.8'),
    ('meeting_room (held out)', '3.0 -> 0.6 %', '0.2 -> 0.2 %', '14.1 -> 6.3 %',
     '13.8 -> 6.1 %', '2.78 -> 2.46 %', '159.0 -> 177.0'),
    ('recording', '2.2 -> 1.6 %', '0.6 -> 0.6 %', '13.0 -> 7.3 %', '11.6 -> 6.0 %',
     '2.49 -> 2.19 %', '146.2 -> 167.9'),
)


def point_location_table():
    """Return the measured feature -> structure table of ``point_location`` (Markdown)."""
    return markdown_rows(POINT_LOCATION_COLUMNS, POINT_LOCATION_ROWS)


# `st-stereo eval points --stride 4 [--set temporal_tolerance_px=0.3]`, 2026-12-06: off -> on.
TEMPORAL_COLUMNS = ('sequence', 'points', 'outliers 3-D, all', 'on people', 'strict',
                    'correct / frame', 'correct on people / frame')
TEMPORAL_ROWS = (
    ('walk_across', '3065 -> 2892', '4.3 -> 3.8 %', '3.0 -> 3.1 %', '12.3 -> 11.5 %',
     '162.9 -> 154.5', '63.7 -> 63.3'),
    ('two_people', '5308 -> 5016', '1.9 -> 1.1 %', '0.3 -> 0.3 %', '15.4 -> 14.5 %',
     '289.4 -> 275.7', '151.6 -> 148.1'),
    ('sit_down', '5813 -> 5435', '3.2 -> 2.2 %', '0.7 -> 0.7 %', '13.2 -> 12.0 %',
     '216.3 -> 204.5', '79.2 -> 78.9'),
    ('meeting_room (held out)', '4351 -> 4073', '3.0 -> 2.4 %', '0.2 -> 0.2 %',
     '14.1 -> 12.9 %', '234.4 -> 220.8', '159.0 -> 152.2'),
    ('recording', '42458 -> 40404', '2.2 -> 1.8 %', '0.6 -> 0.6 %', '13.0 -> 12.3 %',
     '298.7 -> 285.6', '146.2 -> 144.0'),
)


def markdown_rows(columns, rows):
    """Return a Markdown table of string rows."""
    lines = ['| ' + ' | '.join(columns) + ' |', '|' + '---|' * len(columns)]
    lines += ['| ' + ' | '.join(row) + ' |' for row in rows]
    return chr(10).join(lines) + chr(10)


def temporal_table():
    """Return the measured off -> on table of ``temporal_tolerance_px`` (Markdown)."""
    return markdown_rows(TEMPORAL_COLUMNS, TEMPORAL_ROWS)


POINTS_BEFORE = 'points_before.json'


def points_before(figures):
    """Return the per-surface tables measured before issue 12's changes, when on record."""
    from st_stereo.tools import eval_points
    path = pathlib.Path(__file__).resolve().parents[2] / 'docs' / figures / POINTS_BEFORE
    if not path.is_file():
        return ''
    record = json.loads(path.read_text(encoding='utf-8'))
    return (f'Before the plausible range, the valid-region handling and the confidence '
            f'(commit {record["commit"]}, the same scoring and frames; '
            f'`{figures}/{POINTS_BEFORE}`):\n\n'
            + eval_points.markdown_report(record['report']).replace('#### ', '##### before: '))


def scoring_doc():
    """Return the scoring criteria, from the docstring of ``st_stereo.sim.scoring``."""
    from st_stereo.sim import scoring
    return scoring.__doc__.split(chr(10) + chr(10), 1)[1].strip()
