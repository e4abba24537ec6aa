//! The core's modules form layers with no cycles: each uses only the modules of the layers
//! below it (and itself). Read from the sources (outside comments and test modules), so a new
//! `use crate::...` that points up fails here, naming the file and the module.
use std::path::{Path, PathBuf};

/// Lowest first; modules in one inner list may not use each other.
const LAYERS: &[&[&str]] =
    &[&["error", "par"], &["watch", "memory", "trig", "interp"], &["model"], &["dynamics"], &["integrators"], &["run"], &["chaos"], &["facts"]];

fn layer(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&module))
}

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn no_module_uses_one_above_it() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut bad = Vec::new();
    let mut seen = 0;
    for file in &files {
        let rel = file.strip_prefix(&src).unwrap();
        let own = rel.components().next().unwrap().as_os_str().to_str().unwrap().trim_end_matches(".rs").to_string();
        // Tests may use any layer (the integrators' are run through the driver).
        if own == "lib" || rel.file_name().is_some_and(|f| f == "tests.rs") {
            continue;
        }
        let own_layer = layer(&own).unwrap_or_else(|| panic!("{}: module {own} is in no layer", rel.display()));
        let text = std::fs::read_to_string(file).unwrap();
        let code = text.split("#[cfg(test)]").next().unwrap_or("");
        for (i, line) in code.lines().enumerate() {
            if line.trim_start().starts_with("//") {
                continue; // docs may link anywhere
            }
            let mut rest = line;
            while let Some(at) = rest.find("crate::") {
                rest = &rest[at + 7..];
                let used: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                seen += 1;
                if used == own {
                    continue;
                }
                match layer(&used) {
                    Some(l) if l < own_layer => {}
                    Some(_) => bad.push(format!("{}:{}: {own} uses {used}", rel.display(), i + 1)),
                    None => bad.push(format!("{}:{}: {used} is in no layer", rel.display(), i + 1)),
                }
            }
        }
    }
    assert!(seen > 50, "only {seen} crate paths read: is the scan reading the sources?");
    assert!(bad.is_empty(), "uses that point up a layer (or sideways):\n{}", bad.join("\n"));
}
