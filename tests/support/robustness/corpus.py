"""A second, independent robustness corpus (docs/robustness.md, "Second corpus").

Every input is made by code in a temporary folder (``tests/support/robustness/inputs.py``); each case runs
a real command (``phyir ...`` / ``phyir-view``) in its own folder, under a timeout, with its peak
memory measured (``ru_maxrss`` from ``wait4``: this driver imports neither numpy nor torch, so the
figure is the command's own).  Outcomes:

* OK — exit 0 with sane output, or exit 2 with ONE stderr line ``phyir <cmd>: error: ...`` naming
  the file or option;
* TRACEBACK (or a death by a signal), HANG (timeout), JUNK (temporaries left, or half of a set of
  outputs), MEMORY (> 1.5 GB), BAD-MESSAGE (several lines, nothing named, raw control characters),
  SILENT-NONSENSE (exit 0, meaningless output and no warning).

    PYTHONPATH=tests python -m support.robustness.corpus [--json OUT] [--only SUBSTRING] [--keep DIR] [--list]

Prints a table case -> outcome and the counts per class; exits 1 if any case is not OK.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from support.robustness import cases_more, checks

BIN = Path(sys.executable).parent
MEMORY_MB = 1536
EXITS = (0, 1, 2, 129, 130, 141, 143)  # done, failed, refused, SIGHUP, Ctrl-C, closed pipe, SIGTERM
_TMP = re.compile(r"(\.phyir\.tmp$|\.tmp(\.[A-Za-z0-9]+)?$|^\.[^/]*\.[0-9a-f]{8}\b)")
_RAW_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")
OUTCOMES = ("OK", "TRACEBACK", "HANG", "JUNK", "MEMORY", "BAD-MESSAGE", "SILENT-NONSENSE", "SKIP")


@dataclass
class Result:
    rc: int | None
    out: str
    err: str
    peak_mb: float
    seconds: float
    folder: Path
    outcome: str = "OK"
    note: str = ""
    extra: dict = field(default_factory=dict)


def support_env() -> dict[str, str]:
    """This environment with the folder holding ``support/`` (tests/) first on PYTHONPATH: what a
    child interpreter running ``-m support.robustness...`` needs."""
    tests = str(Path(__file__).resolve().parents[2])
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (tests, os.environ.get("PYTHONPATH"))))}


def slug(key: str) -> str:
    """A case's key as a file name (keys hold option values: '/', spaces, ...)."""
    return re.sub(r"[^\w.=+-]", "_", key)


def _limits(fsize: int | None):
    def pre() -> None:
        # a command meets SIGHUP as from a closing terminal, even when the corpus runs under nohup
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
    return pre


def _command(argv: list[str]) -> list[str]:
    if argv[0] == "view":
        return [str(BIN / "phyir-view"), *argv[1:]]
    return [str(BIN / "phyir"), *argv]


def _wait(pid: int, deadline: float, trigger=None) -> tuple[int | None, float]:
    """Poll ``pid`` until it exits (its status and ru_maxrss in MB) or the deadline passes (None)."""
    fired = trigger is None
    while True:
        done, status, usage = os.wait4(pid, os.WNOHANG)
        if done:
            rc = os.waitstatus_to_exitcode(status)
            return rc, usage.ru_maxrss / 1024
        if not fired:
            fired = trigger(pid)
        if time.monotonic() > deadline:
            os.killpg(pid, signal.SIGKILL)
            _, status, usage = os.wait4(pid, 0)
            return None, usage.ru_maxrss / 1024
        time.sleep(0.001 if not fired else 0.02)


