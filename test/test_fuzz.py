"""A short run of every fuzz target of .ci/fuzz.py (atheris): no input raises anything else."""

import pathlib
import re
import subprocess
import sys

import pytest

FUZZ = pathlib.Path(__file__).resolve().parents[1] / '.ci' / 'fuzz.py'


@pytest.mark.parametrize('target', ['vospi', 'capture', 'calibration', 'bag_metadata'])
def test_fuzz_target_runs_without_a_crash(target, tmp_path):
    # Bounded in inputs, not time: the same amount of fuzzing on a fast or a loaded machine.
    result = subprocess.run([sys.executable, str(FUZZ), target, '--runs', '300',
                             '--seconds', '120', '--keep', str(tmp_path)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    row = re.search(rf'^\| {target} \| ([\d,]+) \|', result.stdout, re.MULTILINE)
    assert row and int(row.group(1).replace(',', '')) >= 290, result.stdout   # new inputs
    assert not list(tmp_path.glob('crash-*'))
