"""The second robustness corpus (tests/support/robustness): its cases, and a slice of them run."""

from __future__ import annotations

import json
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
def test_a_slice_of_the_corpus_runs_clean(tmp_path, capsys):
    out = tmp_path / "corpus.json"
    rc = corpus.main([a for key in SLICE for a in ("--only", key)] + ["--json", str(out)])
    doc = json.loads(out.read_text())
    outcomes = {c["key"]: c["outcome"] for c in doc["cases"]}
    assert outcomes == dict.fromkeys(SLICE, "OK"), capsys.readouterr().out
    assert rc == 0
    export = next(c for c in doc["cases"] if c["key"] == "5.export-zero-depth")
    assert export["rc"] == 2 and "depth" in export["note"]
