"""Coverage-guided fuzzing of the file readers: ``python -m phyir.bench.fuzz --seconds 60 [--target exr]``.

Targets (each reads a file the way the program does; the seed corpus is made here by code):

* ``exr``   — ``phyir.io.read_raw(panorama=False)`` (what ``phyir info`` reads) and ``load_scene``
  of OpenEXR images (phyir/io/exr.py's header parser, then the OpenEXR library for the pixels);
* ``scene`` — the same on multi-part scene files (layers, masks, meta, the probe atlas part);
* ``hdr``   — the same on Radiance RGBE files (phyir/io/rgbe.py: flat and run-length scanlines);
* ``png``   — the same on PNG and JPEG (phyir/io/ldr.py: its 16-bit PNG decoder, Pillow for the rest);
* ``mesh``  — ``phyir.insert.objects.load_mesh`` on OBJ/OFF/PLY text (trimesh parses; only our checks
  are instrumented).

Engines: ``atheris`` (libFuzzer, when installed: ``pip install atheris``) or ``builtin`` (a small
mutational fuzzer guided by line-pair coverage from ``sys.settrace``; slower, no dependency).
``--engine auto`` picks atheris when it imports.

Outcomes: a :class:`~phyir.errors.PhyIRError` (``InputError``: the one-line message users see) is
the expected answer to a bad file.  A *finding* is anything else: another exception type, the
process dying (segfault, abort), an input running longer than ``--timeout`` seconds, or the process
growing beyond ``--rss-mb``.  Each distinct finding is saved to ``OUT/findings/`` (the input and a
``.txt`` with the traceback), and ``OUT/report.json`` gives per target the executions, the corpus
size, the coverage and the findings.  The fuzzing runs in a child process that a watchdog (this
process) restarts after a crash, so native crashes, hangs and memory blow-ups are caught too.
Exit status: 0 without findings, 1 with findings.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from phyir.bench.fuzz_targets import TARGETS, Hang, Outcome, Target, run_input

TARGET_NAMES = ("exr", "scene", "hdr", "png", "mesh")
STATS_EVERY_S = 0.25
MAX_LEN = 64 * 1024
ATHERIS_WALL_FACTOR = 10  # libFuzzer's per-input limit is wall-clock: generous, for loaded machines
TIMEOUT_EXIT = 70  # libFuzzer's exit status after a timeout
WALL_GRACE_S = 600.0  # a child still running this long after its time is up is blocked


# ---------------------------------------------------------------------------------------------
# seed corpora: small valid files of each format, made by code


# ---------------------------------------------------------------------------------------------
# targets


# ---------------------------------------------------------------------------------------------
# the child: one engine fuzzing one target, writing stats, findings and the current input


class _Child:
    def __init__(self, target: Target, out: Path, timeout: float, seconds: float):
        self.target, self.out, self.timeout, self.seconds = target, out, timeout, seconds
        self.deadline = time.monotonic() + seconds  # reset by start() once the readers are imported
        self.work = out / "work" / target.name
        self.corpus = out / "corpus" / target.name
        self.findings = out / "findings"
        for d in (self.work, self.corpus, self.findings):
            d.mkdir(parents=True, exist_ok=True)
        self.current = str(self.work / ("current" + target.suffix))  # the input being read now
        self.stats_path = self.work / "stats.json"
        self.stats = _load_json(self.stats_path) or {"executions": 0, "findings": {},
                                                        "coverage": 0, "corpus": 0}
        self._last_stats = 0.0
        # the per-input alarm (builtin engine); under atheris, libFuzzer's -timeout (wall clock) and
        # the watchdog's CPU-time check catch hangs
        self.timer = False

    def use_timer(self) -> None:
        signal.signal(signal.SIGPROF, self._alarm)
        self.timer = True

    def start(self) -> None:
        """Fuzzing starts now: the time spent importing torch and making seeds does not count."""
        self.deadline = time.monotonic() + self.seconds

    def _alarm(self, *_):
        raise Hang(f"input took more than {self.timeout:g} s of CPU")

    def execute(self, data: bytes) -> Outcome:
        with open(self.current, "wb") as f:
            f.write(data)
        if self.timer:  # CPU time, so that a loaded machine does not turn slow inputs into hangs
            signal.setitimer(signal.ITIMER_PROF, self.timeout)
        try:
            outcome = run_input(self.target, self.current)
        finally:
            if self.timer:
                signal.setitimer(signal.ITIMER_PROF, 0)
        self.stats["executions"] += 1
        self.stats[outcome.kind] = self.stats.get(outcome.kind, 0) + 1
        if outcome.kind == "finding":
            self.record(data, outcome)
        now = time.monotonic()
        if now - self._last_stats > STATS_EVERY_S:
            self.save_stats()
        return outcome

    def record(self, data: bytes, outcome: Outcome) -> None:
        sig = outcome.signature
        seen = self.stats["findings"]
        if sig in seen:
            seen[sig]["count"] += 1
            return
        name = save_finding(self.findings, self.target, "exception", data, f"{sig}\n\n{outcome.text}")
        seen[sig] = {"count": 1, "file": name}
        self.save_stats()

    def save_stats(self) -> None:
        self.stats["corpus"] = sum(1 for _ in self.corpus.iterdir())
        _write_json(self.stats_path, self.stats)
        self._last_stats = time.monotonic()


def save_finding(folder: Path, target: Target, kind: str, data: bytes, text: str) -> str:
    digest = hashlib.sha1(data).hexdigest()[:12]
    name = f"{target.name}-{kind}-{digest}{target.suffix}"
    (folder / name).write_bytes(data)
    (folder / (name + ".txt")).write_text(f"target: {target.name}\nkind: {kind}\n\n{text}\n")
    return name


def _write_json(path: Path, obj) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    os.replace(tmp, path)


def _load_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _seed_corpus(child: _Child) -> list[bytes]:
    existing = sorted(child.corpus.iterdir())
    if existing:
        return [p.read_bytes() for p in existing]
    seeds = child.target.seeds()
    for s in seeds:
        (child.corpus / hashlib.sha1(s).hexdigest()).write_bytes(s)
    return seeds


def _child_atheris(child: _Child, seed: int, max_len: int) -> None:
    import atheris
    import torch  # noqa: F401 - imported before instrumenting: only the readers are instrumented

    loaded = [m for m in child.target.modules if m in sys.modules]
    assert not loaded, f"imported before instrumenting: {loaded}"
    with atheris.instrument_imports(include=list(child.target.modules)):
        for m in child.target.modules:
            __import__(m)
    _import_readers(child.target)
    _seed_corpus(child)
    child.start()
    dict_path = child.work / "tokens.dict"
    dict_path.write_text("".join(f'"{_dict_escape(t)}"\n' for t in child.target.tokens))
    seconds = max(1, int(round(child.deadline - time.monotonic())))

    def one(data: bytes) -> None:
        child.execute(data)

    wall_limit = max(1, round(ATHERIS_WALL_FACTOR * child.timeout))
    atheris.Setup([sys.argv[0], str(child.corpus), f"-max_total_time={seconds}", f"-timeout={wall_limit}",
                   f"-timeout_exitcode={TIMEOUT_EXIT}", "-rss_limit_mb=0", f"-max_len={max_len}",
                   f"-seed={seed}", f"-dict={dict_path}", f"-artifact_prefix={child.work}/",
                   "-print_final_stats=1"], one)
    try:
        atheris.Fuzz()
    finally:
        child.save_stats()


def _dict_escape(t: bytes) -> str:
    return "".join(chr(b) if 32 <= b < 127 and b not in (34, 92) else f"\\x{b:02X}" for b in t)


def _import_readers(target: Target) -> None:
    """Import what the target's readers import lazily (OpenEXR, PIL, trimesh) before fuzzing."""
    import OpenEXR  # noqa: F401
    import PIL.Image  # noqa: F401

    if target.name == "mesh":
        import trimesh  # noqa: F401


