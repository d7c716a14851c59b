//! The configuration's named choices: the enums a key takes by name (`sampler = "guided"`,
//! `model.normals = "auto"`, …), with what each name means and the rules that resolve `auto`.

use serde::{Deserialize, Serialize};

/// Which rays the trainer draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum SamplerKind {
    /// The probability-guided sampler with the surface losses and the extra ray points.
    #[default]
    Guided,
    /// Uniform pixels, the plain backbone (same rays and samples per ray).
    Uniform,
    /// instant-ngp's error map: pixels drawn in proportion to their recent loss, no correction
    /// (`[mining]`; the plain backbone otherwise, as `uniform`).
    #[serde(rename = "error-map")]
    #[cfg_attr(feature = "clap", value(name = "error-map"))]
    ErrorMap,
    /// Soft mining (CVPR 2024): the error map's pixels with each pixel's loss weighted by
    /// `(p_uniform / Q)^α` (`mining.alpha`).
    #[serde(rename = "soft-mining")]
    #[cfg_attr(feature = "clap", value(name = "soft-mining"))]
    SoftMining,
}

impl SamplerKind {
    /// Every sampler.
    pub const ALL: [SamplerKind; 4] = [SamplerKind::Guided, SamplerKind::Uniform, SamplerKind::ErrorMap, SamplerKind::SoftMining];

    /// The sampler of [`SamplerKind::name`]; the error names the known ones.
    pub fn from_name(name: &str) -> Result<SamplerKind, String> {
        SamplerKind::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| format!("unknown sampler {name:?} (known: {})", SamplerKind::ALL.map(SamplerKind::name).join(", ")))
    }

    /// The name in configurations and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            SamplerKind::Guided => "guided",
            SamplerKind::Uniform => "uniform",
            SamplerKind::ErrorMap => "error-map",
            SamplerKind::SoftMining => "soft-mining",
        }
    }

    /// Whether the pixels come from the loss ([`view_sampler::ErrorMap`]).
    pub fn mines(self) -> bool {
        matches!(self, SamplerKind::ErrorMap | SamplerKind::SoftMining)
    }
}

/// How Adam stores the hash tables' moments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MomentStorage {
    /// f32, like every other parameter's.
    #[default]
    F32,
    /// bf16 with stochastic rounding: half the memory of the moments (sdf-backbone `optim`).
    Bf16,
}

/// The precision of the networks' matrix products (`model.products`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Products {
    /// f32 throughout.
    #[default]
    F32,
    /// The hidden-to-hidden layers of the SDF and colour networks in bf16 with f32 accumulation
    /// where the CPU has AVX512_BF16, f32 on other CPUs ([`sdf_backbone::Products::Bf16Hidden`]).
    Bf16,
}

impl From<Products> for sdf_backbone::Products {
    fn from(p: Products) -> sdf_backbone::Products {
        match p {
            Products::F32 => sdf_backbone::Products::F32,
            Products::Bf16 => sdf_backbone::Products::Bf16Hidden,
        }
    }
}

/// How the run takes its normals (`model.normals`): a scheme of `sdf-backbone`, or `auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Normals {
    /// Analytic where the model allows it (no curvature loss), else tetrahedral: the analytic
    /// step is the faster one at level or better mesh quality (docs/DECISIONS.md §24, §29).
    Auto,
    /// Central differences: 6 probes per sample.
    Central,
    /// Tetrahedral differences: 4 probes per sample.
    Tetrahedral,
    /// The exact gradient by forward-mode derivatives (every preset; no curvature loss).
    Analytic,
}

/// How the smoothing weights (`model.curvature`, `model.normal_smoothness`) follow the
/// coarse-to-fine levels (`model.smoothing_decay`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SmoothingDecay {
    /// The weights stay as given once the warm-up has reached them.
    None,
    /// Neuralangelo's (the default): divided by the hash grid's growth for each level switched on
    /// after the initial ones (the finest active resolution over the initial finest), so that
    /// smoothing holds the coarse shape early and lets the finer levels' detail through later.
    /// No effect without a hash grid.
    Levels,
}

/// Where the normal smoothness (`model.normal_smoothness`) compares neighbouring samples of a
/// ray (`model.smoothing_region`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SmoothingRegion {
    /// Every pair of neighbouring samples (the term as it was).
    Everywhere,
    /// Pairs with a sample outside the solid or within `model.smoothing_depth` of its surface:
    /// free space and a band at the surface, not the solid's depth, where a ray's normals turn
    /// from the near side's to the far side's and smoothing them pushes the unseen far side out.
    Outside,
}

/// Which connected components of the extracted mesh are kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshFilter {
    /// Every component.
    All,
    /// Only the largest (by triangle count).
    Largest,
    /// The largest component and every other the views support: with masks, a component whose
    /// vertices lie inside the visual hull (in the foreground of ≥ 90 % of the training views that see them in frame);
    /// without masks, a component of at least `output.min_component_area` of the mesh's area.
    Supported,
}

