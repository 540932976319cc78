"""Reads a Baton recording (.rrd) back with the Rerun SDK of the same version (rerun-sdk==0.36.3) and prints, as
JSON its entity paths; per step, the states logged on `sfc/steps/<step>` with their `wall` time in ms; per
variable, the values logged on `vars/<name>`; per token, the (level, text) entries of `tokens/<id>`; and how many colour updates `sfc/graph` has.

    python3 tests/scripts/read_recording.py RUN.rrd

Used by tests/tests/recording.rs to check a recording against the run's trace."""

import json
import sys

from rerun.experimental import RrdReader


def main(path):
    store = RrdReader(path).stream().collect()
    paths = sorted(str(p) for p in store.schema().entity_paths())
    df = store.reader(index="wall").to_pandas()
    steps = {}
    prefix = "/sfc/steps/"
    for column in df.columns:
        if not (column.startswith(prefix) and column.endswith(":StateChange:state")):
            continue
        step = column[len(prefix):-len(":StateChange:state")]
        rows = df[["wall", column]].dropna()
        changes = []
        for _, row in rows.iterrows():
            wall_ms = int(round(row["wall"].value / 1e6))
            for state in row[column]:
                changes.append([wall_ms, str(state)])
        steps[step] = changes
    variables = {}
    prefix = "/vars/"
    for column in df.columns:
        if not (column.startswith(prefix) and column.endswith(":Scalars:scalars")):
            continue
        name = column[len(prefix):-len(":Scalars:scalars")]
        rows = df[["wall", column]].dropna()
        variables[name] = [[int(round(r["wall"].value / 1e6)), float(r[column][0])] for _, r in rows.iterrows()]
    tokens = {}
    prefix = "/tokens/"
    for column in df.columns:
        if not (column.startswith(prefix) and column.endswith(":TextLog:text")):
            continue
        token = column[len(prefix):-len(":TextLog:text")]
        level = column.replace(":TextLog:text", ":TextLog:level")
        rows = df[["wall", column, level]].dropna(subset=[column])
        tokens[token] = [[str(r[level][0]) if r[level] is not None else "", str(r[column][0])] for _, r in rows.iterrows()]
    colours = "/sfc/graph:GraphNodes:colors"
    colour_updates = int(df[colours].notna().sum()) if colours in df.columns else 0
    print(json.dumps({"entity_paths": paths, "steps": steps, "vars": variables, "tokens": tokens, "graph_colour_updates": colour_updates}))


if __name__ == "__main__":
    main(sys.argv[1])
