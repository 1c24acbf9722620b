"""Case type, input setups and result checks of the second robustness corpus
(tests/support/robustness/corpus.py).

A case is a command line (``{b}``: the base inputs' folder, ``{w}``: the case's own folder, also its
working directory), what to expect (``refuse``: exit 2 with one line naming ``names``; ``ok``: exit 0;
``either``; ``signal``), an optional ``setup`` (writes the hostile input into the case folder) and
``check`` (inspects the result: ``(outcome, note)`` or None).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from phyir.learn.weights import default_weights_path

WEIGHTS = default_weights_path()
BIN = Path(sys.executable).parent
VALUES = ("1e400", "-0", "+inf", "0x10", "1_000", "\u0661\u0662", "", " ")  # class 7's spellings
SIZES = ("64X32", "64x", "x32", "-64x-32", "64x32x1", "1e400x5", "\u0666\u0664x\u0661\u0662\u0668",
         " 32 x 64 ", "32\u00d764")


@dataclass
class Case:
    cls: int
    name: str
    argv: list[str]
    expect: str = "refuse"
    names: tuple[str, ...] = ()
    setup: Callable[[Path], str | None] | None = None
    check: Callable | None = None
    timeout: float = 90
    stdin: bytes | None = None
    fsize: int | None = None
    trigger: Callable | None = None
    gl: bool = False
    env: dict = field(default_factory=dict)
    close_stdout: bool = False
    base: Path = Path()

    @property
    def key(self) -> str:
        return f"{self.cls}.{self.name}"

    @property
    def cmd(self) -> str:
        return self.argv[0]

    def render(self, folder: Path) -> list[str]:
        return [a.replace("{b}", str(self.base)).replace("{w}", str(folder)) for a in self.argv]


def have_egl() -> bool:
    code = "from viewer.gl.window import gl_context; gl_context().release()"
    try:
        return subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


# ---------------------------------------------------------------------------------------------
# setups


def write(**files) -> Callable[[Path], None]:
    def setup(w: Path) -> None:
        for name, data in files.items():
            p = w / name.replace("__", "/")
            p.parent.mkdir(parents=True, exist_ok=True)
            data = data() if callable(data) else data  # big inputs are made when the case runs
            p.write_bytes(data.encode() if isinstance(data, str) else data)
    return setup


def named(name: str, data: bytes) -> Callable[[Path], None]:
    """A file whose name ``write``'s keywords can't spell (spaces, control characters, ...)."""
    def setup(w: Path) -> None:
        (w / name).write_bytes(data)
    return setup


def fifo(*names: str) -> Callable[[Path], None]:
    def setup(w: Path) -> None:
        for n in names:
            (w / n).parent.mkdir(parents=True, exist_ok=True)
            os.mkfifo(w / n)
    return setup


def sock(name: str) -> Callable[[Path], None]:
    def setup(w: Path) -> None:
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(w / name))
        s.close()  # the socket file stays
    return setup


def mkdir(*names: str) -> Callable[[Path], None]:
    def setup(w: Path) -> None:
        for n in names:
            (w / n).mkdir(parents=True)
    return setup


def link(target: str, name: str) -> Callable[[Path], None]:
    def setup(w: Path) -> None:
        os.symlink(target, w / name)
    return setup


def copy(base: Path, src: str, name: str) -> Callable[[Path], None]:
    def setup(w: Path) -> None:
        (w / name).parent.mkdir(parents=True, exist_ok=True)
        s = base / src
        (shutil.copytree if s.is_dir() else shutil.copy)(s, w / name)
    return setup


def both(*fns) -> Callable[[Path], None]:
    def setup(w: Path) -> None:
        for f in fns:
            f(w)
    return setup


# ---------------------------------------------------------------------------------------------
# checks


def warned(r) -> tuple[str, str] | None:
    """Exit 0 must come with a warning (the input carries no information)."""
    if r.rc == 0 and "warning" not in r.err.lower():
        last = (r.out.strip().splitlines() or [""])[-1]
        return "SILENT-NONSENSE", "exit 0 without a warning: " + last[:120]
    return None


def python_warning_format(r) -> tuple[str, str] | None:
    """A warning printed as Python's ``file.py:12: UserWarning: ...`` plus a source line."""
    for line in r.err.splitlines():
        if "Warning:" in line and ".py:" in line:
            return "BAD-MESSAGE", "a Python warning with a source line: " + line.strip()[:140]
    return None


