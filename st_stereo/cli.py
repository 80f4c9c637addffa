"""
Command line ``st-stereo`` (also ``python -m st_stereo``).

    st-stereo match LEFT RIGHT [--calibration LEFT_YAML RIGHT_YAML] [--out FILE.csv|.json]
    st-stereo features IMAGE [--overlay out.png]
    st-stereo eval subpixel --image IMG [...]
    st-stereo bench [...]
    st-stereo demo [...]

Every ST parameter can be set with ``--set NAME=VALUE`` (see ``st-stereo params``).
Errors in the input are reported as one line naming the file and the problem, exit code 2.
"""

import argparse
import json
import sys

from st_stereo.core.config import describe_fields, STConfig


def _parse_value(text, kind):
    if kind is bool:
        lowered = text.lower()
        if lowered in ('true', '1', 'yes', 'on'):
            return True
        if lowered in ('false', '0', 'no', 'off'):
            return False
        raise ValueError(f'expected true or false, got {text!r}')
    return kind(text)


def config_from_assignments(assignments):
    """Build an STConfig from ``NAME=VALUE`` strings (types from the config fields)."""
    kinds = {name: kind for name, kind, _, _ in describe_fields()}
    values = {}
    for assignment in assignments or ():
        name, sep, text = assignment.partition('=')
        if not sep:
            raise ValueError(f'--set: expected NAME=VALUE, got {assignment!r}')
        if name not in kinds:
            raise ValueError(f'--set: unknown ST parameter {name!r} (see st-stereo params)')
        try:
            values[name] = _parse_value(text, kinds[name])
        except ValueError as error:
            raise ValueError(f'--set {name}: {error}') from None
    return STConfig(**values)


def _add_config_option(parser):
    parser.add_argument('--set', action='append', metavar='NAME=VALUE', default=[],
                        help='set an ST parameter (repeatable; list: st-stereo params)')


def _allowed_values(kind, meta):
    if meta['choices']:
        return ' / '.join(meta['choices'])
    if meta['low'] is not None:
        odd = ', odd' if meta['odd'] else ''
        return f'[{meta["low"]}, {meta["high"]}]{odd}'
    return kind.__name__


def parameters_markdown():
    """Return the Markdown table of every ST parameter (the README's parameter section)."""
    lines = ['| parameter | default | allowed | meaning |', '|---|---|---|---|']
    for name, kind, default, meta in describe_fields():
        lines.append(f'| `{name}` | `{default!r}` | {_allowed_values(kind, meta)} | '
                     f'{meta["description"]} |')
    return '\n'.join(lines)


def command_params(args):
    """Print every ST parameter with its default, range and description."""
    if args.markdown:
        print(parameters_markdown())
        return 0
    for name, kind, default, meta in describe_fields():
        print(f'{name} = {default!r}  ({_allowed_values(kind, meta)})\n'
              f'    {meta["description"]}')
    return 0