def _child_builtin(child: _Child, seed: int, max_len: int) -> None:
    rng = random.Random(seed)
    corpus = _seed_corpus(child)
    _import_readers(child.target)
    for m in child.target.modules:
        __import__(m)
    files = {os.path.realpath(sys.modules[m].__file__) for m in child.target.modules}
    cover = _Coverage(files)
    child.use_timer()
    child.start()
    for data in list(corpus):  # the seeds' coverage first
        with cover:
            child.execute(data)
        cover.commit()
    while time.monotonic() < child.deadline:
        parent = rng.choice(corpus[-64:] if rng.random() < 0.5 else corpus)
        data = mutate(parent, rng, corpus, child.target.tokens, max_len)
        with cover:
            child.execute(data)
        if cover.commit():
            corpus.append(data)
            (child.corpus / hashlib.sha1(data).hexdigest()).write_bytes(data)
            child.stats["coverage"] = len(cover.seen)
    child.stats["coverage"] = len(cover.seen)
    child.save_stats()


class _Coverage:
    """Line-pair (edge) coverage of the given source files through ``sys.settrace``."""

    def __init__(self, files: set[str]):
        self.files = files
        self.seen: set[tuple] = set()
        self.new: set[tuple] = set()
        self._prev: dict[int, int] = {}
        self._keep: dict[str, bool] = {}

    def _global(self, frame, event, arg):
        fn = frame.f_code.co_filename
        keep = self._keep.get(fn)
        if keep is None:
            keep = self._keep[fn] = os.path.realpath(fn) in self.files
        if not keep:
            return None
        self._prev[id(frame)] = -1
        return self._local

    def _local(self, frame, event, arg):
        if event == "line":
            key = id(frame)
            edge = (frame.f_code, self._prev.get(key, -1), frame.f_lineno)
            self._prev[key] = frame.f_lineno
            if edge not in self.seen:
                self.new.add(edge)
        return self._local

    def __enter__(self):
        self._prev.clear()
        sys.settrace(self._global)
        return self

    def __exit__(self, *exc):
        sys.settrace(None)
        return False

    def commit(self) -> bool:
        """Merge this run's new edges; True if there were any."""
        if not self.new:
            return False
        self.seen |= self.new
        self.new = set()
        return True


