//! `docs/book/src/standard-library.md` is a contract: every name of IEC 61131-3's tables of standard functions and
//! function blocks has a row; a row marked `yes` compiles its example in a chart; a row marked `no` is refused by
//! the compiler and says why.

use std::path::Path;

use baton_proto::pipeline::check_source;

/// The names of the standard's tables (IEC 61131-3 ed. 3, tables 22 to 39 and 43 to 46), as the doc writes
/// them (`*_TO_**` stands for every conversion between two elementary types).
const STANDARD: &[&str] = &[
    // 22: type conversion
    "*_TO_**",
    "TO_**",
    "TRUNC",
    "*_TRUNC_**",
    "*_BCD_TO_**",
    "**_TO_BCD_*",
    // 28: numerical
    "ABS",
    "SQRT",
    "LN",
    "LOG",
    "EXP",
    "SIN",
    "COS",
    "TAN",
    "ASIN",
    "ACOS",
    "ATAN",
    "ATAN2",
    // 29: arithmetic
    "ADD",
    "MUL",
    "SUB",
    "DIV",
    "MOD",
    "EXPT",
    "MOVE",
    // 30, 31: bit shift, bitwise Boolean
    "SHL",
    "SHR",
    "ROL",
    "ROR",
    "AND",
    "OR",
    "XOR",
    "NOT",
    // 32: selection
    "SEL",
    "MAX",
    "MIN",
    "LIMIT",
    "MUX",
    // 33: comparison
    "GT",
    "GE",
    "EQ",
    "LE",
    "LT",
    "NE",
    // 34: character strings
    "LEN",
    "LEFT",
    "RIGHT",
    "MID",
    "CONCAT",
    "INSERT",
    "DELETE",
    "REPLACE",
    "FIND",
    // 35: time and duration
    "ADD_TIME",
    "ADD_LTIME",
    "ADD_TOD_TIME",
    "ADD_LTOD_LTIME",
    "ADD_DT_TIME",
    "ADD_LDT_LTIME",
    "SUB_TIME",
    "SUB_LTIME",
    "SUB_DATE_DATE",
    "SUB_LDATE_LDATE",
    "SUB_TOD_TIME",
    "SUB_LTOD_LTIME",
    "SUB_TOD_TOD",
    "SUB_LTOD_LTOD",
    "SUB_DT_TIME",
    "SUB_LDT_LTIME",
    "SUB_DT_DT",
    "SUB_LDT_LDT",
    "MUL_TIME",
    "MUL_LTIME",
    "DIV_TIME",
    "DIV_LTIME",
    // 36: CONCAT and SPLIT of dates and times
    "CONCAT_DATE_TOD",
    "CONCAT_DATE_LTOD",
    "CONCAT_DATE",
    "CONCAT_TOD",
    "CONCAT_LTOD",
    "CONCAT_DT",
    "CONCAT_LDT",
    "SPLIT_DATE",
    "SPLIT_TOD",
    "SPLIT_LTOD",
    "SPLIT_DT",
    "SPLIT_LDT",
    "DAY_OF_WEEK",
    // 37: endianness; 39: validation
    "TO_BIG_ENDIAN",
    "TO_LITTLE_ENDIAN",
    "FROM_BIG_ENDIAN",
    "FROM_LITTLE_ENDIAN",
    "IS_VALID",
    "IS_VALID_BCD",
    // 43 to 46: bistables, edges, counters, timers
    "SR",
    "RS",
    "R_TRIG",
    "F_TRIG",
    "CTU",
    "CTU_INT",
    "CTU_DINT",
    "CTU_LINT",
    "CTU_UDINT",
    "CTU_ULINT",
    "CTD",
    "CTD_INT",
    "CTD_DINT",
    "CTD_LINT",
    "CTD_UDINT",
    "CTD_ULINT",
    "CTUD",
    "CTUD_INT",
    "CTUD_DINT",
    "CTUD_LINT",
    "CTUD_UDINT",
    "CTUD_ULINT",
    "TP",
    "TON",
    "TOF",
    "TP_TIME",
    "TON_TIME",
    "TOF_TIME",
    "TP_LTIME",
    "TON_LTIME",
    "TOF_LTIME",
];

struct Row {
    name: String,
    block: bool,
    supported: bool,
    example: String,
    notes: String,
}

fn rows() -> Vec<Row> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/book/src/standard-library.md");
    let text = std::fs::read_to_string(&path).expect("docs/book/src/standard-library.md");
    let mut rows = Vec::new();
    let mut block = false;
    for line in text.lines() {
        if line.starts_with("## ") {
            block = line == "## Function blocks";
        }
        let cells: Vec<&str> = line.trim_matches('|').split(" | ").map(str::trim).collect();
        if !line.starts_with("| `") || cells.len() != 5 || line.starts_with("## Where") {
            continue;
        }
        let code = |c: &str| c.trim_matches('`').to_string();
        // A name cell may go on in words ("`WSTRING_TO_STRING` and the other …"): the name is its first code span.
        let name = cells[0].split('`').nth(1).unwrap_or_default().to_string();
        rows.push(Row {
            name,
            block,
            supported: match cells[2] {
                "yes" => true,
                "no" => false,
                other => panic!("{}: Baton is `{other}`, not yes or no", cells[0]),
            },
            example: code(cells[3]),
            notes: cells[4].to_string(),
        });
    }
    rows
}

/// A chart that runs `example` in an action, with the doc's variables (and `f` of type `block`).
fn chart(example: &str, block: Option<&str>) -> String {
    let instance = block.map(|b| format!("  f : {b};\n")).unwrap_or_default();
    format!(
        "PROGRAM Lib\nVAR\n  b, b2 : BOOL; i, i2 : INT; di : DINT; ui : UINT; us : USINT; bt : BYTE; w : WORD; dw : DWORD;\n  \
         r : REAL; lr : LREAL; t : TIME; d : DATE; tod1 : TOD; dt1 : DT; s : STRING;\n{instance}END_VAR\n\
         INITIAL_STEP S0: A(N); END_STEP\nACTION A:\n  {example}\nEND_ACTION\nEND_PROGRAM\n"
    )
}

#[test]
fn every_name_of_the_standards_tables_has_a_row() {
    let rows = rows();
    let missing: Vec<&&str> = STANDARD.iter().filter(|n| !rows.iter().any(|r| r.name == **n)).collect();
    assert!(missing.is_empty(), "docs/book/src/standard-library.md has no row for {missing:?}");
}

#[test]
fn every_row_says_what_the_compiler_does() {
    let rows = rows();
    assert!(rows.len() >= STANDARD.len(), "{} rows", rows.len());
    let mut wrong = Vec::new();
    for row in &rows {
        let block = row.block.then_some(row.name.as_str());
        let report = check_source(&chart(&row.example, block));
        let errors: Vec<String> =
            report.diagnostics.iter().filter(|d| d.is_error()).map(|d| d.message.clone()).collect();
        if row.supported && !errors.is_empty() {
            wrong.push(format!("{} is `yes`, and `{}` is refused: {errors:?}", row.name, row.example));
        }
        if !row.supported && errors.is_empty() {
            wrong.push(format!("{} is `no`, and `{}` compiles", row.name, row.example));
        }
        if !row.supported && row.notes.len() < 20 {
            wrong.push(format!("{} is `no` without a reason", row.name));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}
