"""Reads a Baton recording (.rrd) back with the Rerun SDK of the same version (rerun-sdk==0.36.3) and prints, as
JSON, every row it holds, in the order they were logged:

    {"entity_paths": [...],
     "steps":  {step: [[wall_ms, state], ...]},      sfc/steps/<step>
     "agents": {name: [[wall_ms, state], ...]},      agents/<name>
     "tokens": {id: [[level, text], ...]},           tokens/<id>
     "log":    [[wall_ms, level, text], ...],        log
     "vars":   {name: [[wall_ms, value], ...]},      vars/<name>
     "graph_colour_updates": N,                      timed colour rows of sfc/graph
     "graph_nodes": [[id, label], ...],              the static nodes of sfc/graph
     "graph_edges": [[from, to], ...]}               its static edges

    python3 tests/scripts/read_recording.py RUN.rrd

Rows are read chunk by chunk (a dataframe query would keep one row per entity and instant). Used by
tests/tests/recording.rs to check a recording against the run's trace."""

import json
import sys

from rerun.experimental import RrdReader


def wall_ms(row):
    return int(round(row["wall"].value / 1e6))


def main(path):
    rows = []  # (row id, entity path, row)
    static = {}
    paths = set()
    for chunk in RrdReader(path).stream().to_chunks():
        entity = str(chunk.entity_path)
        paths.add(entity)
        if chunk.is_static:
            if entity == "/sfc/graph":
                for row in chunk.to_record_batch().to_pylist():
                    for key, value in row.items():
                        if key == "GraphNodes:node_ids" and value:
                            static["ids"] = value
                        elif key == "GraphNodes:labels" and value:
                            static["labels"] = value
                        elif key == "GraphEdges:edges" and value:
                            static["edges"] = value
            continue
        for row in chunk.to_record_batch().to_pylist():
            rows.append((row["rerun.controls.RowId"], entity, row))
    rows.sort(key=lambda r: r[0])
    out = {"entity_paths": sorted(paths), "steps": {}, "agents": {}, "tokens": {}, "log": [], "vars": {},
           "graph_colour_updates": 0}
    for _, entity, row in rows:
        if entity.startswith("/sfc/steps/") and row.get("StateChange:state"):
            out["steps"].setdefault(entity[len("/sfc/steps/"):], []).append([wall_ms(row), row["StateChange:state"][0]])
        elif entity.startswith("/agents/") and row.get("StateChange:state"):
            out["agents"].setdefault(entity[len("/agents/"):], []).append([wall_ms(row), row["StateChange:state"][0]])
        elif entity.startswith("/tokens/") and row.get("TextLog:text"):
            level = (row.get("TextLog:level") or [""])[0]
            out["tokens"].setdefault(entity[len("/tokens/"):], []).append([level, row["TextLog:text"][0]])
        elif entity == "/log" and row.get("TextLog:text"):
            out["log"].append([wall_ms(row), (row.get("TextLog:level") or [""])[0], row["TextLog:text"][0]])
        elif entity.startswith("/vars/") and row.get("Scalars:scalars"):
            out["vars"].setdefault(entity[len("/vars/"):], []).append([wall_ms(row), float(row["Scalars:scalars"][0])])
        elif entity == "/sfc/graph" and row.get("GraphNodes:colors"):
            out["graph_colour_updates"] += 1
    out["graph_nodes"] = [list(p) for p in zip(static.get("ids", []), static.get("labels", []))]
    out["graph_edges"] = [edge_pair(e) for e in static.get("edges", [])]
    print(json.dumps(out))


def edge_pair(e):
    if isinstance(e, dict):
        return [e.get("first") or e.get("source"), e.get("second") or e.get("target")]
    return list(e)


if __name__ == "__main__":
    main(sys.argv[1])
