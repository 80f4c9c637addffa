"""
Faster features at the same accuracy? (issue 17: fewer FFTs per pair; docs/speed.md).

Runs the sub-pixel protocol of docs/accuracy.md (W 9, gamma 0.1, ``min_confidence`` 0 as
there, the shared thermal frames, noise-free and realistic) with the whole ST pipeline under
each feature variant (the matcher's ``STConfig`` replaced by the variant's: its own features,
rough matches and refinement) and prints within 0.5 / 0.25 / 0.1 / 0.05 px per variant. The
default row reproduces docs/accuracy.md's ST figures.
Run: ``.venv/bin/python docs/experiments/feature_variants.py`` (about five minutes).
"""

from poc_iterations import FRAMES, THERMAL   # the protocol's frames and shifts, as there
from st_stereo.tools import eval_subpixel

VARIANTS = {'default (phasecong3, 6 orientations, 4 scales)': {},
            'monogenic': {'pc_method': 'monogenic'},
            '4 orientations': {'pc_orientations': 4},
            '3 scales': {'pc_scales': 3}}


def main():
    """Print one row per frame, degradation and variant."""
    eval_subpixel.ST_VARIANTS.clear()
    config_class = eval_subpixel.STConfig
    tolerances = eval_subpixel.TOLERANCES
    print('| frame | degradation | variant | features | ' +
          ' | '.join(f'within {t} px %' for t in tolerances) + ' | rmsd px |')
    print('|---|---|---|---:|' + '---:|' * (len(tolerances) + 1))
    try:
        for realistic in (False, True):
            for name, shifts in FRAMES:
                for variant, changes in VARIANTS.items():
                    eval_subpixel.STConfig = _variant_config(config_class, changes)
                    protocol = eval_subpixel.SubpixelProtocol(
                        image_path=str(THERMAL / name), windows=(9,), gammas=(0.1,),
                        shifts=shifts, realistic=realistic, peers=False)
                    summary = eval_subpixel.evaluate(protocol)['results'][0]['methods']['ST']
                    cells = ' | '.join(f"{summary[f'within_{t}']:.2f}" for t in tolerances)
                    kind = 'realistic' if realistic else 'noise-free'
                    print(f"| {name} | {kind} | {variant} | {summary['features']} | {cells} | "
                          f"{summary['rmsd']:.4f} |", flush=True)
    finally:
        eval_subpixel.STConfig = config_class


def _variant_config(config_class, changes):
    def make(**fields):
        return config_class(**{'min_confidence': 0.0, **fields, **changes})
    return make


if __name__ == '__main__':
    main()
