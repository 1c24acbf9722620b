"""``DIR/report.md`` and ``DIR/report.json``: every target of one ``phyir bench`` run in one place.

report.json holds the date, the command, the machine (:func:`phyir.bench.measure.machine_info`) and
per target: its wall time, its table (markdown), its key numbers (the target's ``key_numbers(result)``
or, failing that, the numbers at the top two levels of its result), its plots and its whole result.
Targets not run this time keep their entry from the folder's previous report when it was made
with the same ``--quick`` and device (each entry records its own ``date`` and ``command``), so
rerunning one target leaves the report whole.  The file is strict JSON: a value that is not finite
(an error on a layer a scene doesn't have, say) is written as ``null`` and its path listed in the
target's ``undefined``, so a reader can tell it from a number; :data:`ALLOWED_UNDEFINED` names the
ones that are expected.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import re
from pathlib import Path

# target -> regexes of result paths that may be undefined (not finite) by construction
ALLOWED_UNDEFINED = {
    # metals have no diffuse layer: its relative error divides by zero
    "render": [r"^scenes/metal/rows/\d+/err(_raw)?_diffuse$"],
}
TARGET_KEYS = ("date", "command", "seconds", "table", "key_numbers", "plots", "undefined", "result")
REPORT_KEYS = ("date", "command", "quick", "device", "threads", "repeats", "machine", "targets",
               "not_available", "total_seconds")


def write_json(path: Path, obj: object) -> None:
    """Atomic, indented JSON (NaN written as NaN: use :func:`sanitize` first for strict JSON)."""
    from phyir.io import atomic_write

    with atomic_write(path) as tmp:
        Path(tmp).write_text(json.dumps(obj, indent=1))


def target_config(full: dict, quick_config: dict, quick: bool, repeats: int | None) -> dict:
    """A target's settings: a copy of its quick or full configuration, ``repeats`` overriding."""
    cfg = dict(quick_config if quick else full)
    if repeats is not None:
        cfg["repeats"] = repeats
    return cfg


def save_target(out_dir: str | os.PathLike, name: str, result: dict, plot, format_table, log) -> None:
    """Write ``<name>.json`` and ``<name>.png`` (``plot(result, path)``) into ``out_dir`` and log the
    target's table."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / f"{name}.json", result)
    plot(result, out / f"{name}.png")
    log(format_table(result))


def save_figure(fig, path: Path, dpi: int = 100) -> None:
    """Write a matplotlib figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    from phyir.io import atomic_write

    with atomic_write(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)