INTERESTING = (0, 1, 2, 3, 4, 7, 8, 15, 16, 31, 32, 63, 64, 127, 128, 255, 256, 1023, 1024, 4096, 32767,
               32768, 65535, 65536, 2**31 - 1, 2**31, 2**32 - 1)


def mutate(data: bytes, rng: random.Random, corpus: list[bytes], tokens: tuple[bytes, ...],
           max_len: int) -> bytes:
    """One to four stacked byte-level mutations (flips, interesting integers, tokens, cuts, splices)."""
    b = bytearray(data)
    for _ in range(rng.choice((1, 1, 2, 3, 4))):
        n = len(b)
        op = rng.randrange(9)
        pos = rng.randrange(n) if n else 0
        if op == 0 and n:
            b[pos] ^= 1 << rng.randrange(8)
        elif op == 1 and n:
            b[pos] = rng.randrange(256)
        elif op == 2 and n:
            width = rng.choice((1, 2, 4))
            v = rng.choice(INTERESTING) + rng.choice((-1, 0, 0, 1))
            enc = (v % (1 << (8 * width))).to_bytes(width, rng.choice(("little", "big")))
            b[pos:pos + width] = enc
        elif op == 3 and tokens:
            t = rng.choice(tokens)
            if rng.random() < 0.5:
                b[pos:pos + len(t)] = t
            else:
                b[pos:pos] = t
        elif op == 4 and n:
            cut = rng.randrange(1, min(n, 64) + 1)
            del b[pos:pos + cut]
        elif op == 5 and n:
            cut = rng.randrange(1, min(n - pos, 64) + 1)
            b[pos:pos] = b[pos:pos + cut]
        elif op == 6:
            b[pos:pos] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 16)))
        elif op == 7 and n:
            del b[rng.randrange(n):]
        elif op == 8 and corpus:
            other = rng.choice(corpus)
            if other:
                a = rng.randrange(len(other))
                b[pos:] = other[a:a + rng.randrange(1, 256)] + b[pos:]
    return bytes(b[:max_len])


def _child_main(args) -> int:
    target = TARGETS[args.target]
    child = _Child(target, Path(args.out), args.timeout, args.seconds)
    if args.engine == "atheris":
        _child_atheris(child, args.seed, args.max_len)
    else:
        _child_builtin(child, args.seed, args.max_len)
    return 0


# ---------------------------------------------------------------------------------------------
# the watchdog: runs children until the time is up, catching what kills them


