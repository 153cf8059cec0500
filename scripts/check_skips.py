#!/usr/bin/env python3
"""Lists every GoogleTest case that skipped, with its reason, and fails on any not allowed.

    scripts/check_skips.py RESULTS_DIR [ALLOW_LIST]   (default: tests/skip_allowlist.txt)
    scripts/check_skips.py --self-test

RESULTS_DIR holds the XML reports GoogleTest writes when GTEST_OUTPUT=xml:RESULTS_DIR/ is set
(scripts/run-tests.sh sets it for the whole ctest run; a binary run twice writes NAME_1.xml).
A skip is a failure unless a line of the allow-list matches it: `Suite.Case | reason`, where
Suite.Case may hold shell wildcards (fnmatch) and the reason says why that skip is legitimate on a
machine scripts/setup.sh prepared. A line without a reason is an error. Exit 0: no skip outside the
list; 1: some; 2: bad arguments or an unreadable report (named).
"""
import fnmatch
import os
import sys
import tempfile
import xml.etree.ElementTree as ET


def read_allow_list(path):
    entries = []
    with open(path, encoding="utf-8") as f:
        for number, line in enumerate(f, 1):
            text = "" if line.lstrip().startswith("#") else line.strip()
            if not text:
                continue
            pattern, sep, reason = text.partition("|")
            if not sep or not pattern.strip() or not reason.strip():
                raise ValueError(f"{path}:{number}: expected 'Suite.Case | reason', got '{text}'")
            entries.append((pattern.strip(), reason.strip()))
    return entries


def skipped_cases(results_dir):
    """(Suite.Case, reason, report file) of every skipped case in the XML reports."""
    found = []
    names = sorted(n for n in os.listdir(results_dir) if n.endswith(".xml"))
    for name in names:
        path = os.path.join(results_dir, name)
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError as e:
            raise ValueError(f"{path}: not a GoogleTest XML report ({e})") from e
        for case in root.iter("testcase"):
            skipped = case.find("skipped")
            if skipped is None and case.get("result") != "skipped":
                continue
            reason = ""
            if skipped is not None:
                reason = (skipped.get("message") or skipped.text or "").strip()
            # GoogleTest prefixes the message with the file:line of the GTEST_SKIP.
            reason = reason.splitlines()[-1] if reason else "(no reason given)"
            found.append((f"{case.get('classname')}.{case.get('name')}", reason, name))
    return found, len(names)


def check(results_dir, allow_path, out=sys.stdout):
    if not os.path.isdir(results_dir):
        print(f"check_skips: {results_dir}: no such folder of GoogleTest reports", file=out)
        return 2
    try:
        allowed = read_allow_list(allow_path)
        skipped, reports = skipped_cases(results_dir)
    except (OSError, ValueError) as e:
        print(f"check_skips: {e}", file=out)
        return 2
    bad = 0
    for case, reason, report in skipped:
        match = next((r for p, r in allowed if fnmatch.fnmatchcase(case, p)), None)
        if match is None:
            bad += 1
            print(f"check_skips: SKIPPED, not allowed: {case} ({report}): {reason}", file=out)
        else:
            print(f"check_skips: skipped, allowed: {case}: {reason} [allowed because: {match}]",
                  file=out)
    print(f"check_skips: {len(skipped)} skipped case(s) in {reports} report(s), {bad} not on "
          f"{allow_path}", file=out)
    return 1 if bad else 0


def self_test():
    report = """<?xml version="1.0" encoding="UTF-8"?>
<testsuites><testsuite name="A">
<testcase name="Runs" status="run" result="completed" classname="A"/>
<testcase name="Skips" status="run" result="skipped" classname="A">
<skipped message="x.cc:3&#x0A;needs a thing"><![CDATA[x.cc:3
needs a thing]]></skipped></testcase>
</testsuite></testsuites>"""
    with tempfile.TemporaryDirectory() as d:
        results = os.path.join(d, "xml")
        os.mkdir(results)
        with open(os.path.join(results, "a_test.xml"), "w", encoding="utf-8") as f:
            f.write(report)
        allow = os.path.join(d, "allow.txt")
        log = open(os.path.join(d, "log"), "w+", encoding="utf-8")
        with open(allow, "w", encoding="utf-8") as f:
            f.write("# nothing allowed\n")
        assert check(results, allow, log) == 1, "an unlisted skip must fail"
        log.seek(0)
        text = log.read()
        assert "SKIPPED, not allowed: A.Skips (a_test.xml): needs a thing" in text, text
        with open(allow, "w", encoding="utf-8") as f:
            f.write("A.Sk* | the thing is optional\n")
        assert check(results, allow, log) == 0, "a listed skip must pass"
        with open(allow, "w", encoding="utf-8") as f:
            f.write("A.Skips\n")
        assert check(results, allow, log) == 2, "an entry without a reason must be refused"
        with open(os.path.join(results, "broken.xml"), "w", encoding="utf-8") as f:
            f.write("<testsuites>")
        with open(allow, "w", encoding="utf-8") as f:
            f.write("A.Sk* | the thing is optional\n")
        assert check(results, allow, log) == 2, "an unreadable report must be refused"
        assert check(os.path.join(d, "missing"), allow, log) == 2
    print("check_skips: self-test passed")
    return 0


def main(argv):
    if argv[1:] == ["--self-test"]:
        return self_test()
    if len(argv) not in (2, 3):
        print(__doc__, file=sys.stderr)
        return 2
    here = os.path.dirname(os.path.abspath(__file__))
    allow = argv[2] if len(argv) == 3 else os.path.join(here, "..", "tests", "skip_allowlist.txt")
    return check(argv[1], os.path.normpath(allow))


if __name__ == "__main__":
    sys.exit(main(sys.argv))
