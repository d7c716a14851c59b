//! The machine a figure was measured on, named beside every figure a `bench` prints: the CPU's
//! model, the instruction set the kernels run ([`sdf_backbone::kernels::instruction_set`]), the
//! CPU's bf16 and AMX extensions, and the threads. Figures compare only within one machine.

use serde_json::Value;

/// What [`tag`] adds to a figure.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Machine {
    /// The CPU's model name (`/proc/cpuinfo`), or `"unknown CPU"`.
    pub cpu: String,
    /// The vector instruction set the kernels run.
    pub isa: &'static str,
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
            extensions: extensions.clone(),
            threads: rayon::current_num_threads(),
        }
    }

    /// One line for a table's header: model, instruction set, extensions, threads.
    pub fn line(&self) -> String {
        let extensions = if self.extensions.is_empty() { String::new() } else { format!(" with {}", self.extensions.join(", ")) };
        format!("{}, kernels {}{extensions}, {} threads", self.cpu, self.isa, self.threads)
    }
}

/// `figure` (a JSON object) with the machine's `cpu`, `isa`, `cpu_extensions` and `threads`
/// (kept where the figure has its own).
pub fn tag(mut figure: Value) -> Value {
    let machine = Machine::this();
    if let Value::Object(map) = &mut figure {
        map.entry("cpu").or_insert_with(|| Value::from(machine.cpu));
        map.entry("isa").or_insert_with(|| Value::from(machine.isa));
        map.entry("cpu_extensions").or_insert_with(|| Value::from(machine.extensions));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_tagged_figure_names_the_cpu_and_the_instruction_set() {
        let figure = tag(serde_json::json!({"figure": "x", "threads": 7}));
        assert!(figure["cpu"].as_str().is_some_and(|c| !c.is_empty()));
        assert_eq!(figure["isa"], sdf_backbone::kernels::instruction_set());
        assert!(figure["cpu_extensions"].is_array());
        assert_eq!(figure["threads"], 7, "a figure's own thread count is kept");
        assert!(Machine::this().line().contains(Machine::this().isa));
    }
}
