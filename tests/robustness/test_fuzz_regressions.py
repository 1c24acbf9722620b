"""The file-reader fuzzer (``python -m phyir.bench.fuzz``, docs/robustness.md#fuzzing): the command runs and
finds new coverage, its outcome classification, and the inputs it found that broke a reader."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
from pathlib import Path

import pytest
from support.paths import REPO

from phyir.bench import fuzz


def run_fuzzer(tmp_path: Path, *args: str, timeout: float = 240) -> tuple[int, dict, str]:
    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE")
    p = subprocess.run([sys.executable, "-m", "phyir.bench.fuzz", "--out", str(tmp_path), *args], cwd=REPO,
                       env=env,
                       capture_output=True, text=True, timeout=timeout)
    report = json.loads((tmp_path / "report.json").read_text()) if (tmp_path / "report.json").exists() else {}
    return p.returncode, report, p.stdout + p.stderr


@pytest.mark.slow  # ~5 s of CPU each, but a child interpreter importing torch: ~50 s on a loaded machine
@pytest.mark.parametrize("engine", ["builtin", "atheris"])
def test_the_fuzz_command_runs_and_grows_its_corpus(tmp_path, engine):
    if engine == "atheris" and not fuzz.atheris_available():
        pytest.skip("atheris is not installed (the optional 'fuzz' extra)")
    rc, report, out = run_fuzzer(tmp_path, "--seconds", "4", "--target", "hdr", "--engine", engine)
    assert rc == 0, out
    (r,) = report["targets"]
    assert r["engine"] == engine and r["findings"] == [], out
    assert r["executions"] > 20, r
    seeds = len(fuzz.TARGETS["hdr"].seeds())
    assert r["corpus"] > seeds and r["coverage"] > 0, r  # coverage guidance kept new inputs
    assert f"hdr: {r['executions']} executions" in out


def test_every_seed_reads(tmp_path):
    """The seed corpora are valid files of their formats (else the fuzzer starts from refusals)."""
    for name, target in fuzz.TARGETS.items():
        outcomes = []
        for k, data in enumerate(target.seeds()):
            p = tmp_path / f"{name}{k}{target.suffix}"
            p.write_bytes(data)
            outcomes.append(fuzz.run_input(target, str(p)).kind)
        assert outcomes.count("ok") >= len(outcomes) - 1 and "finding" not in outcomes, (name, outcomes)


def test_outcomes_refusal_and_finding(tmp_path, monkeypatch):
    target = fuzz.TARGETS["hdr"]
    bad = tmp_path / "bad.hdr"
    bad.write_bytes(b"#?RADIANCE\n\n-Y 4 +X 8\n\x01")
    r = fuzz.run_input(target, str(bad))
    assert r.kind == "refused" and str(bad) in r.text and "\n" not in r.text
    from phyir import io

    def broken(path, panorama=True, limit=None):
        raise KeyError("oops")

    monkeypatch.setattr(io, "read_raw", broken)
    r = fuzz.run_input(target, str(bad))
    assert r.kind == "finding" and "KeyError: 'oops'" in r.text
    assert r.signature.startswith("KeyError at ")
    assert r.signature.endswith(f"test_fuzz_regressions.py:{broken.__code__.co_firstlineno + 1} in broken")


def test_mutations_are_seeded_and_bounded():
    seeds = fuzz.TARGETS["hdr"].seeds()
    tokens = fuzz.TARGETS["hdr"].tokens
    ra, rb = random.Random(3), random.Random(3)
    a = [fuzz.mutate(seeds[0], ra, seeds, tokens, 300) for _ in range(50)]
    b = [fuzz.mutate(seeds[0], rb, seeds, tokens, 300) for _ in range(50)]
    assert a == b and all(len(x) <= 300 for x in a)
    assert len(set(a)) > 40 and seeds[0] not in a  # they differ from each other and from the seed


# ---------------------------------------------------------------------------------------------
# regressions: inputs the fuzzer found (rebuilt here by code; the saved files are not committed)


@pytest.mark.parametrize("text", [
    # 'v 1 -1' (two coordinates): trimesh returned vertices [3, 2] -> ValueError in the normals
    b"o quad\nv -1 0 -1\nv 1 -1\nv 1 0 1\nv -1 0 1\nvt 0 0\nf 1/1 2/1 3/3/1 4/1\n",
    # 'v 10': vertices [4, 1] -> "incompatible dimensions for cross product"
    b"o quad\nv -1 0 -1\nv 1 0 -1\nv 10\nv 1 0 1\nv -1 0 1\nvt 0 0\nf 1/1 2/1 3/1 4/1\n",
    # 'v 0.0 0.' then form feeds: vertices [4, 0] -> "zero-size array to reduction operation"
    b"v 0.0 0.\nv 1 0 0\x0c\x0c\x0c\nv 0 1 0\nv 0 0 10 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nj 2 4 3\n",
    # 'v 2 3': vertices [4, 2] -> "array is not broadcastable" in np.add.at
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 0 -1\nv 1 0 1\nv 2 3\nf 1 3 4\nf 1 4 2\nf 2 0 3\n",
])
def test_obj_vertices_without_three_coordinates_are_refused(tmp_path, text):
    """Found by the mesh target (ValueError from numpy, not an InputError): now a one-line refusal."""
    from phyir.errors import InputError
    from phyir.insert.objects import load_mesh

    p = tmp_path / "bad.obj"
    p.write_bytes(text)
    with pytest.raises(InputError, match=r"bad\.obj: vertices must have 3 coordinates") as e:
        load_mesh(p)
    assert "\n" not in str(e.value)
