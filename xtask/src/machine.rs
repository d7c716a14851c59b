//! The machine a figure was measured on, named beside every figure a `bench` prints: the CPU's
//! model, the instruction set the kernels run ([`sdf_backbone::kernels::instruction_set`]), the
//! CPU's bf16 and AMX extensions, and the threads. Figures compare only within one machine.

use anyhow::{Context, Result};
use sdf_backbone::kernels::{InstructionSet, instruction_set_limit};
use serde_json::Value;

/// What [`tag`] adds to a figure.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Machine {
    /// The CPU's model name (`/proc/cpuinfo`), or `"unknown CPU"`.
    pub cpu: String,
    /// The vector instruction set the kernels run.
    pub isa: &'static str,
    /// Whether `--isa` limited the kernels to a narrower instruction set than the CPU's.
    pub limited: bool,
    /// The CPU's extensions that matter to the kernels (`avx512_bf16`, `amx_bf16`), present.
    pub extensions: Vec<&'static str>,
    /// Worker threads.
    pub threads: usize,
}

impl Machine {
    /// This machine (`/proc/cpuinfo` read once per process).
    pub fn this() -> Machine {
        static CPU: std::sync::OnceLock<(String, Vec<&'static str>)> = std::sync::OnceLock::new();
        let (cpu, extensions) = CPU.get_or_init(|| {
            let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
            (cpu_model(&info), extensions(&info))
        });
        Machine {
            cpu: cpu.clone(),
            isa: sdf_backbone::kernels::instruction_set(),
            limited: instruction_set_limit().is_some(),
            extensions: extensions.clone(),
            threads: rayon::current_num_threads(),
        }
    }

    /// One line for a table's header: model, instruction set, extensions, threads.
    pub fn line(&self) -> String {
        let extensions = match (self.extensions.is_empty(), self.limited) {
            (true, _) => String::new(),
            (false, false) => format!(" with {}", self.extensions.join(", ")),
            (false, true) => format!(" (limited by --isa; the CPU has {}, unused)", self.extensions.join(", ")),
        };
        format!("{}, kernels {}{extensions}, {} threads", self.cpu, self.isa, self.threads)
    }
}

/// `figure` (a JSON object) with the machine's `cpu`, `isa`, `cpu_extensions`, `isa_limited`
/// (`--isa` narrower than the CPU) and `threads` (kept where the figure has its own).
pub fn tag(mut figure: Value) -> Value {
    let machine = Machine::this();
    if let Value::Object(map) = &mut figure {
        map.entry("cpu").or_insert_with(|| Value::from(machine.cpu));
        map.entry("isa").or_insert_with(|| Value::from(machine.isa));
        map.entry("cpu_extensions").or_insert_with(|| Value::from(machine.extensions));
        map.entry("isa_limited").or_insert_with(|| Value::from(machine.limited));
        map.entry("threads").or_insert_with(|| Value::from(machine.threads));
    }
    figure
}

/// The CPU's model name from `/proc/cpuinfo`'s text `info` (Linux), else `"unknown CPU"`, with
/// its family and model numbers where the name alone does not tell the generation (AMD's "AMD
/// EPYC").
fn cpu_model(info: &str) -> String {
    let field = |key: &str| {
        info.lines().find(|l| l.split(':').next().is_some_and(|k| k.trim() == key)).and_then(|l| l.split_once(':')).map(|(_, v)| v.trim().to_string())
    };
    match field("model name") {
        Some(name) => match (field("cpu family"), field("model")) {
            (Some(family), Some(model)) => format!("{name} (family {family} model {model})"),
            _ => name,
        },
        None => "unknown CPU".to_string(),
    }
}

/// The extensions of this CPU that the kernels could use beyond their instruction set: from
/// `/proc/cpuinfo`'s flags (`info`) where there are any (AMX's detection is not stable in Rust), else
/// `avx512_bf16` by the standard library's detection.
fn extensions(info: &str) -> Vec<&'static str> {
    const WANTED: [&str; 2] = ["avx512_bf16", "amx_bf16"];
    if let Some(flags) = info.lines().find(|l| l.starts_with("flags")) {
        let flags: Vec<&str> = flags.split_whitespace().collect();
        return WANTED.into_iter().filter(|w| flags.contains(w)).collect();
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512bf16") {
        return vec![WANTED[0]];
    }
    Vec::new()
}

