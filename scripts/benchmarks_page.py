#!/usr/bin/env python3
"""Renders docs/benchmarks.md from docs/benchmarks/summary.json and the `slshadow bench --json`
output it names, so the page cannot drift from the figures it quotes.

    python3 scripts/benchmarks_page.py            # rewrite docs/benchmarks.md
    python3 scripts/benchmarks_page.py --check    # exit 1 when the page differs (a CTest test)

summary.json: {"intro": [lines], "bench_run": {"file", "commit", "command", "when"},
"areas": [{"title", "log": [paths under docs/benchmarks/], "rows": [row]}], "outro": [lines]}.
A row is {"figure", "slshadow", "peer", "ratio", "goal", "commit", "command"} (free text), or
{"bench_entry": NAME, "what": PREFIX, "goal": ...} to take the figure, the peer and the ratio
from the bench file's one entry NAME whose "what" starts with PREFIX (docs/formats.md, "Bench
results").
"""
import json
import os
import sys

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
DOCS = os.path.join(ROOT, "docs")
SUMMARY = os.path.join(DOCS, "benchmarks", "summary.json")
PAGE = os.path.join(DOCS, "benchmarks.md")
COLUMNS = ["figure", "slshadow", "peer in the same run", "ratio", "goal", "commit", "command"]


def fail(message):
    sys.stderr.write("benchmarks_page: " + message + "\n")
    sys.exit(2)


def cell(text):
    return str(text).replace("|", "\\|").replace("\n", " ")


def bench_row(entries, row, run, where):
    name, what = row["bench_entry"], row.get("what", "")
    matches = [e for e in entries if e["name"] == name and e["what"].startswith(what)]
    if len(matches) != 1:
        fail(f"{where}: bench_entry '{name}' what '{what}...' is not one entry of {run['file']}")
    e = matches[0]
    ours = f"{e['median_wall_s']:.3f} s wall, {e['cpu_s']:.3f} s CPU"
    if e["throughput"] > 0:
        ours += f", {e['throughput']:.1f} {e['unit']}"
    peer, ratio = "-", "-"
    if e["peer"]:
        peer = f"{e['peer']}: {e['peer_median_wall_s']:.3f} s"
        if e["peer_throughput"] > 0:
            peer += f", {e['peer_throughput']:.2f} {e['unit']}"
        ratio = f"**{e['ratio']:.1f}x**"
    return {
        "figure": row.get("figure", f"`{name}`: {e['what']}"),
        "slshadow": ours,
        "peer": peer,
        "ratio": ratio,
        "goal": row.get("goal", "-"),
        "commit": run["commit"],
        "command": f"`{run['command']}`",
    }


def render():
    try:
        with open(SUMMARY, encoding="utf-8") as f:
            summary = json.load(f)
    except (OSError, ValueError) as e:
        fail(f"{SUMMARY}: {e}")
    run = summary["bench_run"]
    bench_path = os.path.join(DOCS, "benchmarks", run["file"])
    try:
        with open(bench_path, encoding="utf-8") as f:
            bench = json.load(f)
    except (OSError, ValueError) as e:
        fail(f"{bench_path}: {e}")
    if bench.get("format") != "slshadow-bench" or bench.get("version") != 1:
        fail(f"{bench_path}: format must be slshadow-bench version 1")
    lines = list(summary["intro"])
    for area in summary["areas"]:
        logs = []
        for log in area["log"]:
            if not os.path.isfile(os.path.join(DOCS, "benchmarks", log)):
                fail(f"{SUMMARY}: area '{area['title']}': log '{log}' does not exist")
            logs.append(f"[{log}](benchmarks/{log})")
        lines += ["", f"## {area['title']}", "", "Log: " + ", ".join(logs) + ".", ""]
        lines.append("| " + " | ".join(COLUMNS) + " |")
        lines.append("|" + "---|" * len(COLUMNS))
        for i, row in enumerate(area["rows"]):
            if "bench_entry" in row:
                row = bench_row(bench["entries"], row, run, f"area '{area['title']}' row {i}")
            missing = [k for k in ["figure", "slshadow", "peer", "ratio", "goal", "commit", "command"] if k not in row]
            if missing:
                fail(f"{SUMMARY}: area '{area['title']}' row {i}: missing {', '.join(missing)}")
            lines.append("| " + " | ".join(cell(row[k]) for k in ["figure", "slshadow", "peer", "ratio", "goal",
                                                                  "commit", "command"]) + " |")
    if summary["outro"]:
        lines += [""] + list(summary["outro"])
    return "\n".join(lines) + "\n"


def main():
    check = sys.argv[1:] == ["--check"]
    if sys.argv[1:] and not check:
        fail("usage: benchmarks_page.py [--check]")
    text = render()
    if check:
        try:
            with open(PAGE, encoding="utf-8") as f:
                current = f.read()
        except OSError as e:
            fail(f"{PAGE}: {e}")
        if current != text:
            sys.stderr.write("docs/benchmarks.md differs from its rendering of docs/benchmarks/summary.json: "
                             "run python3 scripts/benchmarks_page.py\n")
            return 1
        return 0
    with open(PAGE + ".partial", "w", encoding="utf-8") as f:
        f.write(text)
    os.replace(PAGE + ".partial", PAGE)
    return 0


if __name__ == "__main__":
    sys.exit(main())
