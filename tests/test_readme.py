"""The README's runnable examples run and print what they show (every block marked
``<!-- test: run -->``), and the example for your own plant stays within 40 lines."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"
BLOCK = re.compile(r"<!-- test: run -->\s*```python\n(.*?)```", re.DOTALL)


def blocks():
    return BLOCK.findall(README.read_text(encoding="utf-8"))


def test_the_readme_marks_its_examples():
    assert len(blocks()) >= 2


def test_the_own_plant_example_is_short():
    own = blocks()[0]
    assert "SafeSwitch" in own and len(own.strip().splitlines()) <= 40


@pytest.mark.parametrize("index", range(len(blocks())))
def test_each_readme_example_runs(index, tmp_path):
    code = blocks()[index]
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    printed = [line for line in code.splitlines() if line.lstrip().startswith("print(")]
    assert len(done.stdout.strip().splitlines()) >= len(printed)  # it prints what it shows