/// `--isa`'s values: `avx512`, `avx2`, `baseline` (x86-64's SSE2).
pub fn parse_instruction_set(text: &str) -> std::result::Result<InstructionSet, String> {
    match text {
        "avx512" => Ok(InstructionSet::Avx512),
        "avx2" => Ok(InstructionSet::Avx2),
        "baseline" => Ok(InstructionSet::Baseline),
        other => Err(format!("`{other}`: the instruction sets are avx512, avx2 and baseline")),
    }
}

/// `--isa`'s spelling of `isa` ([`parse_instruction_set`]'s inverse).
pub fn instruction_set_name(isa: InstructionSet) -> &'static str {
    match isa {
        InstructionSet::Avx512 => "avx512",
        InstructionSet::Avx2 => "avx2",
        InstructionSet::Baseline => "baseline",
    }
}

/// A child `xtask` process on the kernels' instruction set of this one (`--isa` passed on
/// where it is limited), so that a benchmark's children measure what it names.
pub fn xtask_child() -> Result<std::process::Command> {
    let mut command = std::process::Command::new(std::env::current_exe().context("locating the xtask binary")?);
    if let Some(isa) = instruction_set_limit() {
        command.args(["--isa", instruction_set_name(isa)]);
    }
    Ok(command)
}

/// The environment that limits PyTorch to the instruction set our kernels are limited to (its
/// own kernels, `torch.compile`'s generated code, oneDNN and MKL), empty without a limit. The
/// compiled code then has a cache of its own: `torch.compile` keys its cache without the
/// instruction set, and code cached for AVX-512 ran under `ATEN_CPU_CAPABILITY=avx2` and gave a
/// NaN loss (PyTorch 2.15, 2026-12-06).
pub fn peer_instruction_set_env() -> Vec<(&'static str, String)> {
    let (aten, onednn, mkl) = match instruction_set_limit() {
        None | Some(InstructionSet::Avx512) => return Vec::new(),
        Some(InstructionSet::Avx2) => ("avx2", "AVX2", "AVX2"),
        Some(InstructionSet::Baseline) => ("default", "SSE41", "SSE4_2"),
    };
    let cache = std::env::temp_dir().join(format!("psneus-torchinductor-{aten}"));
    vec![
        ("ATEN_CPU_CAPABILITY", aten.to_string()),
        ("ONEDNN_MAX_CPU_ISA", onednn.to_string()),
        ("MKL_ENABLE_INSTRUCTIONS", mkl.to_string()),
        ("TORCHINDUCTOR_CACHE_DIR", cache.display().to_string()),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_tagged_figure_names_the_cpu_and_the_instruction_set() {
        let figure = tag(serde_json::json!({"figure": "x", "threads": 7}));
        assert!(figure["cpu"].as_str().is_some_and(|c| !c.is_empty()));
        assert_eq!(figure["isa"], sdf_backbone::kernels::instruction_set());
        assert!(figure["cpu_extensions"].is_array());
        assert_eq!(figure["isa_limited"], false, "no --isa in the tests' process");
        assert_eq!(figure["threads"], 7, "a figure's own thread count is kept");
        assert!(Machine::this().line().contains(Machine::this().isa));
    }

    #[test]
    fn every_instruction_set_is_spelt_as_it_is_parsed() {
        for isa in [InstructionSet::Avx512, InstructionSet::Avx2, InstructionSet::Baseline] {
            assert_eq!(parse_instruction_set(instruction_set_name(isa)), Ok(isa));
        }
        assert!(parse_instruction_set("sse9").unwrap_err().contains("sse9"));
    }
}