def sanitize(obj: object, path: str = "", undefined: list[str] | None = None) -> object:
    """A copy of ``obj`` with non-finite floats as None (their paths appended to ``undefined``),
    tuples as lists and dict keys as strings."""
    if undefined is None:
        undefined = []
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        undefined.append(path)
        return None
    if isinstance(obj, dict):
        return {str(k): sanitize(v, f"{path}/{k}" if path else str(k), undefined) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [sanitize(v, f"{path}/{i}" if path else str(i), undefined) for i, v in enumerate(obj)]
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if hasattr(obj, "item"):  # numpy / torch scalars
        return sanitize(obj.item(), path, undefined)
    raise TypeError(f"bench report: {path}: cannot write {type(obj).__name__} as JSON")


def default_key_numbers(result: dict) -> dict[str, float]:
    """Numbers at the top two levels of a result (for targets without ``key_numbers``)."""
    out = {}
    for k, v in result.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            out[k] = float(v)
        elif isinstance(v, dict):
            out.update({f"{k}.{k2}": float(v2) for k2, v2 in v.items()
                        if isinstance(v2, (int, float)) and not isinstance(v2, bool)})
    return out


def render_key_numbers(result: dict) -> dict[str, float]:
    """Key numbers of :mod:`phyir.bench.render` (which has no ``key_numbers`` of its own)."""
    out = {}
    for kind, res in result["scenes"].items():
        rows = res["rows"]
        pref = next(r for r in rows if r["method"] == "prefiltered")
        best = max((r for r in rows if r["method"] == "importance"), key=lambda r: r["spp"])
        out[f"{kind}.prefiltered.ms"] = pref["median_s"] * 1e3
        out[f"{kind}.prefiltered.err_image"] = pref["err_image"]
        out[f"{kind}.importance_{best['spp']}spp.ms"] = best["median_s"] * 1e3
        out[f"{kind}.importance_{best['spp']}spp.err_image"] = best["err_image"]
        cmp = res["summary"].get("prefiltered_vs_is")
        if cmp:
            out[f"{kind}.prefiltered_speedup_at_equal_error"] = cmp["speedup_median"]
        sd = res.get("seeds")
        if sd and "speedup_cpu_median_of_seeds" in sd:
            tag = f"{kind}.prefiltered_speedup_cpu"
            out[f"{tag}.median_of_{len(sd['rows'])}_seeds"] = sd["speedup_cpu_median_of_seeds"]
            out[f"{tag}.min_of_{len(sd['rows'])}_seeds"] = sd["speedup_cpu_min_of_seeds"]
    for e in result["skips"][-1]["summary"]:
        out[f"skip.{e['skip']}.time_saved_frac"] = e["time_saved_frac"]
        out[f"skip.{e['skip']}.err_image"] = e["err_image"]
    return out


KEY_NUMBERS = {"render": render_key_numbers}  # for targets without their own key_numbers


def target_entry(name: str, module, result: dict, seconds: float, out_dir: Path,
                 log_lines: list[str]) -> dict:
    """The report's entry for one target run."""
    keys_fn = getattr(module, "key_numbers", None) or KEY_NUMBERS.get(name, default_key_numbers)
    table_fn = getattr(module, "format_table", None)
    table = table_fn(result) if table_fn is not None else "\n".join(log_lines)
    plots = sorted(p.name for p in out_dir.glob(f"{name}*.png"))
    undefined: list[str] = []
    clean = sanitize(result, "", undefined)
    key_undefined: list[str] = []
    keys = sanitize(keys_fn(result), "", key_undefined)
    return {"date": now(), "command": "", "seconds": seconds, "table": table, "key_numbers": keys,
            "key_numbers_undefined": key_undefined, "plots": plots, "undefined": undefined, "result": clean}


def unexpected_undefined(name: str, entry: dict) -> list[str]:
    """Undefined values of a target's entry that :data:`ALLOWED_UNDEFINED` doesn't expect."""
    pats = [re.compile(p) for p in ALLOWED_UNDEFINED.get(name, [])]
    bad = [p for p in entry["undefined"] if not any(r.search(p) for r in pats)]
    return bad + [f"key_numbers/{p}" for p in entry.get("key_numbers_undefined", [])]


def now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def build_report(entries: dict[str, dict], *, command: str, quick: bool, device: str, threads: int | None,
                 repeats: int | None, machine: dict, not_available: list[str], total_seconds: float) -> dict:
    return {"date": now(), "command": command, "quick": quick, "device": device, "threads": threads,
            "repeats": repeats, "machine": machine, "targets": entries, "not_available": not_available,
            "total_seconds": total_seconds}


def merge_previous(out_dir: str | os.PathLike, report: dict) -> list[str]:
    """Add to ``report`` the entries of ``out_dir/report.json`` for targets it lacks (same ``quick``
    and device, their ``<target>.json`` still there); returns their names."""
    path = Path(out_dir) / "report.json"
    if not path.is_file():
        return []
    try:
        prev = json.loads(path.read_text())
        same = prev.get("quick") == report["quick"] and prev.get("device") == report["device"]
        old = prev["targets"].items() if same else []
    except (ValueError, KeyError, AttributeError) as e:  # an unreadable old report is replaced
        print(f"bench report: {path}: not merged ({type(e).__name__}: {e})")
        return []
    added = []
    for name, e in old:
        if name not in report["targets"] and (Path(out_dir) / f"{name}.json").is_file() and "date" in e:
            report["targets"][name] = {**e, "machine": e.get("machine", prev.get("machine"))}
            added.append(name)
    return added


def format_markdown(report: dict) -> str:
    m = report["machine"]
    lines = ["# PhyIR benchmark report", "",
             f"- date: {report['date']}", f"- command: `{report['command']}`",
             f"- machine: {m['cpu']}, {m['cpu_cores']} cores ({m['cpu_cores_usable']} usable), "
             f"{m['memory_gb']} GB; {m['os']}",
             f"- torch {m['torch']} ({m['torch_threads']} threads), python {m['python']}, device "
             f"{m['device']} ({m['device_name']}), commit {m['git_commit']}",
             f"- load average at the start: {m.get('loadavg', 'n/a')}",
             f"- total time {report['total_seconds']:.0f} s"
             + (" (quick: small sizes, few repeats: a smoke test)" if report["quick"] else ""), ""]
    if report["not_available"]:
        lines += [f"Targets not available in this checkout: {', '.join(report['not_available'])}", ""]
    for name, e in report["targets"].items():
        lines += [f"## {name} ({e['seconds']:.0f} s)", ""]
        if "machine" in e:  # kept from an earlier run
            lines += [f"(from an earlier run: {e['date']}, `{e['command']}`, {e['machine']['cpu']})", ""]
        lines += [e["table"], ""]
        lines += [f"![{p}]({p})" for p in e["plots"]]
        if e["undefined"]:
            lines += ["", f"Undefined (not finite, written as null): {len(e['undefined'])} values, e.g. "
                      + ", ".join(f"`{p}`" for p in e["undefined"][:4])]
        lines.append("")
    return "\n".join(lines)


def write_report(out_dir: str | os.PathLike, report: dict) -> tuple[Path, Path]:
    """Write ``report.json`` (strict JSON) and ``report.md``; returns their paths."""
    from phyir.io import atomic_files

    out = Path(out_dir)
    js, md = out / "report.json", out / "report.md"
    report.setdefault("merged_from_earlier", merge_previous(out, report))
    with atomic_files([js, md]) as (js_tmp, md_tmp):  # one set: the JSON and its Markdown agree
        Path(js_tmp).write_text(json.dumps(report, indent=1, allow_nan=False))
        Path(md_tmp).write_text(format_markdown(report))
    return js, md
