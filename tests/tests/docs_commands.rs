//! The commands the README and the docs show, checked as written (issue 28: "the README's commands
//! all work as written").
//!
//! Every line of every fenced `sh` block of `README.md`, `docs/*.md` and `firmware/README.md` is
//! split as the shell would (quotes, comments, `\` continuations, `VAR=…` lines expanded), cut at
//! `&&`, `;`, `|` and `&`, and each command either checked or skipped with its reason:
//!
//! - one of this workspace's programs (`target/release/sonar-…`, `sonar-…`, `sonar`) and
//!   `scripts/demo.sh`: run as written with `--help` appended, against the debug build. clap
//!   parses every argument before the help (an unknown flag, a value its parser refuses, a flag
//!   given twice: the error the user would get) and then prints the help without starting
//!   anything, so a command that would fail on its arguments fails here, in milliseconds.
//!   Running them for real needs hardware, a pipeline or minutes; the end-to-end tests run those
//!   paths (pipeline, record/replay, export, bridge, viewer).
//!   `cargo run -p sonar-eval -- …` is checked as sonar-eval's arguments.
//! - anything else (cargo, the CI script, apt, ROS 2, Python, shell utilities, the benchmark
//!   script) and templates (`...` for the reader's values): skipped, the reason printed
//!   (`--nocapture` shows the whole list).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use sonar_e2e::{Sandbox, bin};

