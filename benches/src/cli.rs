//! Command-line pieces shared by several binaries (parsed with clap).

use prt_trace::expert::BuildQuality;

/// The BVH build quality of a tracing experiment (`--quality`), prt-trace's `BuildQuality`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum BvhQuality {
    /// `BuildQuality::Fast`.
    Fast,
    /// `BuildQuality::Medium`, the baker's default.
    #[default]
    Medium,
    /// `BuildQuality::Slow`.
    Slow,
    /// `BuildQuality::VerySlow`.
    VerySlow,
}

impl From<BvhQuality> for BuildQuality {
    fn from(quality: BvhQuality) -> Self {
        match quality {
            BvhQuality::Fast => BuildQuality::Fast,
            BvhQuality::Medium => BuildQuality::Medium,
            BvhQuality::Slow => BuildQuality::Slow,
            BvhQuality::VerySlow => BuildQuality::VerySlow,
        }
    }
}
