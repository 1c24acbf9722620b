"""The second robustness corpus (tests/support/robustness): its cases, and a slice of them run."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter

import pytest
from support.robustness import corpus

# one case of each kind of outcome check: a decoded NaN panorama, a name with a bidi override
# (the message must escape it), an export refusing a depth layer of zeros
SLICE = ("5.predict-nan.exr", "9.info-name-bidi-override", "5.export-zero-depth")


def test_the_corpus_holds_every_class(capsys):
    assert corpus.main(["--list"]) == 0
    keys = capsys.readouterr().out.splitlines()
    assert len(keys) == len(set(keys)) >= 278
    per_class = Counter(k.split(".")[0] for k in keys)
    assert sorted(per_class) == [str(c) for c in range(1, 10)]
    assert min(per_class.values()) >= 12


@pytest.mark.slow
def test_a_slice_of_the_corpus_runs_clean(tmp_path):
    # the driver runs in its own small interpreter: a command's peak memory is read from wait4, and a
    # child forked from this test process (torch loaded, GBs by the end of a suite) would report ours
    out = tmp_path / "corpus.json"
    argv = [a for key in SLICE for a in ("--only", key)] + ["--json", str(out)]
    run = subprocess.run([sys.executable, "-m", "support.robustness.corpus", *argv], env=corpus.support_env(),
                         capture_output=True, text=True, timeout=600)
    doc = json.loads(out.read_text())
    outcomes = {c["key"]: c["outcome"] for c in doc["cases"]}
    assert outcomes == dict.fromkeys(SLICE, "OK"), run.stdout[-3000:]
    assert run.returncode == 0, run.stderr[-2000:]
    export = next(c for c in doc["cases"] if c["key"] == "5.export-zero-depth")
    assert export["rc"] == 2 and "depth" in export["note"]
    assert all(c["peak_mb"] < 1000 for c in doc["cases"]), doc["cases"]
