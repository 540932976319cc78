//! The charts `baton bench` measures with that a criterion bench runs too, so that both measure the same chart:
//! a loop that counts its passes on the coordinator, and phase (2)'s one-token round trip on agent `bench1`.

/// A chart named `name` that loops until `i` reaches `n`: its initial step `Home`, the exit `Stop` to `Finished`,
/// and the action `Count` that counts one pass each time a step runs it with `P`. The caller adds the loop's body
/// (from `Home` while `i < n`, back to `Home`) and `END_PROGRAM`.
pub fn counted_loop_header(name: &str, n: u64) -> String {
    format!(
        "PROGRAM {name}\nVAR\n  n : DINT := {n};\n  i : DINT := 0;\nEND_VAR\nINITIAL_STEP Home: END_STEP\n\
         TRANSITION Stop FROM Home TO Finished := i >= n; END_TRANSITION\nSTEP Finished: END_STEP\n\
         ACTION Count: IF Count.Q THEN i := i + 1; END_IF; END_ACTION\n"
    )
}

/// Phase (2): `n` times, a one-step segment on agent `bench1` (`Remote`) whose exit is TRUE at once, then `Back`
/// on the coordinator, which counts the pass.
pub fn token_round_trip(n: u64) -> String {
    let mut chart = counted_loop_header("token_rtt", n);
    chart.push_str(concat!(
        "TRANSITION Go FROM Home TO Remote := i < n; END_TRANSITION\n",
        "STEP Remote: {agent := 'bench1'} END_STEP\n",
        "TRANSITION FROM Remote TO Back := TRUE; END_TRANSITION\n",
        "STEP Back: Count(P); END_STEP\n",
        "TRANSITION FROM Back TO Home := TRUE; END_TRANSITION\nEND_PROGRAM\n",
    ));
    chart
}