/// What is behind the object. In a file also `learned_background = true | false` (the key
/// of earlier versions: learned | fixed).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", try_from = "NameOrFlag")]
pub enum BackgroundModel {
    /// Learned when the run does not use masks (a capture's real surroundings must be
    /// explained by something other than the object), fixed when it does.
    Auto,
    /// NeRF++'s inverted-sphere model beyond the bound, learned with the object.
    Learned,
    /// The fixed colour `model.background`.
    Fixed,
}

/// How a choice with a boolean form may be written: its name, or `true` / `false` (a background
/// model's earlier boolean, `model.background_grid`).
#[derive(Deserialize)]
#[serde(untagged)]
enum NameOrFlag {
    Name(String),
    Flag(bool),
}

impl TryFrom<NameOrFlag> for BackgroundModel {
    type Error = String;
    fn try_from(text: NameOrFlag) -> std::result::Result<Self, String> {
        match text {
            NameOrFlag::Flag(true) => Ok(BackgroundModel::Learned),
            NameOrFlag::Flag(false) => Ok(BackgroundModel::Fixed),
            NameOrFlag::Name(n) => match n.as_str() {
                "auto" => Ok(BackgroundModel::Auto),
                "learned" => Ok(BackgroundModel::Learned),
                "fixed" => Ok(BackgroundModel::Fixed),
                other => Err(format!("unknown background model {other:?}: expected auto, learned or fixed")),
            },
        }
    }
}

impl BackgroundModel {
    /// Whether the background is learned in a run that uses masks (`use_masks`) or not.
    pub fn learned(self, use_masks: bool) -> bool {
        match self {
            BackgroundModel::Auto => !use_masks,
            BackgroundModel::Learned => true,
            BackgroundModel::Fixed => false,
        }
    }
}

/// Whether the learned background's network also reads a hash grid of its own
/// (`model.background_grid`; `sdf_backbone::BackgroundModel::cpu_grid`): in a file `"auto"`,
/// `true` or `false`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(try_from = "NameOrFlag")]
pub enum BackgroundGrid {
    /// With uniform rays, which spend most of a batch on the backdrop: without the grid the
    /// object's network painted a near wall's detail as floaters inside the bound and kept it;
    /// guided rays leave it to the MLP, which keeps thin parts better (docs/DECISIONS.md §42).
    Auto,
    /// Always.
    On,
    /// Never (the MLP alone).
    Off,
}

impl TryFrom<NameOrFlag> for BackgroundGrid {
    type Error = String;
    fn try_from(text: NameOrFlag) -> std::result::Result<Self, String> {
        match text {
            NameOrFlag::Flag(true) => Ok(BackgroundGrid::On),
            NameOrFlag::Flag(false) => Ok(BackgroundGrid::Off),
            NameOrFlag::Name(n) if n == "auto" => Ok(BackgroundGrid::Auto),
            NameOrFlag::Name(other) => Err(format!("unknown background grid {other:?}: expected \"auto\", true or false")),
        }
    }
}

impl Serialize for BackgroundGrid {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            BackgroundGrid::Auto => serializer.serialize_str("auto"),
            BackgroundGrid::On => serializer.serialize_bool(true),
            BackgroundGrid::Off => serializer.serialize_bool(false),
        }
    }
}

impl BackgroundGrid {
    /// Whether a run with `sampler` gives its learned background the grid.
    pub fn used(self, sampler: SamplerKind) -> bool {
        match self {
            BackgroundGrid::Auto => sampler == SamplerKind::Uniform,
            BackgroundGrid::On => true,
            BackgroundGrid::Off => false,
        }
    }
}

/// Which hash grid the run's model has (`model.grid`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GridSize {
    /// The preset's (neuralangelo-cpu: 8 levels, 16 → 256, 2¹⁶ entries per level).
    #[default]
    Preset,
    /// Sized by the data: the finest resolution from the training views' pixel footprint at the
    /// region of interest (`model.pixels_per_cell` pixels per finest cell), the preset's level
    /// spacing, the table grown with the finest level's surface (`crate::sizing`).
    Footprint,
}

/// The marching-cubes resolution of the run's meshes (`output.mesh_resolution`): a number of
/// cells per side of the bound's cube, or `"model"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "MeshResolutionText", into = "MeshResolutionText")]
pub enum MeshResolution {
    /// This many cells per side of the bound's cube.
    Cells(u32),
    /// As fine as the model: one cell per cell of the hash grid's finest level (the preset's,
    /// or the grid sized by the footprint); for a preset without a hash grid, one cell per
    /// `model.pixels_per_cell` pixels of the views' footprint (`crate::sizing::mesh_resolution`).
    Model,
}

