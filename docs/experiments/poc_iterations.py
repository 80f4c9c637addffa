"""
Does ST need three recentring fits? (issue 17: fewer FFTs per pair).

Runs the sub-pixel protocol of docs/accuracy.md (W 9, gamma 0.1, the shared thermal frames,
noise-free and realistic) with ST's recentred estimator at 1, 2, 3 and 4 fits, all refined
on the same rough matches, and prints within 0.5 / 0.25 / 0.1 / 0.05 px per variant.
Run: ``.venv/bin/python docs/experiments/poc_iterations.py`` (about a minute).
"""

from pathlib import Path

import numpy as np
from st_stereo.tools import eval_subpixel

THERMAL = Path(__file__).resolve().parents[3] / 'shared' / 'data' / 'thermal'
FINE = tuple(np.arange(0.0, 30.0 + 1e-9, 0.125))
COARSE = tuple(np.arange(0.0, 30.0 + 1e-9, 0.5))
FRAMES = (('people_lab_180x180.png', FINE), ('panel_flir_c2_80x60.png', COARSE),
          ('ducks.png', COARSE), ('floor_heating.png', COARSE), ('moving_car.png', COARSE))
FITS = (1, 2, 3, 4)


def main():
    """Print one row per frame, degradation and number of fits."""
    eval_subpixel.ST_VARIANTS.clear()
    eval_subpixel.ST_VARIANTS.update(
        {f'{fits} fits': {'poc_iterations': fits} for fits in FITS})
    tolerances = eval_subpixel.TOLERANCES
    print('| frame | degradation | fits | ' + ' | '.join(f'within {t} px %' for t in tolerances)
          + ' | rmsd px |')
    print('|---|---|---:|' + '---:|' * (len(tolerances) + 1))
    for realistic in (False, True):
        for name, shifts in FRAMES:
            protocol = eval_subpixel.SubpixelProtocol(
                image_path=str(THERMAL / name), windows=(9,), gammas=(0.1,), shifts=shifts,
                realistic=realistic, peers=False)
            methods = eval_subpixel.evaluate(protocol)['results'][0]['methods']
            for fits in FITS:
                summary = methods[f'{fits} fits']
                cells = ' | '.join(f"{summary[f'within_{t}']:.2f}" for t in tolerances)
                kind = 'realistic' if realistic else 'noise-free'
                print(f"| {name} | {kind} | {fits} | {cells} | {summary['rmsd']:.4f} |",
                      flush=True)


if __name__ == '__main__':
    main()
