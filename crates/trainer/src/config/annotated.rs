//! The default configuration as an annotated TOML file (`cargo xtask train --print-config`): the
//! TOML of [`TrainConfig::default`] with each key's doc comment, read from this module's own
//! source, above it. The field docs are the one description of the keys; nothing restates them.

use super::TrainConfig;
use std::collections::HashMap;

/// The source whose field docs annotate the keys.
const SOURCE: &str = include_str!("mod.rs");

/// This module's structs and the TOML section each one is.
const SECTIONS: [(&str, &str); 9] = [
    ("TrainConfig", ""),
    ("DataConfig", "data"),
    ("BuiltinConfig", "data.builtin"),
    ("ModelConfig", "model"),
    ("RenderConfig", "render"),
    ("OptimConfig", "optim"),
    ("GuideConfig", "guide"),
    ("MiningConfig", "mining"),
    ("OutputConfig", "output"),
];

/// Sections whose keys are documented elsewhere (a library's struct), and where.
const LIBRARY_SECTIONS: [(&str, &str); 5] = [
    ("guide.scene", "Keys: prob_grid::SceneGridConfig (its documentation describes each)."),
    ("guide.camera", "Keys: prob_grid::CameraGridConfig (its documentation describes each)."),
    ("surface", "Keys: surface_losses::SurfaceLossConfig (its documentation describes each)."),
    ("optim.schedule", "Keys: sdf_backbone::LrSchedule (its documentation describes each)."),
    ("budget", "Keys: exactly one of `steps = N` and `seconds = X`."),
];

/// (section, key) → the field's doc comment, one paragraph.
fn field_docs() -> HashMap<(String, String), String> {
    let mut docs = HashMap::new();
    let mut section: Option<&str> = None;
    let mut doc: Vec<&str> = Vec::new();
    for line in SOURCE.lines() {
        if let Some(name) = line.strip_prefix("pub struct ").and_then(|rest| rest.split_whitespace().next()) {
            section = SECTIONS.iter().find(|(s, _)| *s == name).map(|(_, toml)| *toml);
            doc.clear();
            continue;
        }
        if line == "}" {
            section = None;
        }
        let Some(section) = section else { continue };
        let trimmed = line.trim_start();
        if let Some(text) = trimmed.strip_prefix("///") {
            doc.push(text.trim());
        } else if let Some(field) = trimmed.strip_prefix("pub ").and_then(|rest| rest.split_once(':')).map(|(name, _)| name) {
            docs.insert((section.to_string(), field.to_string()), doc.join(" "));
            doc.clear();
        } else if !trimmed.starts_with("#[") {
            doc.clear();
        }
    }
    docs
}

/// `text` as `# ` comment lines of at most `width` characters.
fn comment(text: &str, width: usize) -> String {
    let mut out = String::new();
    let mut line = String::from("#");
    for word in text.split_whitespace() {
        if line.len() + 1 + word.len() > width && line.len() > 1 {
            out += &line;
            out.push('\n');
            line = String::from("#");
        }
        line.push(' ');
        line.push_str(word);
    }
    if line.len() > 1 {
        out += &line;
        out.push('\n');
    }
    out
}

/// The annotated default configuration.
pub fn annotated_default() -> String {
    let docs = field_docs();
    let mut out = comment(
        "psneus training configuration: the defaults, each key with its description. Give a file with --config FILE (unknown keys \
         are errors) or single keys on the command line (`cargo xtask train render.rays=512`).",
        96,
    );
    let mut section = String::new();
    for line in TrainConfig::default().to_toml().lines() {
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.to_string();
            if !out.ends_with("\n\n") {
                out.push('\n');
            }
            let (parent, key) = name.rsplit_once('.').unwrap_or(("", name));
            if let Some(doc) = docs.get(&(parent.to_string(), key.to_string())) {
                out += &comment(doc, 96);
            }
            if let Some((_, library)) = LIBRARY_SECTIONS.iter().find(|(s, _)| *s == name) {
                out += &comment(library, 96);
            }
        } else if let Some((key, _)) = line.split_once(" = ")
            && let Some(doc) = docs.get(&(section.clone(), key.trim().to_string())).filter(|d| !d.is_empty())
        {
            out += &comment(doc, 96);
        }
        if !(line.is_empty() && out.ends_with("\n\n")) {
            out += line;
            out.push('\n');
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_annotated_default_is_the_default_and_documents_every_key_of_ours() {
        let text = annotated_default();
        assert_eq!(TrainConfig::from_toml(&text).unwrap(), TrainConfig::default());
        // Every key of this module's sections has its description above it.
        let docs = field_docs();
        for (struct_name, section) in SECTIONS {
            let n = docs.keys().filter(|(s, _)| s == section).count();
            assert!(n >= 1, "{struct_name}: no documented field found");
        }
        assert!(text.contains("# Rays per iteration.\nrays = 256"), "{text}");
        assert!(text.contains("# Seed of every random stream.\nseed = 0"), "{text}");
    }
}
