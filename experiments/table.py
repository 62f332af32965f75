"""The reproduction harness for the paper's Tables 1-2 and Figure 1.

    make table ENV=fourrooms                     # = python experiments/table.py --env fourrooms
    python experiments/table.py --env doors --algos fb bfb rfb --set steps=6000

Every method is an ordinary `zsbfm.train` run of its CPU preset with 3 vmapped seeds,
under runs/<env>-<algo>-<size>/ (with --set overrides: runs/<env>-<algo>-<size>-<hash>/).
A finished method (its results.json written by the same config) is read back, not
retrained; an unfinished one resumes from its last checkpoint; so a killed sweep picks up
where it stopped. A directory holding another config is moved aside, never deleted. Writes

    results/<env>.json   per method: success per seed (train / test), wall times, run dir,
                         the date and commit it was measured at
    results/<env>.md     mean +- std over seeds beside the paper's values, wall time
    results/<env>.png    bar chart of train and test success (the paper's Figure 1)
    (another --size writes results/<env>_<size>.*)

A table of some methods (--algos) merges into an existing results/<env>.json of the same
env, size, seeds and overrides: the other methods' rows are kept as they were measured
(each row says when), so a table can be filled one method at a time.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import subprocess
import time

import numpy as np

import zsbfm
from zsbfm.config import SIZES, Config
from zsbfm.evaluate import metric_of

# The paper's Tables 2 (train) and 1 (test): (train, test) success.
PAPER = {
    "fourrooms": {"random": (0.18, 0.05), "fb": (0.25, 0.15), "hilp": (0.40, 0.20), "lap": (0.20, 0.10),
                  "bfb": (0.70, 0.40), "rfb": (0.85, 0.61)},
    "pointmass": {"random": (0.00, 0.03), "fb": (0.20, 0.10), "hilp": (0.45, 0.25), "lap": (0.15, 0.10),
                  "bfb": (0.76, 0.45), "rfb": (0.88, 0.55)},
    # AntWind: episode returns (256 steps). Random's test 250 (= FB's) is as printed in the
    # paper's Table 1, though it is far above Random's train -190
    "antwind": {"random": (-190, 250), "fb": (390, 250), "hilp": (410, 410), "lap": (340, 290),
                "bfb": (680, 550), "rfb": (740, 640)},
}
NAMES = {"random": "Random", "fb": "FB", "hilp": "HILP", "lap": "Laplacian", "bfb": "Belief-FB",
         "rfb": "Rotation-FB", "oracle": "Oracle FB (true layout id)"}
ORDER = ("random", "fb", "hilp", "lap", "bfb", "rfb", "oracle")


def sweep_config(env: str, algo: str, size: str, seeds: int, runs_dir: str, overrides,
                 name: str = "", **fields) -> Config:
    """The preset (with `fields`) and then `overrides` (field=value strings), named `name`
    (default <env>-<algo>-<size>). Overridden runs get "-<hash of the overrides>" appended
    (unless the overrides name the run), so they never touch the preset's runs."""
    cfg = Config.preset(env, algo, size, num_seeds=seeds, runs_dir=runs_dir, name=name, **fields)
    cfg = cfg.with_overrides(overrides)
    if overrides and cfg.name == name:
        digest = hashlib.sha1(" ".join(sorted(overrides)).encode()).hexdigest()[:8]
        cfg = dataclasses.replace(cfg, name=f"{cfg.run_name}-{digest}")
    return cfg


def _same_run(path: str, cfg: Config) -> bool:
    """Whether runs/<name>/config.json describes cfg (where it is stored does not count)."""
    try:
        with open(path) as f:
            old = Config.from_dict(json.load(f))
    except (ValueError, TypeError):  # written by an older Config with other fields
        return False
    keep = dict(runs_dir=cfg.runs_dir, name=cfg.name, checkpoint=cfg.checkpoint)
    return dataclasses.replace(old, **keep) == cfg


def finished_results(cfg: Config) -> dict | None:
    """results.json of a finished run of this config, else None."""
    run_dir = os.path.join(cfg.runs_dir, cfg.run_name)
    paths = [os.path.join(run_dir, f) for f in ("config.json", "results.json")]
    if not all(os.path.exists(p) for p in paths) or not _same_run(paths[0], cfg):
        return None
    with open(paths[1]) as f:
        return json.load(f)


def set_aside_stale(cfg: Config) -> None:
    """If runs/<name>/ holds a run of another config (an older preset), move it to
    runs/<name>.stale-<n>/ (nothing is deleted) so this sweep can train its own."""
    run_dir = os.path.join(cfg.runs_dir, cfg.run_name)
    path = os.path.join(run_dir, "config.json")
    if os.path.exists(path) and not _same_run(path, cfg):
        n = 1
        while os.path.exists(f"{run_dir}.stale-{n}"):
            n += 1
        os.rename(run_dir, f"{run_dir}.stale-{n}")
        print(f"  {run_dir} held another config; moved to {run_dir}.stale-{n}", flush=True)


