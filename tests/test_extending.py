"""The worked examples of docs/extending.md run as written (tiny sizes)."""

import os
import re

import pytest

DOC = os.path.join(os.path.dirname(__file__), "..", "docs", "extending.md")


def examples():
    with open(DOC) as f:
        return re.findall(r"```python\n(.*?)```", f.read(), re.S)


def test_there_are_three_examples():
    assert len(examples()) == 3


@pytest.mark.parametrize("i", range(3), ids=["environment", "algorithm", "data_source"])
def test_example_runs(tmp_path, i, capsys):
    exec(compile(examples()[i], f"extending.md example {i}", "exec"), {"RUNS": str(tmp_path), "__name__": "example"})
    out = capsys.readouterr().out
    assert out.strip(), "the example prints its result"