/// A command found in a document.
#[derive(Debug)]
struct Shown {
    file: String,
    line: usize,
    words: Vec<String>,
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The documents whose commands are checked.
fn documents() -> Vec<PathBuf> {
    let root = repo();
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    [root.join("README.md"), root.join("firmware/README.md")]
        .into_iter()
        .chain(docs)
        .collect()
}

/// `$NAME` and `${NAME}` replaced by the block's earlier `NAME=value` lines.
fn expand(line: &str, vars: &BTreeMap<String, String>) -> String {
    let mut out = line.to_owned();
    // Longest names first, so that `$AB` is not taken for `$A` followed by `B`.
    let mut names: Vec<&String> = vars.keys().collect();
    names.sort_by_key(|n| std::cmp::Reverse(n.len()));
    for name in names {
        out = out
            .replace(&format!("${{{name}}}"), &vars[name])
            .replace(&format!("${name}"), &vars[name]);
    }
    out
}

fn is_assignment(word: &str) -> bool {
    word.split_once('=').is_some_and(|(name, _)| {
        !name.is_empty() && name.chars().all(|c| c == '_' || c.is_ascii_alphanumeric())
    })
}

/// The commands of the fenced `sh` blocks of `path`.
fn commands_of(path: &Path) -> Vec<Shown> {
    let text = std::fs::read_to_string(path).unwrap();
    let file = path
        .strip_prefix(repo())
        .unwrap_or(path)
        .display()
        .to_string();
    let mut shown = Vec::new();
    let mut in_block = false;
    let mut vars: BTreeMap<String, String> = BTreeMap::new();
    let mut pending = String::new();
    for (i, raw) in text.lines().enumerate() {
        let fence = raw.trim_start();
        if fence.starts_with("```") {
            in_block = !in_block && matches!(fence.trim(), "```sh" | "```bash" | "```shell");
            vars.clear();
            continue;
        }
        if !in_block {
            continue;
        }
        if let Some(start) = raw.strip_suffix('\\') {
            pending.push_str(start);
            continue;
        }
        let line = std::mem::take(&mut pending) + raw;
        let words = shlex::split(&expand(&line, &vars))
            .unwrap_or_else(|| panic!("{file}:{}: the shell could not split {line:?}", i + 1));
        if !words.is_empty() && words.iter().all(|w| is_assignment(w)) {
            for w in &words {
                let (name, value) = w.split_once('=').unwrap();
                vars.insert(name.to_owned(), value.to_owned());
            }
            continue;
        }
        shown.extend(split_commands(words).into_iter().map(|words| Shown {
            file: file.clone(),
            line: i + 1,
            words,
        }));
    }
    // The README's commands in running text: `scripts/demo.sh …`, `target/release/… …`.
    if file == "README.md" {
        for (i, raw) in text.lines().enumerate() {
            for span in raw.split('`').skip(1).step_by(2) {
                let program = span.split(' ').next().unwrap_or_default();
                if span.contains(' ')
                    && (program == "scripts/demo.sh" || program.starts_with("target/release/"))
                {
                    let words = shlex::split(span).unwrap_or_default();
                    shown.extend(split_commands(words).into_iter().map(|words| Shown {
                        file: file.clone(),
                        line: i + 1,
                        words,
                    }));
                }
            }
        }
    }
    shown
}

/// One line's words cut into commands at `&&`, `||`, `;`, `|` and `&`, without the leading
/// `VAR=value` of each.
fn split_commands(words: Vec<String>) -> Vec<Vec<String>> {
    let mut commands = vec![Vec::new()];
    for word in words {
        let (word, ends) = match word.strip_suffix(';') {
            Some(w) => (w.to_owned(), true),
            None => (word, false),
        };
        if matches!(word.as_str(), "&&" | "||" | ";" | "|" | "&") {
            commands.push(Vec::new());
            continue;
        }
        let current = commands.last_mut().unwrap();
        let leading_assignment = current.is_empty() && is_assignment(&word);
        if !word.is_empty() && !leading_assignment {
            current.push(word);
        }
        if ends {
            commands.push(Vec::new());
        }
    }
    commands.retain(|c| !c.is_empty());
    commands
}

/// `cargo run -p PKG [--release] [--bin NAME | --example NAME] -- ARGS`: the program it runs (an
/// example as `examples/NAME`, where cargo puts it) and its arguments.
fn cargo_run(words: &[String]) -> Option<(String, Vec<String>)> {
    if words.get(1).map(String::as_str) != Some("run") {
        return None;
    }
    let split = words.iter().position(|w| w == "--").unwrap_or(words.len());
    let (cargo, args) = words.split_at(split);
    let value_of = |flag: &str| {
        cargo
            .iter()
            .position(|w| w == flag)
            .and_then(|i| cargo.get(i + 1))
            .cloned()
    };
    let program = value_of("--example")
        .map(|example| format!("examples/{example}"))
        .or_else(|| value_of("--bin"))
        .or_else(|| value_of("-p"))?;
    Some((program, args.iter().skip(1).cloned().collect()))
}

/// How a command is checked, or why it is not.
enum Check {
    /// This workspace's program (its file name in the debug build) with these arguments.
    Ours(String),
    /// `scripts/demo.sh`, run on the debug build.
    Demo,
    Skip(&'static str),
}

fn check_of(program: &str) -> Check {
    let name = program
        .strip_prefix("target/release/")
        .or_else(|| program.strip_prefix("target/debug/"))
        .unwrap_or(program);
    if (name == "sonar" || name.starts_with("sonar-")) && !name.contains('/') {
        return Check::Ours(name.to_owned());
    }
    // An example of this workspace, built by `cargo test` (or `cargo build --examples`).
    if name
        .strip_prefix("examples/")
        .is_some_and(|example| !example.is_empty() && !example.contains('/'))
    {
        return Check::Ours(name.to_owned());
    }
    match program {
        "scripts/demo.sh" => Check::Demo,
        "cargo" => Check::Skip("cargo: builds and tests are CI's own steps"),
        "bash" => Check::Skip("the CI script itself (`bash .ci/run`)"),
        "sudo" | "apt" | "apt-get" => Check::Skip("changes the system (packages, groups)"),
        "make" => Check::Skip("the firmware build: CI runs `make -C firmware test` and `make`"),
        "scripts/bench.sh" | "scripts/soak.sh" => {
            Check::Skip("the benchmarks and the soak run for minutes to an hour, outside CI")
        }
        "ros2" | "rviz2" => Check::Skip("needs ROS 2 (the bags are checked with rosbags instead)"),
        ".venv/bin/python3" | "python3" | "pip" => {
            Check::Skip("Python consumers: run by the consumers' end-to-end tests")
        }
        "wait" | "kill" | "ls" | "cd" | "ssh" | "iox2" | "avrdude" | "ip" => {
            Check::Skip("a shell or system tool in a shown sequence")
        }
        _ => Check::Skip("not one of this workspace's programs"),
    }
}

#[test]
fn every_command_the_docs_show_parses_as_written() {
    let sandbox = Sandbox::new("docs_cmds");
    let debug_dir = bin("sonar").parent().unwrap().to_path_buf();
    let mut checked = 0;
    let mut skipped: BTreeMap<&'static str, Vec<String>> = BTreeMap::new();
    let mut failures = Vec::new();
    for doc in documents() {
        for shown in commands_of(&doc) {
            let at = format!("{}:{}", shown.file, shown.line);
            // `cargo run -p sonar-eval -- …`: the arguments are sonar-eval's.
            let (program, args) = match cargo_run(&shown.words) {
                Some((program, args)) if debug_dir.join(&program).exists() => (program, args),
                _ => (shown.words[0].clone(), shown.words[1..].to_vec()),
            };
            // A template (`variant1.toml,variant2.toml,...`) names files the reader writes.
            let check = if shown.words.iter().any(|w| w.contains("...")) {
                Check::Skip("a template: `...` stands for the reader's own values")
            } else {
                check_of(&program)
            };
            let mut command = match check {
                Check::Skip(why) => {
                    skipped
                        .entry(why)
                        .or_default()
                        .push(format!("{at} {}", shown.words.join(" ")));
                    continue;
                }
                Check::Ours(name) => {
                    if !debug_dir.join(&name).exists() {
                        failures.push(format!("{at}: no program {name} in this workspace"));
                        continue;
                    }
                    sandbox.command(&name)
                }
                Check::Demo => {
                    let mut c = std::process::Command::new(repo().join("scripts/demo.sh"));
                    c.env("SONAR_DEMO_BIN_DIR", &debug_dir)
                        .env("SONAR_IOX_PREFIX", &sandbox.prefix)
                        .env("SONAR_IOX_ROOT", &sandbox.root);
                    c
                }
            };
            let out = command
                .args(&args)
                .arg("--help")
                .current_dir(repo())
                .stdin(std::process::Stdio::null())
                .output()
                .unwrap();
            checked += 1;
            let help = String::from_utf8_lossy(&out.stdout);
            if !out.status.success() || !help.contains("Usage:") {
                failures.push(format!(
                    "{at}: `{}` refused: {}{}",
                    shown.words.join(" "),
                    String::from_utf8_lossy(&out.stderr).trim(),
                    if out.status.success() {
                        " (no help printed)"
                    } else {
                        ""
                    }
                ));
            }
        }
    }
    println!("checked {checked} commands of this workspace's programs (arguments as written)");
    for (why, commands) in &skipped {
        println!("skipped {} ({why}):", commands.len());
        for c in commands {
            println!("    {c}");
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // The README alone shows more than twenty: a parser that found none must not pass.
    assert!(checked >= 40, "only {checked} commands found");
}

#[test]
fn the_extraction_splits_as_the_shell_does() {
    let dir = std::env::temp_dir().join(format!("sonar-docs-cmds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let doc = dir.join("x.md");
    std::fs::write(
        &doc,
        "text\n```sh\nC=\"--a 1 --b 2\"\nsonar-x $C --c 'a b' \\\n  --d   # comment\n\
         sonar-sim --link /tmp/t &  sonar-driver --port /tmp/t &\nFOO=1 cargo run && ls\n\
         wait %2; kill %1\n```\n\
         ```\nnot-sh --x\n```\n",
    )
    .unwrap();
    let shown: Vec<(usize, Vec<String>)> = commands_of(&doc)
        .into_iter()
        .map(|s| (s.line, s.words))
        .collect();
    let words = |s: &[&str]| s.iter().map(|w| (*w).to_owned()).collect::<Vec<_>>();
    assert_eq!(
        shown,
        vec![
            (
                5,
                words(&["sonar-x", "--a", "1", "--b", "2", "--c", "a b", "--d"])
            ),
            (6, words(&["sonar-sim", "--link", "/tmp/t"])),
            (6, words(&["sonar-driver", "--port", "/tmp/t"])),
            (7, words(&["cargo", "run"])),
            (7, words(&["ls"])),
            (8, words(&["wait", "%2"])),
            (8, words(&["kill", "%1"])),
        ]
    );
    let run = words(&[
        "cargo",
        "run",
        "-p",
        "sonar-eval",
        "--release",
        "--",
        "--suite",
    ]);
    assert_eq!(
        cargo_run(&run),
        Some(("sonar-eval".to_owned(), words(&["--suite"])))
    );
    assert_eq!(cargo_run(&words(&["cargo", "build"])), None);
    std::fs::remove_dir_all(&dir).unwrap();
}
