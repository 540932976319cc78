"""Checks `baton test`'s published schema (docs/baton-test.schema.json) as an editor applies it, with
jsonschema: every scenario of the project validates, and the malformed one with an unknown key does not.
Prints how many scenarios were checked and whether the unknown key was named. Argument: the repository root."""

import glob
import json
import sys
import tomllib

import jsonschema

root = sys.argv[1]
schema = json.load(open(f"{root}/docs/baton-test.schema.json"))
files = sorted(glob.glob(f"{root}/examples/*.test.toml") + glob.glob(f"{root}/tests/baton_test/*/*.test.toml"))
files = [f for f in files if "/malformed/" not in f]
for f in files:
    with open(f, "rb") as scenario:
        jsonschema.validate(tomllib.load(scenario), schema)
with open(f"{root}/tests/baton_test/malformed/keys.test.toml", "rb") as bad:
    try:
        jsonschema.validate(tomllib.load(bad), schema)
        print("accepted a malformed file")
    except jsonschema.ValidationError as e:
        print(len(files), "untill" in e.message)
