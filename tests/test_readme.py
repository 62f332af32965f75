"""The README's command lines run as written (at tiny network sizes and step counts)."""

import os
import re
import shlex

import pytest

README = os.path.join(os.path.dirname(__file__), "..", "README.md")
TINY = ["steps=20", "chunk_steps=10", "enc_steps=10", "d=8", "f_pre_hidden=16", "f_pre_out=16",
        "f_hidden=16", "b_hidden=16", "batch_size=16", "eval_episode_len=10", "context_len=10",
        "enc_embed=16", "enc_mlp=16", "pred_hidden=16", "eval_protocols=official"]


def readme_commands() -> list[list[str]]:
    """argv of every `python -m zsbfm ...` line in the README's bash blocks."""
    text = open(README).read()
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        for line in block.splitlines():
            line = line.split("#")[0].strip()
            if line.startswith("python -m zsbfm "):
                lines.append(shlex.split(line)[3:])
    return lines


def tiny(argv: list[str]) -> list[str]:
    """argv with the tiny overrides appended to its --set (train, sweep) and fewer episodes."""
    if argv[0] not in ("train", "sweep"):
        return argv
    extra = TINY + ([] if "--dataset" in argv else ["episodes_per_layout=10", "n_train_layouts=3"])
    if "--set" in argv:
        i = argv.index("--set") + 1
        while i < len(argv) and not argv[i].startswith("--"):
            i += 1
        return argv[:i] + extra + argv[i:]
    return argv + ["--set", *extra]


def test_readme_has_the_commands():
    cmds = [c[0] for c in readme_commands()]
    assert {"train", "evaluate", "collect", "sweep"} <= set(cmds)


@pytest.mark.slow  # about 3.5 min alone: every README command, each compiled
def test_readme_commands_run(tmp_path, monkeypatch, capsys):
    from zsbfm.cli import main

    monkeypatch.chdir(tmp_path)
    for argv in readme_commands():
        if argv[0] == "collect":  # the dataset the next line trains on: keep it small
            argv = argv + ["--n-train", "3", "--episodes-per-layout", "10"]
        if "--dataset" in argv:
            argv = tiny(argv) + []
            i = argv.index("--set") + 1
            argv[i:i] = ["n_train_layouts=3", "episodes_per_layout=10"]
        else:
            argv = tiny(argv)
        try:
            main(argv)
        except SystemExit as e:
            pytest.fail(f"`python -m zsbfm {' '.join(argv)}` exited with {e.code}: {capsys.readouterr().err}")
    out = capsys.readouterr().out
    assert "success_per_seed" in out and "test  success" in out