def results_of(cfg: Config, label: str) -> dict:
    """results.json of cfg's finished run, else train it (resuming, after moving a stale
    run of another config aside). Prints one progress line starting with `label`."""
    res = finished_results(cfg)
    print(f"{label} ({cfg.run_name}): {'done, read back' if res is not None else 'training'}", flush=True)
    if res is None:
        set_aside_stale(cfg)
        res = zsbfm.train(cfg).results
    return res


def commit_of() -> str:
    """The short commit of the checkout (with "+" when it has uncommitted changes), or "?"."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, check=True).stdout.strip()
        return head + ("+" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "?"


def run_table(env: str, algos, seeds: int, runs_dir: str, overrides, size: str = "cpu") -> dict:
    rows = {}
    for i, algo in enumerate(algos):
        cfg = sweep_config(env, algo, size, seeds, runs_dir, overrides)
        # the code that trains it (a run may outlast later commits); a finished run read
        # back: the day its results were written, the commit unknown
        done = os.path.join(runs_dir, cfg.run_name, "results.json")
        measured = (f"{time.strftime('%Y-%m-%d', time.localtime(os.path.getmtime(done)))} (read back)"
                    if finished_results(cfg) is not None else f"{time.strftime('%Y-%m-%d')} {commit_of()}")
        res = results_of(cfg, f"[{i + 1}/{len(algos)}] {NAMES[algo]}")
        wt = res["wall_time_s"]
        rows[algo] = {"train": res["train"], "test": res["test"], "protocols": res.get("protocols", {}),
                      "wall_time_s": wt["train"] + wt["eval"],
                      "resumed_from_chunk": res.get("resumed_from_chunk", 0),
                      "run": os.path.join(runs_dir, cfg.run_name), "steps": cfg.steps,
                      "measured": measured, "config": comparable(cfg)}
    return rows


def comparable(cfg: Config) -> dict:
    """cfg as a dict without where the run is stored (its name, runs_dir, checkpointing)."""
    d = cfg.to_dict()
    for k in ("name", "runs_dir", "checkpoint"):
        d.pop(k)
    return json.loads(json.dumps(d))  # tuples as lists, as read back from JSON


def same_config(recorded: dict, today: Config) -> bool:
    """Whether a row's recorded config is today's: every recorded field equal, and every field
    added to Config since at its default (a new option whose default keeps the old behaviour)."""
    now = comparable(today)
    defaults = json.loads(json.dumps({f.name: f.default for f in dataclasses.fields(Config)}))
    return all(k in now and now[k] == v for k, v in recorded.items()) and \
        all(now[k] == defaults[k] for k in now if k not in recorded)


def merge_rows(path: str, header: dict, rows: dict, current=None) -> dict:
    """rows over the rows already in `path` when it holds a table of the same header (env,
    size, seeds, overrides); every method in ORDER. Another header: rows alone.

    current(algo) -> Config: today's config of a method; an old row that records another
    config (the preset changed since it was measured) is dropped, with a line saying so."""
    old = {}
    if os.path.exists(path):
        with open(path) as f:
            prev = json.load(f)
        if all(prev.get(k) == v for k, v in header.items()):
            old = prev.get("methods", {})
    for algo in [a for a in old if a not in rows and current is not None and "config" in old[a]]:
        if not same_config(old[algo]["config"], current(algo)):
            print(f"  {path}: dropped the {algo} row (measured {old[algo].get('measured', '?')} "
                  "with another config than today's preset)", flush=True)
            del old[algo]
    merged = {**old, **rows}
    return {a: merged[a] for a in ORDER if a in merged}


def markdown(env: str, rows: dict, seeds: int, size: str, metric: str) -> str:
    """The table; metric: "success" or "return" (evaluate.metric_of, the env's own). The
    official (paper-protocol) score first, then every other protocol the runs report
    (train / test means over seeds)."""
    paper = PAPER.get(env, {})
    fmt = ".0f" if metric == "return" else ".2f"
    extra = [p for p in ("dense", "random_start") if any(p in r.get("protocols", {}) for r in rows.values())]
    head = f"| {env} ({seeds} seeds, {size} preset) | train {metric} | test {metric} | paper train / test "
    head += "".join(f"| {p} train / test " for p in extra) + "| wall time (train + eval) | measured |"
    lines = [head, "|---" * (6 + len(extra)) + "|"]
    for algo, row in rows.items():
        tr, te = np.asarray(row["train"]), np.asarray(row["test"])
        pp = paper.get(algo)
        note = " (resumed)" if row["resumed_from_chunk"] else ""
        oracle_id = algo == "oracle" and row.get("oracle_context", "id") == "id"
        test = "n/a (h = 0)" if oracle_id else f"{te.mean():{fmt}} +- {te.std():{fmt}}"
        cells = ""
        for p in extra:
            d = row.get("protocols", {}).get(p, {})
            cells += f"| {np.mean(d['train']):.2f} / {np.mean(d['test']):.2f} " if d else "| - "
        lines.append(f"| {NAMES[algo]} | {tr.mean():{fmt}} +- {tr.std():{fmt}} | {test} | "
                     f"{f'{pp[0]:{fmt}} / {pp[1]:{fmt}}' if pp else 'n/a'} {cells}| {row['wall_time_s']:.0f} s{note} | {row.get('measured', '?')} |")
    if extra:
        lines.append("\nProtocols: train / test success = the paper's (start (1, 1), one goal in each other room); "
                     "dense = every free cell a goal from the start; random_start = the authors' earlier variant "
                     "(5 random start cells per goal, goals (2, 2), (8, 8), (2, 8), (8, 2) on fourrooms).")
    if any(r["resumed_from_chunk"] for r in rows.values()):
        lines.append("(resumed): the run was killed and resumed from its checkpoint; it ends as an "
                     "uninterrupted run would, its wall time counts the last part only.")
    total = sum(r["wall_time_s"] for r in rows.values())
    lines.append(f"\nTotal wall time {total / 60:.1f} min.")
    if "oracle" in rows:
        lines[-1] += (" Oracle test: the oracle knows only train layouts; on a test layout its h is 0 "
                      "(see zsbfm/agents/oracle.py).")
    return "\n".join(lines)


def bar_chart(env: str, rows: dict, path: str, metric: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    returns = metric == "return"
    algos = [a for a in rows if a != "oracle"]
    x = np.arange(len(algos))
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for ax, split, k in zip(axes, ("train", "test"), (0, 1)):
        means = [np.mean(rows[a][split]) for a in algos]
        stds = [np.std(rows[a][split]) for a in algos]
        ax.bar(x, means, yerr=stds, capsize=3, color="tab:blue", label="zsbfm (CPU preset)")
        paper = [PAPER.get(env, {}).get(a, (np.nan, np.nan))[k] for a in algos]
        ax.scatter(x, paper, marker="_", s=400, color="k", zorder=3, label="paper")
        ax.set_xticks(x, [NAMES[a].split(" ")[0] for a in algos], rotation=20)
        ax.set_title(f"{env}: {split} {'winds' if returns else 'layouts'}")
        if not returns:
            ax.set_ylim(0, 1)
    axes[0].set_ylabel("episode return" if returns else "success rate")
    axes[0].legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="fourrooms", choices=["fourrooms", "doors", "pointmass", "antwind"])
    p.add_argument("--algos", nargs="+", default=list(ORDER), choices=list(ORDER))
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--size", default="cpu", choices=list(SIZES))
    p.add_argument("--runs-dir", default="runs")
    p.add_argument("--out", default="results")
    p.add_argument("--set", nargs="*", default=[], help="Config overrides (field=value) for every method")
    a = p.parse_args()
    # Validate every config before training anything: a typo fails now, not an hour in.
    for algo in a.algos:
        sweep_config(a.env, algo, a.size, a.seeds, a.runs_dir, a.set)

    t0 = time.time()
    rows = run_table(a.env, a.algos, a.seeds, a.runs_dir, a.set, a.size)
    os.makedirs(a.out, exist_ok=True)
    # results/<env>.* is the CPU preset's table; other sizes get results/<env>_<size>.*
    stem = os.path.join(a.out, a.env if a.size == "cpu" else f"{a.env}_{a.size}")
    header = {"env": a.env, "seeds": a.seeds, "size": a.size, "overrides": a.set}
    rows = merge_rows(stem + ".json", header, rows,
                      lambda algo: sweep_config(a.env, algo, a.size, a.seeds, a.runs_dir, a.set))
    with open(stem + ".json", "w") as f:
        json.dump({**header, "methods": rows, "paper": PAPER.get(a.env, {})}, f, indent=2)
    metric = metric_of(zsbfm.make_env(a.env))
    table = markdown(a.env, rows, a.seeds, a.size, metric)
    with open(stem + ".md", "w") as f:
        f.write(table + "\n")
    bar_chart(a.env, rows, stem + ".png", metric)
    print(table)
    print(f"wrote {stem}.json, {stem}.md, {stem}.png in {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
