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


def test_drivers_never_branch_on_an_env_name():
    """train, evaluate, cli, run, plots, config and data ask the env's registered facts
    (zsbfm.envs.registry.EnvSpec), never compare cfg.env with a built-in env's name, so a
    registered env works through every driver."""
    import glob

    from zsbfm.envs import env_names

    src = os.path.join(os.path.dirname(__file__), "..", "src", "zsbfm")
    names = "|".join(env_names())
    compare = re.compile(rf"""(==|!=|\bin)\s*[\(\[\{{]?\s*["']({names})["']""")
    files = [os.path.join(src, f"{m}.py") for m in ("train", "evaluate", "cli", "run", "plots", "config", "sweep")]
    files += glob.glob(os.path.join(src, "data", "*.py"))
    hits = [f"{os.path.relpath(f, src)}:{i}: {line.strip()}" for f in files
            for i, line in enumerate(open(f), 1) if compare.search(line)]
    assert not hits, hits


def test_callers_ask_the_env_contract_instead_of_probing():
    """Every built-in env subclasses EnvBase (the optional capabilities with their defaults),
    and no caller probes an env with hasattr / getattr."""
    import glob

    import zsbfm
    from zsbfm.envs import EnvBase, env_names

    envs = {name: zsbfm.make_env(name) for name in env_names() if name != "antwind"}  # antwind: MJX, slow
    assert all(isinstance(e, EnvBase) for e in envs.values())
    assert envs["fourrooms"].behaviour_policy(None) is None and envs["fourrooms"].metric == "success"
    from zsbfm.envs.antwind import AntWind

    assert issubclass(AntWind, EnvBase) and AntWind.metric == "return"
    src = os.path.join(os.path.dirname(__file__), "..", "src", "zsbfm")
    probe = re.compile(r"\b(hasattr|getattr)\((self\.)?env\b")
    hits = [f"{os.path.relpath(f, src)}:{i}: {line.strip()}" for f in glob.glob(os.path.join(src, "**", "*.py"), recursive=True)
            for i, line in enumerate(open(f), 1) if probe.search(line)]
    assert not hits, hits
