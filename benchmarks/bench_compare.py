"""This tree against a named earlier commit, side by side, in one command (issue 33, item 4).

1. The base commit is checked out into a temporary ``git worktree`` (removed afterwards); every
   measurement runs in a subprocess whose ``PYTHONPATH`` names one tree (this one or the base),
   with the same virtualenv. Each tree's kernels are compiled (numba cache) before any timing.
2. Per run-step cost [µs] of every built-in filter (``compare_steps.py``: R = 100 runs batched,
   one core, CPU time of the process) in the 12-state layout with the DVL and the 15-state
   layout with DVL + depth + fixes; a filter the base lacks shows "—".
3. The tuning overhead: ``nespm tune`` of the EKF on track 5, T trials x r runs (the trials alone:
   ``--no-profile``, the level fitted on the trials' own runs), against one
   ``nespm mc`` of T·r runs of the EKF (jobs 1, CPU time of the whole command and its children).
4. The main job, ``nespm mc --tracks 5 6 --runs 100 --jobs 2`` (the default filters, the embedded
   tracks: ``NESPM_DATA_DIR`` removed from the environment): wall time, CPU time, the largest
   process's peak resident memory and the peak of all its processes together (sampled every 0.1 s).
5. The memory must-hold: ``nespm mc`` of the EKF on track 5, jobs 1, 1,000 against 10,000 runs:
   peak resident memory of each and their ratio (this tree; ``--memory-base`` also the base).

The trees run in turn (base, now, base, now ...) for ``--rounds`` rounds, so the load of other
jobs on the machine hits both alike; medians and spreads are reported. The markdown table is
printed and, unless ``--quick`` or ``--no-readme``, written into benchmarks/README.md between
``<!-- bench_compare:begin -->`` and ``<!-- bench_compare:end -->``; the raw numbers go to
``results/bench/compare.json``.

Per run-step, each round's value is the least of ``--repeat`` (default 2) timed runs: other jobs'
load only ever adds to a CPU time. ``--parts`` measures only some of steps, tune, main, memory;
``--keep-from results/bench/compare.json`` takes the others from an earlier run (same base).

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_compare.py --base REV [--quick] [--rounds 3]``
(``make bench-compare BASE=REV``). Bad input: one line, exit 2.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
PY = sys.executable
sys.path.insert(0, str(HERE))

from compare_table import report, rewrite_section  # noqa: E402

ONE_CORE = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
MEASURE_FLAG = "--measure-command"  # internal: run the command after it, print its resources as JSON


class Refused(Exception):
    """A one-line reason to stop (exit 2)."""


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2 (no usage block)
        raise Refused(f"bench_compare: {message}")


def git(*args: str) -> str:
    r = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        raise Refused(f"git {' '.join(args)}: {(r.stderr.strip().splitlines() or ['failed'])[-1]}")
    return r.stdout.strip()


def resolve(rev: str) -> str:
    """The full hash of commit ``rev``; Refused when git does not know it."""
    r = subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"], cwd=ROOT,
                       capture_output=True, text=True)
    if r.returncode != 0 or not r.stdout.strip():
        raise Refused(f"bench_compare: unknown commit {rev!r}")
    return r.stdout.strip()


def tree_env(tree: Path) -> dict:
    """The environment of a measurement of ``tree``: its package first, one core, the embedded tracks."""
    env = dict(os.environ, PYTHONPATH=str(tree), **ONE_CORE)
    env.pop("NESPM_DATA_DIR", None)
    env.pop("NESPM_KERNELS", None)
    return env


def run_json(cmd: list[str], env: dict, cwd: Path) -> dict:
    """Run ``cmd`` and parse the last line of its output as JSON; Refused naming the command on failure."""
    r = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        tail = (r.stderr.strip().splitlines() or ["no output"])[-1]
        raise Refused(f"bench_compare: {' '.join(map(str, cmd[1:4]))} ... failed: {tail}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def measure_command(cmd: list[str]) -> dict:
    """Run ``cmd`` (in this process's environment) and return its wall time [s], its and its
    children's CPU time [s], the largest process's peak resident memory [MB] (the kernel's
    account of the reaped children) and the peak of the whole process tree's resident memory
    together [MB] (sampled every 0.1 s)."""
    import psutil

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    top = psutil.Process(proc.pid)
    tree_peak, cpu_seen = 0, {}
    while proc.poll() is None:
        try:
            procs = [top] + top.children(recursive=True)
            rss = 0
            for q in procs:
                with q.oneshot():
                    rss += q.memory_info().rss
                    c = q.cpu_times()
                    cpu_seen[q.pid] = c.user + c.system
            tree_peak = max(tree_peak, rss)
        except psutil.Error:
            pass
        time.sleep(0.1)
    err = proc.stderr.read()
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        return {"error": (err.strip().splitlines() or [f"exit {proc.returncode}"])[-1]}
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    # a worker pool the command leaves to exit on its own is not reaped by it, so its CPU time is
    # not in the children's account: the sampled sum over the processes seen is the floor
    return {"wall_s": wall, "cpu_s": max(cpu, sum(cpu_seen.values())), "maxrss_mb": after.ru_maxrss / 1024,
            "tree_mb": tree_peak / 2**20}


def nespm(tree: Path, args: list[str], work: Path) -> dict:
    """``nespm args`` of ``tree`` measured in a fresh process (so the resources are this command's
    alone), from ``work`` (not a tree root: ``-m`` puts the working folder first on the path)."""
    cmd = [PY, str(Path(__file__).resolve()), MEASURE_FLAG, PY, "-m", "nespm_cli.cli", *args]
    res = run_json(cmd, tree_env(tree), work)
    if "error" in res:
        raise Refused(f"bench_compare: nespm {' '.join(args[:3])} ... of {tree} failed: {res['error']}")
    return res


def has_tune(tree: Path) -> bool:
    return (tree / "nespm_cli" / "experiments" / "tune.py").exists()


def plan(a) -> dict:
    """The sizes of every measurement (``--quick``: small ones for a fast check)."""
    if a.quick:
        return dict(rounds=a.rounds or 1, epochs=a.epochs or 20, trials=a.trials or 4, tune_runs=a.tune_runs or 5,
                    main_runs=10, memory=(100, 1000), repeat=a.repeat or 1, parts=a.parts)
    return dict(rounds=a.rounds or 3, epochs=a.epochs or 100, trials=a.trials or 50, tune_runs=a.tune_runs or 20,
                main_runs=100, memory=(1000, 10000), repeat=a.repeat or 2, parts=a.parts)


def one_round(trees: dict, p: dict, work: Path, res: dict, i: int) -> None:
    """One round of every measurement, base then now for each."""
    def say(msg):
        print(f"  round {i + 1}: {msg}", flush=True)

    for who, tree in trees.items() if "steps" in p["parts"] else ():
        r = run_json([PY, str(HERE / "compare_steps.py"), "--epochs", str(p["epochs"]), "--runs", "100",
                      "--repeat", str(p["repeat"])], tree_env(tree), work)
        res["steps"][who].append(r)
        say(f"{who} per run-step " + ", ".join(f"{k} {v['12']:.3f}" for k, v in r["cost_us"].items()
                                               if v.get("12") is not None))
    for who, tree in trees.items() if "tune" in p["parts"] else ():
        if not has_tune(tree):
            continue
        t = res["tune"].setdefault(who, {"tune": [], "mc": []})
        out = work / f"tune-{who}"
        shutil.rmtree(out, ignore_errors=True)
        # the trials alone: no profile, the level fitted on the trials' own runs (its two extra runs counted)
        t["tune"].append(nespm(tree, ["tune", "--tracks", "5", "--filters", "ekf", "--trials", str(p["trials"]),
                                      "--runs", str(p["tune_runs"]), "--jobs", "1", "--no-progress", "--no-profile",
                                      "--level-runs", str(p["tune_runs"]), "--out", str(out)], work))
        out = work / f"mc-{who}"
        shutil.rmtree(out, ignore_errors=True)
        t["mc"].append(nespm(tree, ["mc", "--tracks", "5", "--filters", "ekf", "--runs", str(p["trials"] * p["tune_runs"]),
                                    "--jobs", "1", "--no-progress", "--out", str(out)], work))
        say(f"{who} tune {t['tune'][-1]['cpu_s']:.1f} s CPU, mc {t['mc'][-1]['cpu_s']:.1f} s CPU")
    for who, tree in trees.items() if "main" in p["parts"] else ():
        out = work / f"main-{who}"
        shutil.rmtree(out, ignore_errors=True)
        m = nespm(tree, ["mc", "--tracks", "5", "6", "--runs", str(p["main_runs"]), "--jobs", "2", "--no-progress",
                         "--out", str(out)], work)
        res["main"][who].append(m)
        say(f"{who} main job {m['wall_s']:.1f} s wall, {m['cpu_s']:.1f} s CPU, {m['maxrss_mb']:.0f} MB largest, "
            f"{m['tree_mb']:.0f} MB together")


def memory(trees: dict, p: dict, work: Path, res: dict, who_list: list[str]) -> None:
    """Peak resident memory of the EKF mc on one track at the two run counts (jobs 1)."""
    res["memory"] = {"runs": list(p["memory"])}
    for who in who_list:
        res["memory"][who] = {}
        for runs in p["memory"]:
            out = work / f"mem-{who}-{runs}"
            shutil.rmtree(out, ignore_errors=True)
            m = nespm(trees[who], ["mc", "--tracks", "5", "--filters", "ekf", "--runs", str(runs), "--jobs", "1",
                                   "--no-progress", "--out", str(out)], work)
            res["memory"][who][str(runs)] = [m]
            shutil.rmtree(out, ignore_errors=True)
            print(f"  memory {who} {runs} runs: {m['maxrss_mb']:.0f} MB peak, {m['wall_s']:.1f} s wall", flush=True)


def short(text: str, n: int = 70) -> str:
    """``text`` cut at a word to at most ``n`` characters (an ellipsis when cut)."""
    return text if len(text) <= n else text[:n].rsplit(" ", 1)[0] + " …"


PARTS = ("steps", "tune", "main", "memory")


def kept(path: str) -> dict:
    """An earlier ``compare.json`` (Refused in one line when it cannot be read)."""
    try:
        old = json.loads(Path(path).read_text(encoding="utf-8"))
        if not isinstance(old, dict) or "steps" not in old:
            raise ValueError("not a bench_compare result")
        return old
    except (OSError, ValueError) as exc:
        raise Refused(f"bench_compare: --keep-from {path}: {str(exc).splitlines()[0] if str(exc) else 'unreadable'}") from None


def merge(res: dict, old: dict, parts: list[str]) -> None:
    """Take the parts not measured now from ``old`` (same base required), noting when they were measured."""
    if old.get("base") != res["base"]:
        raise Refused(f"bench_compare: --keep-from holds base {old.get('base')}, not {res['base']}")
    taken = [x for x in PARTS if x not in parts and old.get(x)]
    for x in taken:
        res[x] = old[x]
    if "tune" in taken:
        res["notes"] += [n for n in old.get("notes", []) if "tune" in n]
    if taken:
        res["notes"].append(f"{', '.join(taken)}: from the run of {old.get('date', '?')} against the same base "
                            f"(now `{old.get('now', '?')}`, load {old.get('load', '?')}, "
                            f"{old.get('plan', {}).get('rounds', '?')} rounds).")


def machine() -> tuple[str, str]:
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()}-vCPU {cpu}", f"{os.getloadavg()[0]:.1f}"


def compare(a) -> dict:
    p = plan(a)
    base = resolve(a.base)
    now = git("rev-parse", "HEAD")
    dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    cpu, load0 = machine()
    res = {"base": base[:7], "repeat": p["repeat"], "base_subject": short(git("log", "-1", "--format=%s", base)),
           "now": now[:7] + (" + uncommitted changes" if dirty else ""), "runs": 100, "plan": p,
           "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "cpu": cpu,
           "epochs_note": f"the first {p['epochs']} GT epochs of embedded track 5 ({(p['epochs'] - 1) * 100} IMU steps)",
           "steps": {"base": [], "now": []}, "tune": {"trials": p["trials"], "runs": p["tune_runs"],
                                                      "mc_runs": p["trials"] * p["tune_runs"]},
           "main": {"base": [], "now": []}, "notes": []}
    with tempfile.TemporaryDirectory(prefix="nespm-bench-compare-") as tmp:
        tmp = Path(tmp)
        base_tree = tmp / "base"
        git("worktree", "add", "--detach", str(base_tree), base)
        try:
            trees = {"base": base_tree, "now": ROOT}
            work = tmp / "work"
            work.mkdir()
            for who, tree in trees.items():  # compile (or load) every kernel before any timing
                t0 = time.perf_counter()
                run_json([PY, "-c", "from nespm_cli.filters.kernels import warm_up; print(warm_up())"],
                         tree_env(tree), work)
                print(f"kernels of {who} ready in {time.perf_counter() - t0:.1f} s", flush=True)
            for i in range(p["rounds"]):
                one_round(trees, p, work, res, i)
            if "memory" in p["parts"]:
                memory(trees, p, work, res, ["base", "now"] if a.memory_base else ["now"])
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base_tree)], cwd=ROOT, capture_output=True)
            subprocess.run(["git", "worktree", "prune"], cwd=ROOT, capture_output=True)
    if "tune" in p["parts"] and "base" not in res["tune"]:
        res["notes"].append(f"The base has no `nespm tune`: its tuning overhead is \"{chr(0x2014)}\".")
    v = res["steps"]["now"][-1]["versions"] if res["steps"]["now"] else {}
    res["versions"] = ", ".join(f"{k} {x}" for k, x in v.items())
    res["load"] = f"{load0} and {machine()[1]}"
    return res


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == [MEASURE_FLAG]:
        print(json.dumps(measure_command(argv[1:])))
        return 0
    ap = Parser(description="This tree against a base commit: per run-step costs, tuning overhead, main job, memory.")
    ap.add_argument("--base", required=True, help="the earlier commit (hash, tag or branch)")
    ap.add_argument("--quick", action="store_true", help="small sizes, one round, README untouched")
    ap.add_argument("--rounds", type=int, help="rounds of base-then-now (default 3; quick 1)")
    ap.add_argument("--epochs", type=int, help="GT epochs of track 5 per run-step measurement (default 100; quick 20)")
    ap.add_argument("--trials", type=int, help="tune trials (default 50; quick 4)")
    ap.add_argument("--tune-runs", type=int, help="tune runs per trial (default 20; quick 5)")
    ap.add_argument("--repeat", type=int, help="timed runs per filter, layout and round, the least counts (default 2; quick 1)")
    ap.add_argument("--parts", default="steps,tune,main,memory", help="comma list of what to measure")
    ap.add_argument("--keep-from", help="an earlier compare.json: the parts not measured now are taken from it")
    ap.add_argument("--memory-base", action="store_true", help="also measure the base's memory")
    ap.add_argument("--no-readme", action="store_true", help="print only; leave benchmarks/README.md as it is")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench" / "compare.json"))
    try:
        a = ap.parse_args(argv)
        parts = [x for x in a.parts.split(",") if x]
        if not parts or set(parts) - set(PARTS):
            raise Refused(f"bench_compare: --parts takes a comma list of {', '.join(PARTS)}, got {a.parts!r}")
        a.parts = parts
        old = kept(a.keep_from) if a.keep_from else None
        for name in ("rounds", "epochs", "trials", "tune_runs", "repeat"):
            value = getattr(a, name)
            if value is not None and value < (4 if name == "epochs" else 1):
                raise Refused(f"bench_compare: --{name.replace('_', '-')} must be at least {4 if name == 'epochs' else 1}")
        if a.epochs is not None and a.epochs > 400:
            raise Refused("bench_compare: --epochs must be at most 400 (track 5 has 400 GT epochs)")
        res = compare(a)
        if old is not None:
            merge(res, old, parts)
    except Refused as exc:
        print(str(exc).replace("\n", " "), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bench_compare: interrupted", file=sys.stderr)
        return 2
    md = report(res)
    print(md)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    if not (a.quick or a.no_readme):
        readme = HERE / "README.md"
        readme.write_text(rewrite_section(readme.read_text(encoding="utf-8"), md), encoding="utf-8")
        print(f"wrote {readme} and {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
