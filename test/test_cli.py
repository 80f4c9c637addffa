"""The st-stereo command line: match, features, params, eval, errors."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from st_stereo.cli import main
from st_stereo.core.calibration.files import save_calibration
from st_stereo.core.config import config_from_assignments
from st_stereo.core.fourier import fourier_shift_image_x
from test_camera_calibration import rig_calibration


@pytest.fixture
def pair_files(tmp_path, people_80x60):
    left = np.round(people_80x60).astype(np.uint16)
    right = np.round(fourier_shift_image_x(people_80x60, 12.25)).astype(np.uint16)
    paths = tmp_path / 'left.png', tmp_path / 'right.png'
    cv2.imwrite(str(paths[0]), left)
    cv2.imwrite(str(paths[1]), right)
    return paths


def test_match_writes_json_and_csv(pair_files, tmp_path, capsys):
    out = tmp_path / 'matches.json'
    assert main(['match', str(pair_files[0]), str(pair_files[1]), '--out', str(out)]) == 0
    document = json.loads(out.read_text())
    disparities = np.array([m['disparity'] for m in document['matches']])
    assert len(disparities) > 100
    assert np.median(np.abs(disparities - 12.25)) < 0.05
    summary = json.loads(capsys.readouterr().out)
    assert summary['matches'] == len(disparities)
    csv_out = tmp_path / 'matches.csv'
    assert main(['match', str(pair_files[0]), str(pair_files[1]), '--out', str(csv_out)]) == 0
    header = csv_out.read_text().splitlines()[0]
    assert header == 'x_left,y,disparity,x_right,similarity,poc_peak,confidence,x_point,y_point'


def test_match_with_calibration_adds_points(pair_files, tmp_path):
    left_yaml, right_yaml = tmp_path / 'l.yaml', tmp_path / 'r.yaml'
    save_calibration(rig_calibration('left', 0.0), left_yaml)
    save_calibration(rig_calibration('right', -83.9 * 0.55), right_yaml)
    out = tmp_path / 'm.csv'
    code = main(['match', str(pair_files[0]), str(pair_files[1]), '--calibration',
                 str(left_yaml), str(right_yaml), '--rectified', '--out', str(out)])
    assert code == 0
    rows = out.read_text().splitlines()
    assert rows[0].endswith(',X,Y,Z')
    z = np.array([float(r.split(',')[-1]) for r in rows[1:]])
    assert np.median(z) == pytest.approx(83.9 * 0.55 / 12.25, rel=0.01)


def test_features_with_overlay(pair_files, tmp_path, capsys):
    overlay = tmp_path / 'overlay.png'
    assert main(['features', str(pair_files[0]), '--overlay', str(overlay),
                 '--set', 'gamma=0.3']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['features'] > 0 and report['gamma'] == 0.3
    image = cv2.imread(str(overlay))
    assert image.shape == (480, 640, 3)


@pytest.mark.parametrize('argv, message', [
    (['match', 'missing_left.png', 'missing_right.png'], 'missing_left.png: no such image'),
    (['features', 'x.png', '--set', 'gamma=2'], 'gamma: expected a value in'),
    (['features', 'x.png', '--set', 'gama=0.1'], "unknown ST parameter 'gama'"),
])
def test_errors_are_one_clear_line(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_set_parses_typed_values():
    config = config_from_assignments(['poc_window=11', 'ordering=false', 'gamma=0.3',
                                      'poc_source=moments'])
    assert (config.poc_window, config.ordering, config.gamma, config.poc_source) == \
        (11, False, 0.3, 'moments')


def test_eval_subpixel_small_run(tmp_path, thermal_dir, capsys):
    out, plot, markdown = tmp_path / 'r.json', tmp_path / 'r.png', tmp_path / 'r.md'
    code = main(['eval', 'subpixel', '--image', str(thermal_dir / 'people_lab_180x180.png'),
                 '--windows', '9', '--gammas', '0.1', '--shifts', '3:15:2.375', '--quiet',
                 '--json', str(out), '--plot', str(plot), '--markdown', str(markdown)])
    assert code == 0
    report = json.loads(out.read_text())
    methods = report['results'][0]['methods']
    assert {'ST', 'ST_paper', 'opencv_phaseCorrelate', 'opencv_phaseCorrelateIterative',
            'skimage_upsampled_dft', 'sad_parabola', 'ST_M_recentred'} <= set(methods)
    assert methods['ST']['within_0.5'] > 99.0
    for name, summary in methods.items():
        assert summary['estimates'] + summary['failures'] == summary['features'], name
    assert plot.stat().st_size > 10000
    assert '| ST |' in markdown.read_text()


def test_python_dash_m_entry_point():
    completed = subprocess.run([sys.executable, '-m', 'st_stereo', 'params'],
                               capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0
    assert 'poc_window = 9' in completed.stdout


def test_readme_lists_every_parameter_as_the_code_defines_it():
    import pathlib

    from st_stereo.cli import parameters_markdown
    readme = (pathlib.Path(__file__).resolve().parents[1] / 'README.md').read_text()
    assert parameters_markdown() in readme, 'README parameter table is stale: regenerate ' \
        'it with `st-stereo params --markdown`'


def test_readme_lists_every_node_parameter_as_the_nodes_declare_it():
    import pathlib

    from st_stereo.cli import node_parameters_markdown
    readme = (pathlib.Path(__file__).resolve().parents[1] / 'README.md').read_text()
    assert node_parameters_markdown() in readme, 'README node parameter table is stale: ' \
        'regenerate it with `st-stereo params --node-markdown`'


def test_rig_losses_count_pairs_without_a_cloud_in_the_window_and_late_rigs():
    # Would catch: losses hidden by a per-rig warm-up, a rig that never produced a cloud
    # counted as held, images outside the scored window counted.
    import types
    from st_stereo.tools.latency_bench import rig_losses

    def monitor(raw, clouds, first_cloud):
        return types.SimpleNamespace(
            raw_received={(sec, 0): seen for sec, seen in raw.items()},
            clouds={sec * 1_000_000_000: None for sec in clouds},
            times=[] if first_cloud is None else [first_cloud])

    raw = {1: 10.0, 2: 10.1, 3: 10.2, 4: 10.3, 5: 20.0}
    good = monitor(raw, [2, 3, 4], 9.0)            # pair 1 is before the window
    lossy = monitor(raw, [2, 4], 9.0)              # pair 3 never came back
    late = monitor(raw, [2, 3, 4], 10.15)          # started after the window opened
    silent = monitor(raw, [], None)                # never produced a cloud
    assert rig_losses([good, lossy, late, silent], (10.05, 11.0)) == \
        [(3, 0), (3, 1), (3, 3), (3, 3)]


def test_a_rig_whose_replay_stopped_early_is_counted():
    # Would catch: a driver that died 9 s into a 15 s replay pulling the rigs' common window
    # in with it, and the run held (a review's fake rigs); and, the other way, rigs whose
    # drivers started up to 3 s apart, or whose first images went out before discovery,
    # taken for stopped.
    import types
    from st_stereo.tools.latency_bench import replays_stopped_early

    def monitor(first, last):
        return types.SimpleNamespace(raw_received={} if first is None else
                                     {(0, 0): first, (1, 0): (first + last) / 2, (2, 0): last})

    full, late, died = monitor(100.0, 114.9), monitor(104.0, 118.8), monitor(100.4, 109.4)
    undiscovered = monitor(102.2, 114.9)           # its first 2.2 s went out unmatched
    assert replays_stopped_early([full, late, undiscovered], 15.0) == 0
    assert replays_stopped_early([full, late, died], 15.0) == 1
    assert replays_stopped_early([full, died, monitor(None, None)], 15.0) == 2
