//! The bundled multi-robot cell chart that `baton demo` runs, for any number of picking robots.
//! `examples/cell.st` is this chart for two robots; a test keeps the two identical.

/// The cell chart with `robots` picking robots (at least 1). Robot k picks in 300 + 100·k ms, so the branches
/// finish at different times and the convergence visibly waits for the slowest.
pub fn cell_chart(robots: usize) -> String {
    let robots = robots.max(1);
    let ks: Vec<usize> = (1..=robots).collect();
    let list = |f: &dyn Fn(usize) -> String| ks.iter().map(|&k| f(k)).collect::<Vec<_>>();
    let mut s = String::new();
    s.push_str(&format!(
        "(* A multi-robot cell, the chart `baton demo` runs.\n   {robots} robot(s) pick parts in parallel; when every robot has picked, a robot with the role\n   `assembler` assembles the part and inspects it; inspection passes the part or sends it to rework; the\n   cell loops until `parts` parts are done. Skills are bound in the ACTIONs below (the user guide's chapter\n   \"Skills and devices\" says how). *)\n"
    ));
    s.push_str(
        "PROGRAM cell\nVAR_INPUT\n  parts : INT := 3;\nEND_VAR\nVAR\n  done : INT := 0;\n  reworks : INT := 0;\n",
    );
    for k in &ks {
        s.push_str(&format!("  picked{k} : BOOL;\n"));
    }
    s.push_str("  assembled : BOOL;\n  passed : BOOL;\n  failed : BOOL;\n  reworked : BOOL;\nEND_VAR\n\n");
    s.push_str("INITIAL_STEP Idle: END_STEP\n");
    let picks = list(&|k| format!("Pick{k}"));
    let target = if robots == 1 { picks[0].clone() } else { format!("({})", picks.join(", ")) };
    s.push_str(&format!("TRANSITION Start FROM Idle TO {target} := done < parts; END_TRANSITION\n"));
    s.push_str("TRANSITION Stop FROM Idle TO Finished := done >= parts; END_TRANSITION\nSTEP Finished: END_STEP\n\n");
    for k in &ks {
        s.push_str(&format!(
            "STEP Pick{k}: {{agent := 'robot{k}'}} PickPart{k}(N, picked{k}); END_STEP\nTRANSITION FROM Pick{k} TO Picked{k} := picked{k}; END_TRANSITION\nSTEP Picked{k}: END_STEP\n"
        ));
    }
    let picked = list(&|k| format!("Picked{k}"));
    let source = if robots == 1 { picked[0].clone() } else { format!("({})", picked.join(", ")) };
    s.push_str(&format!("\nTRANSITION FROM {source} TO Assemble := TRUE; END_TRANSITION\n"));
    s.push_str(concat!(
        "STEP Assemble: {role := 'assembler'} AssemblePart(N, assembled); END_STEP\n",
        "TRANSITION FROM Assemble TO Inspect := assembled; END_TRANSITION\n",
        "STEP Inspect: {role := 'assembler'} InspectPart(N, passed, failed); END_STEP\n",
        "TRANSITION Pass FROM Inspect TO Count := passed; END_TRANSITION\n",
        "TRANSITION Fail FROM Inspect TO Rework := failed; END_TRANSITION\n",
        "STEP Rework: {role := 'assembler'} ReworkPart(N, reworked); CountRework(P); END_STEP\n",
        "TRANSITION FROM Rework TO Inspect := reworked; END_TRANSITION\n",
        "STEP Count: CountPart(P); END_STEP\n",
        "TRANSITION FROM Count TO Idle := TRUE; END_TRANSITION\n\n",
    ));
    for k in &ks {
        s.push_str(&format!("ACTION PickPart{k}: {{skill := 'motion', ms := {}}} END_ACTION\n", 300 + 100 * k));
    }
    s.push_str(concat!(
        "ACTION AssemblePart: {skill := 'motion', ms := 300} END_ACTION\n",
        "ACTION InspectPart: {skill := 'motion', ms := 100, fault_rate := 0.3} END_ACTION\n",
        "ACTION ReworkPart: {skill := 'motion', ms := 200} END_ACTION\n",
        "(* A P action's body runs once more with Q = FALSE when the step leaves (the IEC final scan): count once. *)\n",
        "ACTION CountRework: IF CountRework.Q THEN reworks := reworks + 1; END_IF; END_ACTION\n",
        "ACTION CountPart: IF CountPart.Q THEN done := done + 1; END_IF; END_ACTION\n",
        "END_PROGRAM\n",
    ));
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn examples_cell_is_the_two_robot_chart() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/cell.st");
        if std::env::var_os("UPDATE_EXPECT").is_some() {
            std::fs::write(path, cell_chart(2)).expect("write examples/cell.st");
        }
        let file = std::fs::read_to_string(path).expect("examples/cell.st");
        assert_eq!(file, cell_chart(2), "examples/cell.st differs from cell_chart(2): UPDATE_EXPECT=1 regenerates it");
    }

    #[test]
    fn cells_of_any_size_check_clean() {
        for robots in [1, 2, 3, 8] {
            let report = baton_proto::pipeline::check_source(&cell_chart(robots));
            assert_eq!(report.error_count(), 0, "{robots} robots: {:?}", report.diagnostics);
            let layout = report.charts[0].layout.as_ref().expect("layout");
            // One segment per picking robot, and one for the assembler (assemble, inspect, rework).
            assert_eq!(layout.segments.len(), robots + 1);
        }
    }
}
