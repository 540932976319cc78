"""Validates a `baton test --junit` report against the Surefire/Jenkins JUnit schema (junit-10.xsd, as pytest's
source distribution ships it for its own JUnit tests), with xmlschema.

The schema has no `file` and `line` on `testcase`; Baton writes them (as pytest's xunit1 family and GitLab's
reader do) so that a failure points at the expectation. They are checked here to be what they must be — a
file, and a line number on every expectation's case — and then taken off, and the rest must be valid as is.

usage: validate_junit.py SCHEMA REPORT  — prints `valid TESTCASES` or the schema's complaints (exit 1).
"""
import sys
import xml.etree.ElementTree as ET

import xmlschema

schema = xmlschema.XMLSchema(sys.argv[1])
tree = ET.parse(sys.argv[2])
cases = list(tree.iter("testcase"))
for case in cases:
    if not case.get("file"):
        sys.exit(f"testcase {case.get('name')!r} has no file")
    line = case.attrib.pop("line", None)
    if line is not None and not line.isdigit():
        sys.exit(f"testcase {case.get('name')!r} has line {line!r}")
    del case.attrib["file"]
errors = list(schema.iter_errors(tree))
for e in errors[:10]:
    print(e.reason, "at", e.path)
if errors:
    sys.exit(1)
print("valid", len(cases))
