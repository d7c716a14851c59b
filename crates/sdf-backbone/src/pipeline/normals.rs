//! How the pipeline takes normals from the SDF network: numerical differences on probes around
//! each sample (central, tetrahedral) or the exact gradient by a reverse pass.

#[cfg(doc)]
use crate::module::TangentModule;

/// The probes of numerical normals.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Differences {
    /// Central differences: 6 probes per sample.
    Central,
    /// Tetrahedral differences: 4 probes per sample.
    Tetrahedral,
}

impl Differences {
    /// Probe offsets (in units of the step h) and the weight of each probe in `nᵢ` per unit h.
    pub(crate) fn probes(self) -> &'static [([f64; 3], f64)] {
        const C: [([f64; 3], f64); 6] = [
            ([1.0, 0.0, 0.0], 0.5),
            ([-1.0, 0.0, 0.0], 0.5),
            ([0.0, 1.0, 0.0], 0.5),
            ([0.0, -1.0, 0.0], 0.5),
            ([0.0, 0.0, 1.0], 0.5),
            ([0.0, 0.0, -1.0], 0.5),
        ];
        const T: [([f64; 3], f64); 4] = [([1.0, -1.0, -1.0], 0.25), ([-1.0, -1.0, 1.0], 0.25), ([-1.0, 1.0, -1.0], 0.25), ([1.0, 1.0, 1.0], 0.25)];
        match self {
            Differences::Central => &C,
            Differences::Tetrahedral => &T,
        }
    }
}

/// How normals are taken from the SDF network: what a user chooses. A pipeline takes
/// [`NormalScheme::Analytic`] only with a network that has tangents
/// ([`crate::Pipeline::with_analytic_normals`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NormalScheme {
    /// Central differences: 6 probes per sample.
    Central,
    /// Tetrahedral differences: 4 probes per sample.
    Tetrahedral,
    /// The exact gradient ∇ₓS by one reverse pass through the network
    /// ([`TangentModule::input_gradient`]), and the loss's gradient through it by one forward-mode
    /// tangent and the reverse pass through it ([`TangentModule::backward_tangent`]): no probes.
    /// Needs a network with tangents and no curvature loss (its Laplacian comes from the probes).
    Analytic,
}

impl NormalScheme {
    /// Every scheme.
    pub const ALL: [NormalScheme; 3] = [NormalScheme::Central, NormalScheme::Tetrahedral, NormalScheme::Analytic];

    /// The name in configurations and on command lines.
    pub fn name(self) -> &'static str {
        match self {
            NormalScheme::Central => "central",
            NormalScheme::Tetrahedral => "tetrahedral",
            NormalScheme::Analytic => "analytic",
        }
    }

    /// The scheme of [`NormalScheme::name`]; the error names the known ones.
    pub fn from_name(name: &str) -> Result<NormalScheme, String> {
        NormalScheme::ALL
            .into_iter()
            .find(|n| n.name() == name)
            .ok_or_else(|| format!("unknown normal scheme {name:?} (known: {})", NormalScheme::ALL.map(NormalScheme::name).join(", ")))
    }

    /// Extra SDF evaluations (probe rows) per sample: 6 central, 4 tetrahedral, 0 analytic.
    pub fn probe_count(self) -> usize {
        self.differences().map_or(0, |d| d.probes().len())
    }

    /// The probes of a numerical scheme (None for analytic normals).
    pub fn differences(self) -> Option<Differences> {
        match self {
            NormalScheme::Central => Some(Differences::Central),
            NormalScheme::Tetrahedral => Some(Differences::Tetrahedral),
            NormalScheme::Analytic => None,
        }
    }
}

impl From<Differences> for NormalScheme {
    fn from(d: Differences) -> NormalScheme {
        match d {
            Differences::Central => NormalScheme::Central,
            Differences::Tetrahedral => NormalScheme::Tetrahedral,
        }
    }
}