def chain(*checks) -> Callable:
    def check(r):
        for c in checks:
            v = c(r)
            if v:
                return v
        return None
    return check


def outputs_whole(*names: str) -> Callable:
    """A set of outputs: all present (exit 0) or none (anything else)."""
    def check(r):
        there = [n for n in names if (r.folder / n).is_file()]
        if r.rc == 0 and len(there) != len(names):
            return "JUNK", f"exit 0 but only {there} of {list(names)}"
        if r.rc != 0 and there:
            return "JUNK", f"exit {r.rc} and a partial set {there} of {list(names)}"
        return None
    return check


def interrupted(r) -> tuple[str, str] | None:
    if r.rc == 0:
        r.note = "finished before the signal: " + r.note
    elif "Traceback" in r.err or len([x for x in r.err.splitlines() if x.strip()]) > 2:
        return "BAD-MESSAGE", r.err.strip().replace("\n", " | ")[-200:]
    return None


def no_nan_json(path: str) -> Callable:
    """The glTF's JSON (or a JSON file) is strict JSON: no NaN / Infinity."""
    def check(r):
        p = r.folder / path
        if not p.exists():
            return None
        data = p.read_bytes()
        if path.endswith(".glb"):
            n = struct.unpack("<I", data[12:16])[0]
            data = data[20:20 + n]
        try:
            json.loads(data, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
        except ValueError as e:
            return "SILENT-NONSENSE", f"{path} holds {e} (not valid JSON)"
        return None
    return check


def then(argv: list[str], expect_rc: int = 0) -> Callable:
    """After the case, ``phyir ARGV`` (in the case's folder) must exit ``expect_rc``."""
    def check(r):
        p = subprocess.run([str(BIN / "phyir"), *argv], cwd=r.folder, capture_output=True, text=True,
                           timeout=300)
        if p.returncode != expect_rc:
            return "JUNK", f"then `phyir {' '.join(argv)}` exits {p.returncode}: {p.stderr.strip()[-160:]}"
        return None
    return check


def same_info_as(other: str, this: str) -> Callable:
    """``phyir info`` of the case's file shows the same values as of ``other`` (a twin encoding)."""
    def check(r):
        if r.rc != 0:  # refused in one line: fine
            return None
        a = subprocess.run([str(BIN / "phyir"), "info", other], cwd=r.folder, capture_output=True, text=True)
        strip = [ln for ln in a.stdout.splitlines()[1:]]
        got = [ln for ln in r.out.splitlines()[1:]]
        if strip != got:
            return "SILENT-NONSENSE", f"decoded differently from {other}: {got[2:3]} vs {strip[2:3]}"
        return None
    return check


def on_temporary(sig: int, sub: str = "", delay: float = 0.0) -> Callable:
    """Trigger: send ``sig`` once a temporary appears in the case folder (or ``sub``) and ``delay``
    seconds passed; or when the command's stdout log is non-empty (``sub`` = ``"stdout"``)."""
    def make(folder: Path, out_log: Path | None = None):
        seen = {"t": None}

        def fire(pid: int) -> bool:
            hit = False
            if sub == "stdout":
                hit = out_log is not None and out_log.exists() and out_log.stat().st_size > 0
            else:
                for _, _, names in os.walk(folder / sub):
                    if any(n.endswith(".phyir.tmp") for n in names):
                        hit = True
                        break
            if hit and seen["t"] is None:
                seen["t"] = time.monotonic()
            if seen["t"] is not None and time.monotonic() - seen["t"] >= delay:
                os.kill(pid, sig)
                return True
            return False
        return fire
    return make