def execute(case, folder: Path, logs: Path) -> Result:
    out_path, err_path = logs / f"{slug(case.key)}.out", logs / f"{slug(case.key)}.err"
    argv = case.render(folder)
    # the commands are installed scripts: the PYTHONPATH that finds this driver (tests/) would make
    # the test folders tests/phyir and tests/viewer shadow the packages
    env = {**{k: v for k, v in os.environ.items() if k != "PYTHONPATH"}, "PYTHONUNBUFFERED": "1", **case.env}
    stdin = subprocess.PIPE if case.stdin is not None else subprocess.DEVNULL
    with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
        t0 = time.monotonic()
        # RLIMIT_FSIZE would hit the stdout log too: the command's own files are what is tested
        stdout = subprocess.PIPE if case.close_stdout else subprocess.DEVNULL if case.fsize else fo
        p = subprocess.Popen(_command(argv), cwd=folder, stdin=stdin, stdout=stdout, stderr=fe,
                             env=env, start_new_session=True, preexec_fn=_limits(case.fsize))
        if case.stdin is not None:
            p.stdin.write(case.stdin)
            p.stdin.close()
        if case.close_stdout:  # `phyir ... | head -c 1`: the reader goes away
            fo.write(p.stdout.read(1))
            p.stdout.close()
        trigger = case.trigger(folder, out_path) if case.trigger else None
        rc, peak = _wait(p.pid, t0 + case.timeout, trigger)
        p.returncode = rc if rc is not None else -9  # reaped here, not by Popen
        seconds = time.monotonic() - t0
    return Result(rc, out_path.read_text(errors="replace"), err_path.read_text(errors="replace"),
                  peak, seconds, folder)


def temporaries(folder: Path) -> list[str]:
    found = []
    for dirpath, dirs, names in os.walk(folder):
        for n in names + dirs:
            if _TMP.search(n):
                found.append(os.path.relpath(os.path.join(dirpath, n), folder))
    return sorted(found)


def one_line(r: Result, cmd: str, names: tuple[str, ...]) -> str | None:
    """None if stderr is exactly one error line of ``cmd`` naming ``names``; else what is wrong."""
    lines = [x for x in r.err.split("\n") if x.strip()]
    if not lines:
        return "nothing on stderr"
    line = lines[-1]
    # progress lines (train's "starting from ...") may come first; a second error, a Python warning
    # (file.py:NN: ...Warning) or a traceback may not
    noise = [x for x in lines[:-1] if "error" in x.lower() or "Warning" in x or x.startswith(" ")]
    if noise:
        return f"{len(lines)} stderr lines"
    if _RAW_CONTROL.search(line):
        return "raw control characters"
    if not line.startswith("phyir-view: " if cmd == "view" else f"phyir {cmd}: error: "):
        return "not 'phyir <cmd>: error:'"
    missing = [n for n in names if n not in line]
    return f"does not name {missing}" if missing else None


