//! JUnit XML for CI: one `testsuite` per scenario file, one `testcase` per expectation (with the `file` and
//! `line` of the expectation), a failure's message and the run's timeline in `system-out`. Written in the
//! shape Jenkins, GitLab and GitHub's test reporters read: Surefire's `junit-10.xsd`, plus `file` and `line` on
//! `testcase` as GitLab and pytest's xunit1 write them.

use crate::back::plcopen::esc as escape;

/// One scenario file's verdicts.
pub struct Suite {
    pub name: String,
    pub file: String,
    pub time_s: f64,
    /// A scenario that could not run: the whole suite is one error.
    pub error: Option<String>,
    pub cases: Vec<Case>,
    pub system_out: String,
}

impl Suite {
    /// A file that could not run (or was malformed): one error for the whole suite.
    pub fn error(name: &str, file: &str, time_s: f64, why: &str) -> Suite {
        Suite {
            name: name.to_string(),
            file: file.to_string(),
            time_s,
            error: Some(why.to_string()),
            cases: Vec::new(),
            system_out: String::new(),
        }
    }
}

pub struct Case {
    pub name: String,
    pub line: usize,
    pub failure: Option<String>,
}

/// The whole report. `interrupted` names what stopped the run early (an interrupt, a time limit): the suites
/// not run are missing, and the report says so in its `testsuites` element.
pub fn write(suites: &[Suite], interrupted: Option<&str>) -> String {
    let tests: usize = suites.iter().map(|s| s.cases.len().max(s.error.is_some() as usize)).sum();
    let failures: usize = suites.iter().map(|s| s.cases.iter().filter(|c| c.failure.is_some()).count()).sum();
    let errors = suites.iter().filter(|s| s.error.is_some()).count();
    let time: f64 = suites.iter().map(|s| s.time_s).sum();
    let mut x = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    let name = match interrupted {
        Some(why) => format!("baton test (interrupted: {why})"),
        None => "baton test".to_string(),
    };
    x.push_str(&format!(
        "<testsuites name=\"{}\" tests=\"{tests}\" failures=\"{failures}\" errors=\"{errors}\" time=\"{time:.3}\">\n",
        escape(&name)
    ));
    for s in suites {
        let failed = s.cases.iter().filter(|c| c.failure.is_some()).count();
        x.push_str(&format!(
            "  <testsuite name=\"{}\" tests=\"{}\" failures=\"{failed}\" errors=\"{}\" skipped=\"0\" time=\"{:.3}\" file=\"{}\">\n",
            escape(&s.name),
            s.cases.len().max(s.error.is_some() as usize),
            s.error.is_some() as usize,
            s.time_s,
            escape(&s.file)
        ));
        if let Some(e) = &s.error {
            x.push_str(&format!(
                "    <testcase name=\"{}\" classname=\"{}\" file=\"{}\" time=\"0\">\n      <error message=\"{}\">{}</error>\n    </testcase>\n",
                escape(&s.name),
                escape(&s.name),
                escape(&s.file),
                escape(e.lines().next().unwrap_or_default()),
                escape(e)
            ));
        }
        for c in &s.cases {
            x.push_str(&format!(
                "    <testcase name=\"{}\" classname=\"{}\" file=\"{}\" line=\"{}\" time=\"0\"",
                escape(&c.name),
                escape(&s.name),
                escape(&s.file),
                c.line
            ));
            match &c.failure {
                None => x.push_str("/>\n"),
                Some(f) => x.push_str(&format!(
                    ">\n      <failure message=\"{}\" type=\"expectation\">{}</failure>\n    </testcase>\n",
                    escape(f.lines().next().unwrap_or_default()),
                    escape(f)
                )),
            }
        }
        if !s.system_out.is_empty() {
            x.push_str(&format!("    <system-out>{}</system-out>\n", escape(&s.system_out)));
        }
        x.push_str("  </testsuite>\n");
    }
    x.push_str("</testsuites>\n");
    x
}
