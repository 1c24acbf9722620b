"""Running a corpus of corrupt files through a loader in a child interpreter (the robustness tests)."""

from __future__ import annotations

import json
import subprocess
import sys


def corpus_outcomes(child: str, paths: list) -> dict[str, str]:
    """Load every file of a corrupt corpus in one child interpreter running ``child`` (a crash there
    can't take the test run down): {path: "ok" | "InputError"}; any other outcome fails."""
    proc = subprocess.run([sys.executable, "-c", child, *map(str, paths)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, f"interpreter crashed ({proc.returncode}): {proc.stderr[-2000:]}"
    lines = proc.stdout.splitlines()
    assert lines[-1] == "done"
    results = dict(json.loads(line) for line in lines[:-1])
    assert len(results) == len(paths)
    assert set(results.values()) <= {"ok", "InputError"}, results
    return results