def classify(case, r: Result) -> None:
    cmd = case.cmd
    if r.rc is None:
        r.outcome, r.note = "HANG", f"killed after {case.timeout:.0f} s"
        return
    if "Traceback" in r.err or "Exception ignored" in r.err or r.rc not in EXITS:
        r.outcome = "TRACEBACK"
        r.note = f"rc {r.rc}: " + (r.err.strip().splitlines() or [""])[-1][:160]
        return
    junk = [t for t in temporaries(r.folder) if t not in r.extra.get("before", ())]
    if junk:
        r.outcome, r.note = "JUNK", f"left {junk[:3]}"
        return
    if r.peak_mb > MEMORY_MB:
        r.outcome, r.note = "MEMORY", f"peak {r.peak_mb:.0f} MB"
        return
    if r.rc == 2 and case.expect in ("refuse", "either"):
        bad = one_line(r, cmd, case.names)
        if bad:
            r.outcome, r.note = "BAD-MESSAGE", bad + ": " + r.err.strip().replace("\n", " | ")[:200]
        else:
            r.note = r.err.strip()[:200]
    elif r.rc == 0 and case.expect in ("ok", "either"):
        r.note = (r.out.strip().splitlines() or [""])[-1][:160]
    elif (case.expect == "signal" and r.rc in (129, 130, 143, 0)) or (r.rc == 141 and case.close_stdout):
        r.note = f"rc {r.rc}: " + r.err.strip()[-120:]
    elif r.rc == 0 and case.expect == "refuse":
        r.outcome, r.note = "SILENT-NONSENSE", "exit 0: " + (r.out.strip().splitlines() or [""])[-1][:160]
    else:
        r.outcome = "BAD-MESSAGE" if r.rc == 2 else "TRACEBACK"
        r.note = f"rc {r.rc} (expected {case.expect}): " + r.err.strip().replace("\n", " | ")[-200:]
    if case.check is not None and r.outcome == "OK":
        verdict = case.check(r)
        if verdict:
            r.outcome, r.note = verdict


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", metavar="OUT", help="write the results as JSON")
    ap.add_argument("--only", action="append", help="run only cases whose key contains this (repeatable)")
    ap.add_argument("--keep", metavar="DIR", help="work in DIR and keep it (default: a temporary folder)")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    args = ap.parse_args(argv)
    root = Path(args.keep or tempfile.mkdtemp(prefix="phyir-corpus-"))
    if args.keep and root.exists():
        shutil.rmtree(root)
    base = root / "base"
    cases = cases_more.all_cases(base)
    if args.only:
        cases = [c for c in cases if any(s in c.key for s in args.only)]
    if args.list:
        for c in cases:
            print(c.key)
        return 0
    t_all = time.monotonic()
    env = support_env()
    subprocess.run([sys.executable, "-m", "support.robustness.inputs", str(base)], check=True, timeout=600,
                   env=env)
    logs = root / "logs"
    logs.mkdir()
    egl = checks.have_egl()
    results = []
    for c in cases:
        folder = root / "cases" / slug(c.key)
        folder.mkdir(parents=True)
        if c.gl and not egl:
            r = Result(None, "", "", 0, 0, folder, "SKIP", "no EGL (headless GL) on this machine")
        else:
            try:
                skip = c.setup(folder) if c.setup else None
                skip = skip if isinstance(skip, str) else None  # a reason, or nothing
            except OSError as e:  # e.g. mkfifo not permitted here
                skip = f"setup failed: {e}"
            if skip:
                r = Result(None, "", "", 0, 0, folder, "SKIP", str(skip))
            else:
                before = temporaries(folder)  # a case's own input may be a temporary
                r = execute(c, folder, logs)
                r.extra["before"] = before
                classify(c, r)
        results.append((c, r))
        print(f"{c.key:<44} {r.outcome:<15} {r.seconds:5.1f} s {r.peak_mb:6.0f} MB  {r.note[:110]}",
              flush=True)
    counts: dict[str, Counter] = {}
    for c, r in results:
        counts.setdefault(str(c.cls), Counter())[r.outcome] += 1
    print(f"\n{'class':<8}" + "".join(f"{o:>17}" for o in OUTCOMES))
    for k in sorted(counts, key=int):
        print(f"{k:<8}" + "".join(f"{counts[k][o]:>17}" for o in OUTCOMES))
    total = Counter(r.outcome for _, r in results)
    print(f"{'all':<8}" + "".join(f"{total[o]:>17}" for o in OUTCOMES))
    print(f"{len(results)} cases in {time.monotonic() - t_all:.0f} s")
    if args.json:
        doc = {"cases": [{"key": c.key, "class": c.cls, "argv": c.render(root / "cases" / slug(c.key)),
                          "outcome": r.outcome, "note": r.note,
                          "rc": r.rc, "peak_mb": round(r.peak_mb, 1), "seconds": round(r.seconds, 2)}
                         for c, r in results],
               "counts": {k: dict(v) for k, v in counts.items()}}
        Path(args.json).write_text(json.dumps(doc, indent=1, default=str) + "\n")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0 if all(r.outcome in ("OK", "SKIP") for _, r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