def atheris_available() -> bool:
    try:
        import atheris  # noqa: F401
    except ImportError:
        return False
    return True


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (its threads included)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def fuzz_target(name: str, seconds: float, out: Path, *, engine: str = "auto", timeout: float = 5.0,
                rss_mb: float = 2048.0, seed: int = 0, max_len: int = MAX_LEN, log=print) -> dict:
    """Fuzz one target for ``seconds`` (wall clock); returns its report entry."""
    target = TARGETS[name]
    if engine == "auto":
        engine = "atheris" if atheris_available() else "builtin"
    work = out / "work" / name
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    (out / "findings").mkdir(parents=True, exist_ok=True)
    current = work / ("current" + target.suffix)
    end = time.monotonic() + seconds
    crashes: list[dict] = []
    execs_before = 0
    runs = 0
    stuck_cpu = 2 * timeout + 5  # CPU seconds on one input outside Python's reach: a hang
    while True:
        left = end - time.monotonic()
        if left < 1 or runs >= 50:
            break
        runs += 1
        cmd = [sys.executable, "-m", "phyir.bench.fuzz", "--child", "--target", name,
               "--seconds", f"{left:.1f}", "--out", str(out), "--engine", engine, "--timeout", str(timeout),
               "--seed", str(seed + runs),
               "--max-len", str(max_len)]
        with open(work / f"log-{runs}.txt", "wb") as logf:
            proc = subprocess.Popen(cmd, stdout=logf, stderr=subprocess.STDOUT)
            killed = None
            started = time.monotonic()
            mtime, cpu_at = None, 0.0  # the current input's write time, the child's CPU time then
            while proc.poll() is None:
                time.sleep(0.2)
                cpu = _cpu_seconds(proc.pid)
                m = current.stat().st_mtime if current.exists() else None
                if m != mtime:
                    mtime, cpu_at = m, cpu
                if _rss_mb(proc.pid) > rss_mb:
                    killed = ("memory", f"the process grew beyond {rss_mb:g} MB reading this input")
                elif mtime is not None and cpu - cpu_at > stuck_cpu:
                    killed = ("hang", f"over {stuck_cpu:g} s of CPU on this input (stuck outside Python)")
                elif time.monotonic() > started + left + WALL_GRACE_S:
                    killed = ("hang", f"the fuzzer ran {WALL_GRACE_S:g} s past its time (blocked?)")
                if killed:
                    proc.kill()
                    proc.wait()
                    break
        rc = proc.returncode
        if killed is None and rc == TIMEOUT_EXIT and engine == "atheris":
            killed = ("hang", f"libFuzzer: an input took over {ATHERIS_WALL_FACTOR * timeout:g} s (wall)")
        if killed is None and rc not in (0, None):
            tail = (work / f"log-{runs}.txt").read_bytes()[-3000:].decode("utf-8", "replace")
            killed = ("crash", f"the process died (exit status {rc}):\n{tail}")
        if killed is None:
            break
        data = current.read_bytes() if current.exists() else b""
        fname = save_finding(out / "findings", target, killed[0], data, killed[1])
        crashes.append({"kind": killed[0], "file": fname, "detail": killed[1].splitlines()[0]})
        log(f"[{name}] {killed[0]}: saved {fname}")
        stats = _load_json(work / "stats.json") or {}
        if stats.get("executions", 0) == execs_before:
            break  # it dies before making progress: don't spin
        execs_before = stats.get("executions", 0)
    stats = _load_json(work / "stats.json") or {"executions": 0, "findings": {}, "coverage": 0, "corpus": 0}
    findings = [{"kind": "exception", "signature": sig, **v} for sig, v in stats["findings"].items()]
    findings += crashes
    cov = stats.get("coverage", 0)
    if engine == "atheris":
        cov = _libfuzzer_coverage(work)
    return {"target": name, "engine": engine, "seconds": round(seconds, 1), "executions": stats["executions"],
            "corpus": stats.get("corpus", 0), "coverage": cov,
            "coverage_unit": "libFuzzer cov (edges)" if engine == "atheris" else "line pairs",
            "restarts": runs - 1, "findings": findings}


def _libfuzzer_coverage(work: Path) -> int:
    best = 0
    for log in work.glob("log-*.txt"):
        for line in log.read_text("utf-8", "replace").splitlines():
            if " cov: " in line:
                with contextlib.suppress(ValueError, IndexError):
                    best = max(best, int(line.split(" cov: ")[1].split()[0]))
    return best


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m phyir.bench.fuzz", description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=60.0, help="time per target (s)")
    p.add_argument("--target", action="append", choices=(*TARGET_NAMES, "all"),
                   help="reader to fuzz (repeatable; default all)")
    p.add_argument("--out", default="fuzz-out", help="output folder (corpus, findings, report.json)")
    p.add_argument("--engine", choices=("auto", "atheris", "builtin"), default="auto")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds one input may take (a hang)")
    p.add_argument("--rss-mb", type=float, default=2048.0, help="memory (RSS, MB) that is a finding")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-len", type=int, default=MAX_LEN, help="largest input (bytes)")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        args.target = args.target[0]
        return _child_main(args)
    names = TARGET_NAMES if not args.target or "all" in args.target else tuple(dict.fromkeys(args.target))
    if args.engine == "atheris" and not atheris_available():
        print("phyir.bench.fuzz: atheris is not installed (pip install atheris); use --engine builtin",
              file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    reports = []
    for name in names:
        r = fuzz_target(name, args.seconds, out, engine=args.engine, timeout=args.timeout, rss_mb=args.rss_mb,
                        seed=args.seed, max_len=args.max_len)
        reports.append(r)
        print(f"{name}: {r['executions']} executions in {r['seconds']:g} s ({r['engine']}), corpus "
              f"{r['corpus']}, coverage {r['coverage']} {r['coverage_unit']}, findings {len(r['findings'])}")
        for f in r["findings"]:
            print(f"  {f['kind']}: {f.get('signature') or f.get('detail')} -> {out / 'findings' / f['file']}")
    _write_json(out / "report.json", {"targets": reports, "python": sys.version.split()[0],
                                       "date": time.strftime("%Y-%m-%d %H:%M:%S %Z")})
    return 1 if any(r["findings"] for r in reports) else 0


if __name__ == "__main__":
    sys.exit(main())
