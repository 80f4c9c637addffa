"""
Validated configuration of the ST matcher.

One flat, frozen dataclass. Each field carries its description and its admissible range or
choices in ``dataclasses.field(metadata=...)``: the same metadata validates the config, builds
the command-line help and (in the node suite) the ROS parameter descriptors, so the three can
never disagree.
"""

import dataclasses
import math
import typing

# Reference defaults of the noise multiplier k per phase-congruency method (Kovesi's code).
DEFAULT_NOISE_K = {'phasecong3': 2.0, 'monogenic': 3.0}


def _field(default, description, *, low=None, high=None, choices=None, odd=False):
    metadata = {'description': description, 'low': low, 'high': high, 'choices': choices,
                'odd': odd}
    return dataclasses.field(default=default, metadata=metadata)


@dataclasses.dataclass(frozen=True)
class STConfig:
    """
    Parameters of the ST pipeline: features, rough matching, sub-pixel POC.

    Every field is validated on construction (also by ``dataclasses.replace``); an invalid
    value raises ``ValueError`` naming the field, the expected range and the value received.
    """

    # --- 1. Phase-congruency features (paper section 2.2; Kovesi phasecong3) ---------------
    pc_method: str = _field(
        'phasecong3', 'phase congruency: phasecong3 (oriented log-Gabor moments, default) or '
        'monogenic (phasecongmono, M := PC; its gamma scale differs)',
        choices=('phasecong3', 'monogenic'))
    pc_scales: int = _field(4, 'number of log-Gabor scales (nscale)', low=2, high=8)
    pc_orientations: int = _field(6, 'number of filter orientations (norient, phasecong3)',
                                  low=1, high=16)
    pc_min_wavelength: float = _field(3.0, 'wavelength of the smallest-scale filter, pixels',
                                      low=2.0, high=40.0)
    pc_mult: float = _field(2.1, 'scaling factor between successive filter wavelengths',
                            low=1.1, high=5.0)
    pc_sigma_onf: float = _field(0.55, 'log-Gabor bandwidth: sigma over centre frequency',
                                 low=0.1, high=0.99)
    pc_noise_k: float = _field(-1.0, 'noise threshold in standard deviations above the mean '
                               'noise energy; negative = the method default (2 phasecong3, 3 '
                               'monogenic)', low=-1.0, high=20.0)
    pc_cutoff: float = _field(0.5, 'frequency-spread cut-off of the sigmoid weighting',
                              low=0.0, high=1.0)
    pc_gain: float = _field(10.0, 'sharpness g of the frequency-spread sigmoid', low=0.0,
                            high=100.0)
    pc_deviation_gain: float = _field(1.5, 'phase-deviation gain (monogenic only)', low=0.0,
                                      high=10.0)
    pc_periodic: bool = _field(True, 'use the periodic-plus-smooth FFT (recommended at 80x60)')
    gamma: float = _field(0.1, 'feature threshold on the maximum moment M (paper: 0.3, 0.1, '
                          '0.01)', low=0.0, high=1.0)

    # --- 2. Rough matching (paper section 2.3) --------------------------------------------
    similarity_window: int = _field(11, 'side of the Lades-similarity window on M, pixels (the '
                                    'paper: 5; 11 measured best, see docs/accuracy.md)',
                                    low=3, high=21, odd=True)
    min_similarity: float = _field(0.7, 'minimum Lades similarity of an accepted match',
                                   low=0.0, high=1.0)
    min_distinctiveness: float = _field(
        0.0, 'reject a rough match whose Lades similarity beats the best candidate more than '
        '1 px away on the row by less than this (weak texture, edges along the rows, periodic '
        'structure; docs/results.md); 0 = off', low=0.0, high=1.0)
    candidate_ratio: float = _field(0.5, 'a right pixel is a candidate when its M exceeds '
                                    'candidate_ratio * gamma', low=0.0, high=1.0)
    disparity_min: int = _field(0, 'smallest disparity searched, pixels', low=0, high=1024)
    disparity_max: int = _field(40, 'largest disparity searched, pixels', low=0, high=1024)
    prior_radius: int = _field(3, 'search radius around a disparity prior, pixels', low=0,
                               high=256)
    uniqueness: bool = _field(True, 'one-to-one matching: a right point serves one left '
                              'feature, the most similar (checked on sub-pixel positions)')
    uniqueness_tolerance: float = _field(0.5, 'two matches collide when their sub-pixel right '
                                         'positions are closer than this, pixels', low=0.0,
                                         high=2.0)
    left_right_check: bool = _field(True, 'left-right consistency check')
    left_right_tolerance: int = _field(1, 'allowed disagreement of the right-to-left search, '
                                       'pixels', low=0, high=8)
    ordering: bool = _field(True, 'ordering constraint along each row')
    continuity: bool = _field(True, 'continuity: reject disparities far from the local median')
    continuity_max_jump: float = _field(2.0, 'largest allowed |d - local median|, pixels',
                                        low=0.0, high=256.0)
    continuity_radius: int = _field(3, 'half-side of the continuity neighbourhood, pixels',
                                    low=1, high=32)
    continuity_min_neighbours: int = _field(4, 'neighbours needed before continuity applies',
                                            low=1, high=1000)

    # --- 3. Sub-pixel phase-only correlation (paper section 2.4) ----------------------------
    poc_window: int = _field(9, 'POC window side W, pixels (the peak fit needs 7 or more)',
                             low=7, high=63, odd=True)
    poc_band: str = _field('full', 'POC band limit: full (V = W) or takita (K = half of the '
                           'half-width)', choices=('full', 'takita'))
    poc_hann: bool = _field(True, 'half-sample Hann window before the FFT')
    poc_source: str = _field('intensity', 'image the POC runs on: intensity (the input counts, '
                             'measured best) or moments (M, the paper)',
                             choices=('moments', 'intensity'))
    poc_estimator: str = _field('recentred', 'sub-pixel estimator: nagashima (the paper, one '
                                'least-squares fit) or recentred (re-centre the right window '
                                'on the estimate by a Fourier shift and fit again)',
                                choices=('nagashima', 'recentred'))
    poc_iterations: int = _field(3, "fits of the recentred estimator (1 = the paper's)",
                                 low=1, high=10)
    poc_max_shift: float = _field(2.0, 'reject a sub-pixel correction larger than this, pixels '
                                  '(2 measured best: it keeps rough matches 1.5 px off)',
                                  low=0.1, high=2.5)

    # --- 4. What is published: plausible range and confidence ---------------------------
    min_range_m: float = _field(0.3, 'nearest depth published, metres (with a calibration: '
                                'turned into the largest admissible disparity)', low=0.01,
                                high=1000.0)
    max_range_m: float = _field(10.0, 'farthest depth published, metres (with a calibration: '
                                'the smallest admissible disparity; a room a few metres deep '
                                'needs no more)', low=0.01, high=1e6)
    min_confidence: float = _field(0.35, 'drop matches whose confidence (POC peak height times '
                                   'Lades distinctiveness, 0..1) is below this; 0 keeps all '
                                   '(docs/results.md: outliers against the share kept)',
                                   low=0.0, high=1.0)

    temporal_tolerance_px: float = _field(
        0.0, 'drop a static match (its window unchanged since the previous pair beyond the '
        'noise) unless the previous pair matched the same pixel within this many pixels '
        '(counted as temporal rejected_temporal_unmatched / _inconsistent; the first pair and '
        'one after a gap are not checked); 0 disables, the default: 0.3 gives fewer 3-D '
        'outliers, but the people stage then loses a person seen by a handful of points '
        '(st_stereo.core.temporal, docs/results.md)', low=0.0, high=10.0)

    point_location: str = _field(
        'structure', "where a match's 3-D point is placed: structure (the centroid of the POC "
        "window's squared Hann weight times squared horizontal gradient, where the window "
        'found its disparity: fewer 3-D outliers; the default since 2026-12-07) or feature '
        "(the feature's own pixel, the window centre); the disparity is the same, and points2 "
        "carries the feature's pixel (u, v), where the people node places each point "
        '(st_stereo.core.point_location, docs/results.md)', choices=('feature', 'structure'))

    depth_edge_check: bool = _field(
        True, 'reject a match on the cool side of a strong intensity edge unless a POC window '
        'moved half a window plus 1 px into that side finds the same disparity: weakly '
        'textured background beside a warm person otherwise carries the person disparity '
        '(st_stereo.core.depth_edges, docs/results.md)')
    depth_edge_tolerance: float = _field(1.0, 'largest disparity difference, pixels, between a '
                                         'match and the window moved into its side '
                                         '(depth_edge_check)',
                                         low=0.05, high=4.0)

    # --- 5. Camera skew (two free-running cameras; st_stereo.core.skew) --------------------
    skew_compensation: bool = _field(True, 'correct the disparities of moving features for '
                                     'the camera skew of the pair (t_right - t_left, from '
                                     'pair_info) by their image velocity on the camera whose '
                                     'frames bracket the instant of the other; a feature whose '
                                     'window did not change beyond the noise is not touched '
                                     '(docs/skew.md)')
    skew_drop_untracked: bool = _field(True, 'with skew_compensation, drop the matches whose '
                                       'window changed between the frames but could not be '
                                       'tracked (counted as skew rejected_skew_untracked), '
                                       'and, with skew_velocity poc, the moving ones the POC '
                                       'does not find again in the previous frame (counted as '
                                       'skew rejected_skew_poc): they move at an unknown '
                                       'velocity, so their skew error is unknown')
    skew_agreement_px: float = _field(0.5, 'with skew_compensation, track the moving features '
                                      'on both cameras and drop a match whose two '
                                      'displacements over the skew (v_x * skew) differ by '
                                      'more than this, pixels (counted as skew '
                                      'rejected_skew_disagreement); 0 disables',
                                      low=0.0, high=10.0)

    skew_velocity: str = _field('ncc', "with skew_compensation, how a moving feature's "
                                'velocity is measured: ncc (the NCC track alone) or poc (its '
                                'disparity measured again by the sub-pixel POC against the '
                                "bracketing camera's previous frame, the NCC track only "
                                'placing the search: better points and skew errors, but the '
                                'people stage lost a walker to a warm screen with it, so not '
                                'the default; docs/skew.md)',
                                choices=('ncc', 'poc'))

    # --- 6. Implementation ---------------------------------------------------------------
    kernels: str = _field('auto', 'hot-path implementation: compiled (numba kernels), numpy '
                          '(the reference), or auto (compiled when numba imports, else numpy); '
                          'both give the same matches (st_stereo.core.kernels, docs/speed.md)',
                          choices=('auto', 'compiled', 'numpy'))

    def __post_init__(self):
        """Validate every field against its metadata."""
        hints = typing.get_type_hints(type(self))
        for field in dataclasses.fields(self):
            _validate_field(field, hints[field.name], getattr(self, field.name))
        if self.disparity_min > self.disparity_max:
            raise ValueError(f'disparity_min ({self.disparity_min}) must not exceed '
                             f'disparity_max ({self.disparity_max})')
        if self.min_range_m >= self.max_range_m:
            raise ValueError(f'min_range_m ({self.min_range_m}) must be less than max_range_m '
                             f'({self.max_range_m})')

    @property
    def noise_k(self):
        """Noise multiplier k in effect (the method default when ``pc_noise_k`` < 0)."""
        return DEFAULT_NOISE_K[self.pc_method] if self.pc_noise_k < 0 else self.pc_noise_k

    @property
    def poc_margin(self):
        """Half-width of the POC window."""
        return self.poc_window // 2

    @classmethod
    def from_mapping(cls, values):
        """Build a config from a mapping, rejecting unknown keys by name."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f'unknown ST parameter(s): {", ".join(unknown)}; known: '
                             f'{", ".join(sorted(known))}')
        return cls(**dict(values))

    def to_dict(self):
        """Return the fields as a plain dict."""
        return dataclasses.asdict(self)


def describe_fields():
    """Yield ``(name, type, default, metadata)`` for every config field, in declaration order."""
    hints = typing.get_type_hints(STConfig)
    for field in dataclasses.fields(STConfig):
        yield field.name, hints[field.name], field.default, field.metadata


def _validate_field(field, expected_type, value):
    name = field.name
    meta = field.metadata
    if expected_type is bool:
        if not isinstance(value, bool):
            raise ValueError(f'{name}: expected a bool, got {value!r}')
        return
    if expected_type is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f'{name}: expected an integer, got {value!r}')
    elif expected_type is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f'{name}: expected a number, got {value!r}')
        if not math.isfinite(value):
            raise ValueError(f'{name}: expected a finite number, got {value!r}')
    elif expected_type is str:
        if not isinstance(value, str):
            raise ValueError(f'{name}: expected a string, got {value!r}')
    if meta.get('choices') and value not in meta['choices']:
        raise ValueError(f'{name}: expected one of {", ".join(meta["choices"])}, got {value!r}')
    low, high = meta.get('low'), meta.get('high')
    if low is not None and value < low or high is not None and value > high:
        raise ValueError(f'{name}: expected a value in [{low}, {high}], got {value!r}')
    if meta.get('odd') and value % 2 != 1:
        raise ValueError(f'{name}: expected an odd number, got {value!r}')


def parse_bool(text):
    """Return a true/false text as a bool (true/false, 1/0, yes/no, on/off, any case)."""
    lowered = str(text).strip().lower()
    if lowered in ('true', '1', 'yes', 'on'):
        return True
    if lowered in ('false', '0', 'no', 'off'):
        return False
    raise ValueError(f'expected true or false, got {text!r}')


def _parse_value(text, kind):
    """Parse one ``--set`` value as the field's type."""
    return parse_bool(text) if kind is bool else kind(text)


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