def command_match(args):
    """Match a pair and write the matches (CSV or JSON), print a summary."""
    from st_stereo.core.camera_calibration import load_calibration
    from st_stereo.core.image_io import read_thermal_image
    from st_stereo.core.matcher import StereoMatcher
    from st_stereo.core.rectification import StereoRectifier

    config = config_from_assignments(args.set)
    left = read_thermal_image(args.left)
    right = read_thermal_image(args.right)
    model = None
    if args.calibration:
        rectifier = StereoRectifier(load_calibration(args.calibration[0]),
                                    load_calibration(args.calibration[1]))
        model = rectifier.model
        if not args.rectified:
            left, right = rectifier.rectify(left, right)
    result = StereoMatcher(config, model).match(left, right)
    if args.out:
        if args.out.endswith('.json'):
            text = result.to_json()
        elif args.out.endswith('.csv'):
            text = result.to_csv()
        else:
            raise ValueError(f'--out {args.out}: expected a .csv or .json file name')
        with open(args.out, 'w', encoding='utf-8') as stream:
            stream.write(text)
    summary = {'matches': len(result), 'counts': result.counts,
               'timings_ms': {k: round(v, 3) for k, v in result.timings_ms.items()}}
    if len(result):
        summary['disparity_px'] = {'min': float(result.disparity.min()),
                                   'median': float(sorted(result.disparity)[len(result) // 2]),
                                   'max': float(result.disparity.max())}
    print(json.dumps(summary, indent=1))
    return 0


def command_features(args):
    """Count phase-congruency features of one image; optionally draw them on it."""
    import cv2
    import numpy as np

    from st_stereo.core.image_io import contrast_stretch_u8, read_thermal_image
    from st_stereo.core.matcher import validate_image
    from st_stereo.core.phase_congruency import feature_strength

    config = config_from_assignments(args.set)
    image = validate_image(read_thermal_image(args.image), args.image)
    moments = feature_strength(image, config)
    features = moments > config.gamma
    print(json.dumps({'image': args.image, 'size': [image.shape[1], image.shape[0]],
                      'method': config.pc_method, 'gamma': config.gamma,
                      'features': int(features.sum()),
                      'moment_max': float(moments.max())}, indent=1))
    if args.overlay:
        scale = args.scale
        base = cv2.resize(contrast_stretch_u8(image), None, fx=scale, fy=scale,
                          interpolation=cv2.INTER_NEAREST)
        overlay = cv2.cvtColor(base, cv2.COLOR_GRAY2BGR)
        for y, x in zip(*np.nonzero(features)):
            centre = (int(x * scale + scale // 2), int(y * scale + scale // 2))
            cv2.circle(overlay, centre, max(1, scale // 3), (0, 0, 255), -1)
        if not cv2.imwrite(args.overlay, overlay):
            raise ValueError(f'--overlay {args.overlay}: could not write the image')
    return 0


def command_eval(args):
    """Run the sub-pixel accuracy protocol; print tables, write JSON / plot / Markdown."""
    from tqdm import tqdm

    from st_stereo.tools import eval_subpixel as ev

    width, _, height = args.size.partition('x')
    reports = []
    for image in args.image:
        protocol = ev.SubpixelProtocol(
            image_path=image, size=(int(width), int(height)),
            windows=tuple(int(w) for w in args.windows.split(',')),
            gammas=tuple(float(g) for g in args.gammas.split(',')),
            shifts=ev.parse_shifts(args.shifts), noise_counts=args.noise_counts,
            realistic=args.realistic, peers=not args.no_peers, seed=args.seed)
        report = ev.evaluate(protocol, progress_factory=lambda total, name=image: tqdm(
            total=total, desc=name.split('/')[-1], unit='pair', disable=args.quiet))
        reports.append(report)
        print(f'\n## {image} ({"realistic" if args.realistic else "noise-free"})\n')
        print(ev.markdown_table(report))
    if args.json:
        ev.write_json(reports[0] if len(reports) == 1 else reports, args.json)
    if args.plot:
        ev.plot_report(reports[0], args.plot)
    if args.markdown:
        with open(args.markdown, 'w', encoding='utf-8') as stream:
            for report in reports:
                stream.write(f'## {report["image"].split("/")[-1]}\n\n')
                stream.write(ev.markdown_table(report))
                stream.write('\n')
    return 0


def command_bench(args):
    """Time every stage of ST against StereoSGBM and ORB + KNN; print one table."""
    from st_stereo.tools import bench
    return bench.main(args)


def command_demo(args):
    """Run ST on a simulated pair sequence and print what it produced."""
    from st_stereo.tools import demo
    return demo.main(args)


def build_parser():
    """Return the argument parser of ``st-stereo``."""
    parser = argparse.ArgumentParser(prog='st-stereo', description=__doc__.split('\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', required=True)

    p = sub.add_parser('params', help='list the ST parameters')
    p.add_argument('--markdown', action='store_true', help='as a Markdown table')
    p.set_defaults(handler=command_params)

    p = sub.add_parser('match', help='match a stereo pair')
    p.add_argument('left')
    p.add_argument('right')
    p.add_argument('--calibration', nargs=2, metavar=('LEFT_YAML', 'RIGHT_YAML'),
                   help='camera_calibration files: rectify the pair with them and add 3-D '
                        'points')
    p.add_argument('--rectified', action='store_true',
                   help='the images are already rectified (use the calibration for 3-D only)')
    p.add_argument('--out', help='write the matches to FILE.csv or FILE.json')
    _add_config_option(p)
    p.set_defaults(handler=command_match)

    p = sub.add_parser('features', help='phase-congruency features of an image')
    p.add_argument('image')
    p.add_argument('--overlay', help='write a PNG with the features drawn on the image')
    p.add_argument('--scale', type=int, default=8, help='overlay magnification (default 8)')
    _add_config_option(p)
    p.set_defaults(handler=command_features)

    p = sub.add_parser('eval', help='evaluations')
    eval_sub = p.add_subparsers(dest='evaluation', required=True)
    e = eval_sub.add_parser('subpixel', help="the paper's sub-pixel accuracy protocol")
    e.add_argument('--image', action='append', required=True,
                   help='frame to shift (repeatable: one table per image)')
    e.add_argument('--size', default='80x60', help='resize to WIDTHxHEIGHT (default 80x60)')
    e.add_argument('--windows', default='7,9,11,13', help='POC window sizes W')
    e.add_argument('--gammas', default='0.3,0.1,0.01', help='feature thresholds gamma')
    e.add_argument('--shifts', default='0:30:0.125', help='start:stop:step or a list, pixels')
    e.add_argument('--noise-counts', type=float, default=0.0,
                   help='independent Gaussian noise on each image, counts (std)')
    e.add_argument('--realistic', action='store_true',
                   help='1 %% noise and a 1.05 gain / 2 %% offset difference on the right')
    e.add_argument('--no-peers', action='store_true', help='evaluate ST only')
    e.add_argument('--seed', type=int, default=0)
    e.add_argument('--json', help='write the results as JSON')
    e.add_argument('--plot', help='write a PNG plot (paper Figs. 8-9 style)')
    e.add_argument('--markdown', help='write the tables as Markdown')
    e.add_argument('--quiet', action='store_true', help='no progress bar')
    e.set_defaults(handler=command_eval)

    p = sub.add_parser('bench', help='speed of ST vs StereoSGBM and ORB + KNN')
    p.add_argument('--pairs', type=int, default=200, help='timed pairs per size')
    p.add_argument('--sizes', default='80x60,160x120,640x512')
    p.add_argument('--memory-pairs', type=int, default=10000,
                   help='pairs for the memory-flatness run at 80x60 (0 = skip)')
    p.add_argument('--image', default=None, help='source frame (default: a shared frame)')
    _add_config_option(p)
    p.set_defaults(handler=command_bench)

    p = sub.add_parser('demo', help='run ST on a simulated pair sequence (the main job)')
    p.add_argument('--frames', type=int, default=40)
    p.add_argument('--image', default=None, help='texture frame (default: a shared frame)')
    _add_config_option(p)
    p.set_defaults(handler=command_demo)
    return parser


def main(argv=None):
    """Entry point of ``st-stereo``; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except (OSError, ValueError) as error:
        print(f'st-stereo {args.command}: error: {error}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
