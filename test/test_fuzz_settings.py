"""The fuzz suites' split between the two ROS-free runs of ``make test`` (test/fuzz_settings.py):
each part draws its own cases, the same ones every run, and its share of the count."""
import json
import os
import subprocess
import sys
from pathlib import Path

TEST_DIR = Path(__file__).resolve().parent

DRAW = '''
import json
from hypothesis import given, strategies as st
import fuzz_settings
drawn = []
@fuzz_settings.examples(8)
@given(st.integers(0, 10 ** 9))
def draw(value):
    drawn.append(value)
draw()
print(json.dumps({"share": fuzz_settings.share(8), "drawn": drawn}))
'''


def _draw(part: str) -> dict:
    env = dict(os.environ, ZEROSHOT_FUZZ_PART=part, ZEROSHOT_FUZZ_SCALE='1', PYTHONPATH=str(TEST_DIR))
    out = subprocess.run([sys.executable, '-c', DRAW], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def test_the_two_parts_draw_different_cases_each_the_same_every_run():
    one, two = _draw('1/2'), _draw('2/2')
    assert one['share'] == two['share'] == 4 and _draw('1/1')['share'] == 8
    assert one['drawn'] and two['drawn'] and set(one['drawn']) != set(two['drawn'])
    assert _draw('1/2')['drawn'] == one['drawn']  # derandomized: CI sees the same cases every run
