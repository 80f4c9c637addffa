"""
The simulated rig's command line: ``st-stereo sim list | record | render``.

``record`` writes a recording directory (rosbag2 + calibration + ground truth); the bundled
default recording is regenerated with
``st-stereo sim record --sequence office --out data/recordings/office --overwrite``.
``render`` writes one pair and its ground truth as PNG / NPZ for a look.
"""

import pathlib


def command_list(args):
    """Print the named sequences."""
    from st_stereo.sim.sequences import standard_sequences
    for name, spec in standard_sequences().items():
        print(f'{name:12s} {len(spec.frame_times):4d} pairs  {spec.duration_s:5.1f} s  '
              f'{spec.description}')
    return 0


def _spec(name):
    from st_stereo.sim.sequences import standard_sequences
    sequences = standard_sequences()
    if name not in sequences:
        raise ValueError(f'--sequence: unknown sequence {name!r}; expected one of '
                         f'{", ".join(sequences)}')
    return sequences[name]


def command_record(args):
    """Render a sequence into a recording directory."""
    from tqdm import tqdm

    from st_stereo.sim.recording import write_recording
    from st_stereo.sim.sequences import SequenceRenderer
    spec = _spec(args.sequence)
    bar = tqdm(total=len(spec.frame_times), desc=spec.name, unit='pair', disable=args.quiet)

    def progress(done, total):
        bar.update(done - bar.n)
    try:
        summary = write_recording(SequenceRenderer(spec, supersample=args.supersample),
                                  args.out, namespace=args.namespace, progress=progress,
                                  overwrite=args.overwrite)
    finally:
        bar.close()
    print(f'{summary["path"]}: {summary["frames"]} pairs, {summary["bytes"] / 1e6:.2f} MB')
    for name, size in sorted(summary['sizes'].items()):
        print(f'  {name:20s} {size / 1e3:9.1f} kB')
    return 0