/// How a mesh resolution is written: a number, or the name `model`.
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum MeshResolutionText {
    Cells(u32),
    Name(String),
}

impl TryFrom<MeshResolutionText> for MeshResolution {
    type Error = String;
    fn try_from(text: MeshResolutionText) -> std::result::Result<Self, String> {
        match text {
            MeshResolutionText::Cells(n) => Ok(MeshResolution::Cells(n)),
            MeshResolutionText::Name(n) if n == "model" => Ok(MeshResolution::Model),
            MeshResolutionText::Name(n) => Err(format!("mesh resolution {n:?}: expected a number of cells (8 … 2048) or \"model\"")),
        }
    }
}

impl From<MeshResolution> for MeshResolutionText {
    fn from(resolution: MeshResolution) -> Self {
        match resolution {
            MeshResolution::Cells(n) => MeshResolutionText::Cells(n),
            MeshResolution::Model => MeshResolutionText::Name("model".into()),
        }
    }
}

impl MeshResolution {
    /// The cell counts a mesh may have per side.
    pub const CELLS: std::ops::RangeInclusive<u32> = 8..=crate::sizing::MAX_MESH_RESOLUTION;

    /// `self`, or what is wrong with it (a number of cells outside [`Self::CELLS`]).
    pub fn checked(self) -> std::result::Result<MeshResolution, String> {
        match self {
            MeshResolution::Cells(n) if !Self::CELLS.contains(&n) => {
                Err(format!("a mesh resolution of {n} cells per side: expected {} … {} or \"model\"", Self::CELLS.start(), Self::CELLS.end()))
            }
            _ => Ok(self),
        }
    }
}

/// A command line's mesh resolution: a number of cells per side or `model`, checked.
impl std::str::FromStr for MeshResolution {
    type Err = String;
    fn from_str(text: &str) -> std::result::Result<Self, String> {
        let text = text.trim();
        let resolution = match text.parse::<u32>() {
            Ok(n) => MeshResolution::Cells(n),
            Err(_) => MeshResolutionText::Name(text.to_string()).try_into()?,
        };
        resolution.checked()
    }
}

impl std::fmt::Display for MeshResolution {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MeshResolution::Cells(n) => write!(f, "{n}"),
            MeshResolution::Model => write!(f, "\"model\""),
        }
    }
}

/// The radius of the SDF's initial sphere (NeuS's geometric initialisation), in bound radii.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "InitRadiusText", into = "InitRadiusText")]
pub enum InitRadius {
    /// 0.5 with masks; without them the largest sphere up to 0.5 that leaves every view room
    /// around it ([`crate::sizing::initial_sphere_radius`]).
    Auto,
    /// 0.5 with masks; without them the sphere around the object's visual hull, carved from the
    /// silhouettes of a short first phase (the trainer's `silhouettes` module).
    Photos,
    /// This radius, in (0, 1).
    Radius(f64),
}

/// How an initial radius is written: `"auto"` or a number.
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum InitRadiusText {
    Name(String),
    Radius(f64),
}

impl TryFrom<InitRadiusText> for InitRadius {
    type Error = String;
    fn try_from(text: InitRadiusText) -> std::result::Result<Self, String> {
        match text {
            InitRadiusText::Radius(r) => Ok(InitRadius::Radius(r)),
            InitRadiusText::Name(n) if n == "auto" => Ok(InitRadius::Auto),
            InitRadiusText::Name(n) if n == "photos" => Ok(InitRadius::Photos),
            InitRadiusText::Name(other) => Err(format!("unknown initial radius {other:?}: expected auto, photos or a number")),
        }
    }
}

impl From<InitRadius> for InitRadiusText {
    fn from(radius: InitRadius) -> InitRadiusText {
        match radius {
            InitRadius::Auto => InitRadiusText::Name("auto".into()),
            InitRadius::Photos => InitRadiusText::Name("photos".into()),
            InitRadius::Radius(r) => InitRadiusText::Radius(r),
        }
    }
}

impl InitRadius {
    /// The radius for a run on `cameras` that uses masks (`use_masks`) or not; `photos` without
    /// masks gives 0.5 here, which the first phase replaces (the trainer's `silhouettes` module).
    pub fn resolve<'a>(self, cameras: impl IntoIterator<Item = &'a camera_geom::PinholeCamera>, use_masks: bool) -> f64 {
        match self {
            InitRadius::Radius(r) => r,
            InitRadius::Auto if use_masks => crate::sizing::MAX_INITIAL_RADIUS,
            InitRadius::Photos => crate::sizing::MAX_INITIAL_RADIUS,
            InitRadius::Auto => crate::sizing::initial_sphere_radius(cameras).unwrap_or(crate::sizing::MAX_INITIAL_RADIUS),
        }
    }
}