def command_render(args):
    """Render one pair of a sequence to PNG (contrast-stretched, magnified) and NPZ."""
    import cv2
    import numpy as np

    from st_stereo.core.image_io import contrast_stretch_u8
    from st_stereo.sim.sequences import SequenceRenderer
    spec = _spec(args.sequence)
    frame = SequenceRenderer(spec).frame(args.time)
    out = pathlib.Path(args.out)
    scale = args.scale
    views = [cv2.resize(contrast_stretch_u8(frame[side]), None, fx=scale, fy=scale,
                        interpolation=cv2.INTER_NEAREST) for side in ('left', 'right')]
    disparity = frame['truth'].disparity
    disparity = cv2.applyColorMap(np.clip(disparity * 255 / max(disparity.max(), 1e-9), 0,
                                          255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    disparity = cv2.resize(disparity, None, fx=scale, fy=scale,
                           interpolation=cv2.INTER_NEAREST)
    image = np.hstack([cv2.cvtColor(v, cv2.COLOR_GRAY2BGR) for v in views] + [disparity])
    if not cv2.imwrite(str(out.with_suffix('.png')), image):
        raise ValueError(f'--out {out}: could not write the PNG')
    truth = frame['truth']
    np.savez_compressed(out.with_suffix('.npz'), left=frame['left'], right=frame['right'],
                        depth=truth.depth, disparity=truth.disparity, labels=truth.labels,
                        heads_rectified=frame['heads_rectified'])
    print(f'wrote {out.with_suffix(".png")} (left, right, true disparity) and '
          f'{out.with_suffix(".npz")}')
    return 0


def command_calibration(args):
    """Render pairs of a heated target (images + the true calibration) for ``calibrate``."""
    from st_stereo.core.calibration.targets import CalibrationTarget
    from st_stereo.core.calibration.files import save_calibration
    from st_stereo.sim.rig import realistic_rig
    from st_stereo.sim.targets import render_calibration_pairs
    target = CalibrationTarget(args.target, args.rows, args.cols, args.spacing)
    rig = realistic_rig()
    pairs, _ = render_calibration_pairs(rig, target, args.pairs, seed=args.seed,
                                        warm_features=not args.cold_features)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written = _write_pairs(pairs, out, args.bag, args.overwrite)
    for side, calibration in zip(('left', 'right'), rig.calibrations()):
        save_calibration(calibration, out / f'true_{side}.yaml')
    print(f'wrote {len(pairs)} pairs of a {args.target} target to {written} and '
          f'the true calibration to {out}/true_left.yaml, true_right.yaml; baseline '
          f'{rig.baseline_m:.4f} m')
    return 0


def _write_pairs(pairs, out, bag, overwrite):
    """Write raw pairs as OUT/left, OUT/right PNGs or as OUT/bag; return what was written."""
    import cv2
    if bag:
        from st_stereo.sim.recording import write_pairs_bag
        return f'the bag {write_pairs_bag(pairs, out / "bag", overwrite=overwrite)}'
    for side in ('left', 'right'):
        (out / side).mkdir(parents=True, exist_ok=True)
    for index, pair in enumerate(pairs):
        for side, image in zip(('left', 'right'), pair):
            if not cv2.imwrite(str(out / side / f'{index:03d}.png'), image):
                raise ValueError(f'{out / side}: could not write the images')
    return f'{out}/left, {out}/right'


def command_floor_target(args):
    """Render pairs of a target lying on a room's floor (+ the true calibration and pose)."""
    import dataclasses

    from st_stereo.core.calibration.files import save_calibration
    from st_stereo.core.calibration.targets import CalibrationTarget
    from st_stereo.core.rig_pose import rig_pose_yaml
    from st_stereo.sim.rig import realistic_rig
    from st_stereo.sim.targets import render_floor_target_pairs
    target = CalibrationTarget(args.target, args.rows, args.cols, args.spacing)
    rig = dataclasses.replace(realistic_rig(), mount_height_m=args.rig_height,
                              tilt_deg=args.rig_tilt, roll_deg=args.rig_roll)
    pairs = render_floor_target_pairs(rig, target, tuple(args.at), args.yaw, args.pairs,
                                      room=args.room, thickness_m=args.thickness,
                                      seed=args.seed)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written = _write_pairs(pairs, out, args.bag, args.overwrite)
    for side, calibration in zip(('left', 'right'), rig.calibrations()):
        save_calibration(calibration, out / f'{side}.yaml')
    pose = rig.rig_pose()
    (out / 'true_rig_pose.yaml').write_text(rig_pose_yaml(
        pose, ["# The simulated rig's true pose (st-stereo sim floor-target)."]))
    print(f'wrote {len(pairs)} pairs of a {args.target} target on the floor of {args.room} to '
          f'{written}, the true calibration to {out}/left.yaml, right.yaml and the true pose '
          f'to {out}/true_rig_pose.yaml (height {pose.height_m} m, tilt {pose.tilt_deg:.3f}, '
          f'roll {pose.roll_deg:.3f} deg)')
    return 0


def add_parser(sub):
    """Add ``sim`` and its subcommands to the ``st-stereo`` parser."""
    p = sub.add_parser('sim', help='the simulated rig: sequences, recordings with ground truth')
    sim = p.add_subparsers(dest='sim_command', required=True)
    s = sim.add_parser('list', help='list the named sequences')
    s.set_defaults(handler=command_list)
    s = sim.add_parser('record', help='render a sequence to a rosbag2 recording with truth')
    s.add_argument('--sequence', default='office', help='sequence name (see sim list)')
    s.add_argument('--out', required=True, help='recording directory')
    s.add_argument('--namespace', default='/stereo', help='topic namespace (default /stereo)')
    s.add_argument('--supersample', type=int, default=4,
                   help='rays per pixel side (default 4: 16 rays per pixel)')
    s.add_argument('--overwrite', action='store_true', help='replace an existing recording')
    s.add_argument('--quiet', action='store_true', help='no progress bar')
    s.set_defaults(handler=command_record)
    s = sim.add_parser('render', help='render one pair and its ground truth (PNG + NPZ)')
    s.add_argument('--sequence', default='office')
    s.add_argument('--time', type=float, default=0.0, help='seconds into the sequence')
    s.add_argument('--out', required=True, help='output path without extension')
    s.add_argument('--scale', type=int, default=4, help='PNG magnification')
    s.set_defaults(handler=command_render)
    s = sim.add_parser('calibration', help='render pairs of a heated calibration target')
    s.add_argument('--target', default='circles', choices=('circles', 'acircles', 'chessboard'))
    s.add_argument('--rows', type=int, default=5)
    s.add_argument('--cols', type=int, default=7)
    s.add_argument('--spacing', type=float, default=0.1, help='metres')
    s.add_argument('--pairs', type=int, default=200)
    s.add_argument('--bag', action='store_true',
                   help='write OUT/bag (rosbag2, raw image topics) instead of PNG pairs')
    s.add_argument('--overwrite', action='store_true', help='replace an existing OUT/bag')
    s.add_argument('--cold-features', action='store_true',
                   help='cold circles / holes in a warm plate (default: warm on cold)')
    s.add_argument('--seed', type=int, default=0)
    s.add_argument('--out', required=True, help='output directory')
    s.set_defaults(handler=command_calibration)
    s = sim.add_parser('floor-target', help='render pairs of a target lying on the floor '
                       '(for st-stereo rig-pose)')
    s.add_argument('--target', default='circles', choices=('circles', 'acircles', 'chessboard'))
    s.add_argument('--rows', type=int, default=4)
    s.add_argument('--cols', type=int, default=5)
    s.add_argument('--spacing', type=float, default=0.25, help='metres (default 0.25)')
    s.add_argument('--at', type=float, nargs=2, default=(0.0, 2.4), metavar=('X', 'Y'),
                   help="the grid's centre on the floor, metres (room: x right, y away from "
                   'the rig; default 0 2.4)')
    s.add_argument('--yaw', type=float, default=0.0, help="the target's turn on the floor, deg")
    s.add_argument('--thickness', type=float, default=0.005, help='metres (default 0.005)')
    s.add_argument('--room', default='office', choices=('office', 'meeting_room', 'open_office'))
    s.add_argument('--rig-height', type=float, default=2.9, help='metres (default 2.9)')
    s.add_argument('--rig-tilt', type=float, default=40.0,
                   help='degrees below the horizontal (default 40)')
    s.add_argument('--rig-roll', type=float, default=0.0, help='degrees (default 0)')
    s.add_argument('--pairs', type=int, default=20)
    s.add_argument('--bag', action='store_true',
                   help='write OUT/bag (rosbag2, raw image topics) instead of PNG pairs')
    s.add_argument('--overwrite', action='store_true', help='replace an existing OUT/bag')
    s.add_argument('--seed', type=int, default=0)
    s.add_argument('--out', required=True, help='output directory')
    s.set_defaults(handler=command_floor_target)
